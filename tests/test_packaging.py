"""The ament layout: entry points where ros2 run looks, the package share, and a fresh build."""
import importlib.metadata
import os
import pathlib
import shutil
import subprocess

import pytest

REPO_ROOT = pathlib.Path(__file__).resolve().parents[1]


def _console_scripts():
    return sorted(ep.name for ep in importlib.metadata.distribution("softgrip_ros").entry_points
                  if ep.group == "console_scripts")


def test_package_share_is_found_through_the_ament_index():
    from ament_index_python.packages import get_package_prefix, get_package_share_directory

    share = pathlib.Path(get_package_share_directory("softgrip_ros"))
    assert (share / "package.xml").is_file()
    assert (share / "config").is_dir()
    prefix = pathlib.Path(get_package_prefix("softgrip_ros"))
    assert (prefix / "share/ament_index/resource_index/packages/softgrip_ros").exists()


def test_every_console_entry_point_is_installed_where_ros2_run_looks():
    """The list comes from the package metadata, so new executables are checked as they are
    added."""
    from ament_index_python.packages import get_package_prefix

    lib_dir = pathlib.Path(get_package_prefix("softgrip_ros")) / "lib" / "softgrip_ros"
    declared = _console_scripts()
    for name in declared:
        executable = lib_dir / name
        assert executable.is_file(
        ), f"{name} is declared in setup.py but not installed at {executable}"
        assert os.access(executable, os.X_OK), f"{executable} is not executable"
    installed = sorted(p.name for p in lib_dir.iterdir()) if lib_dir.is_dir() else []
    assert (
        installed == declared), "lib/softgrip_ros holds executables that setup.py does not declare"


def _built_from_nothing_by_this_run() -> bool:
    """Whether scripts/test.sh set this very workspace up from nothing before pytest started (as
    CI does on its fresh clone): its setup log says it created the venv and built install/."""
    log = pathlib.Path(os.environ.get("SOFTGRIP_SETUP_LOG", "/nonexistent"))
    if not log.is_file() or log.parent.parent.resolve() != REPO_ROOT.resolve():
        return False
    text = log.read_text()
    return f"creating {REPO_ROOT.resolve() / '.venv'} with" in text and "colcon build (" in text


@pytest.mark.slow
def test_setup_on_a_fresh_clone_builds_both_packages(tmp_path):
    """scripts/setup.sh from nothing, then a second run that changes nothing. Where this run's
    own workspace was just built from nothing (CI's fresh clone), that build is the first run, and
    the same setup is run again on it; elsewhere a fresh clone is set up twice."""
    if _built_from_nothing_by_this_run():
        again = subprocess.run(["bash", "scripts/setup.sh", "--with-reference"], cwd=REPO_ROOT,
                               capture_output=True, text=True, timeout=600)
        assert again.returncode == 0, again.stderr
        assert ("venv up to date" in again.stdout and "reference extra up to date" in again.stdout
                and "install/ up to date" in again.stdout), again.stdout
        return
    if shutil.which("git") is None or not (REPO_ROOT / ".git").exists():
        pytest.skip("needs the git checkout")
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO_ROOT, capture_output=True,
                          text=True)
    if head.returncode != 0:
        pytest.skip("no commit to clone yet")
    clone = tmp_path / "clone"
    subprocess.run(["git", "clone", "--quiet", str(REPO_ROOT), str(clone)], check=True)
    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith(("VIRTUAL_ENV", "AMENT_", "COLCON_", "CMAKE_PREFIX", "PYTHONPATH",
                             "LD_LIBRARY_PATH", "SOFTGRIP_ROOT", "_ROS_WHEELS"))
    }
    env["PATH"] = os.pathsep.join(p for p in env["PATH"].split(os.pathsep) if ".venv" not in p)
    first = subprocess.run(["bash", "scripts/setup.sh"], cwd=clone, env=env, capture_output=True,
                           text=True, timeout=1200)
    assert first.returncode == 0, first.stdout + first.stderr
    probe = ("import softgrip_interfaces.msg, softgrip_interfaces.action, softgrip_ros, rclpy;"
             "print(softgrip_ros.__file__)")
    imported = subprocess.run(["bash", "-c", f"source scripts/env.sh && python -c '{probe}'"],
                              cwd=clone, env=env, capture_output=True, text=True, timeout=120)
    assert imported.returncode == 0, imported.stderr
    assert str(clone) in imported.stdout, "softgrip_ros was imported from outside the fresh clone"
    second = subprocess.run(["bash", "scripts/setup.sh"], cwd=clone, env=env, capture_output=True,
                            text=True, timeout=600)
    assert second.returncode == 0, second.stderr
    assert ("venv up to date" in second.stdout and
            "install/ up to date" in second.stdout), second.stdout


def test_setup_refuses_an_unsupported_interpreter(tmp_path):
    fake_python = tmp_path / "python3.9"
    fake_python.write_text("#!/bin/sh\ncase \"$2\" in *python_implementation*) echo CPython;; "
                           "*) echo 3.9;; esac\n")
    fake_python.chmod(0o755)
    env = dict(os.environ, SOFTGRIP_PYTHON=str(fake_python))
    run = subprocess.run(["bash", "scripts/setup.sh"], cwd=REPO_ROOT, env=env, capture_output=True,
                         text=True, timeout=60)
    assert run.returncode != 0
    assert "unsupported interpreter CPython 3.9" in run.stderr
    assert "3.10-3.13" in run.stderr
