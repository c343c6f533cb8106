"""softgrip_ros.fileio: every file a tool writes is whole or absent (#52, atomic writes)."""
import os
import subprocess

import pytest

from softgrip_ros import fileio
from softgrip_ros.devtools.processes import installed_executable

pytestmark = pytest.mark.cpu  # computation only: scripts/test.sh runs it beside another


def test_a_write_replaces_the_file_whole_and_leaves_nothing_beside_it(tmp_path):
    target = tmp_path / "deeper" / "model.yaml"
    assert fileio.write_text_atomically(target, "a: 1\n") == target
    fileio.write_text_atomically(target, "a: 2\n")
    assert target.read_text() == "a: 2\n"
    assert [p.name for p in target.parent.iterdir()] == ["model.yaml"]


def test_a_failed_write_keeps_the_old_file_and_removes_the_temporary(tmp_path, monkeypatch):
    target = tmp_path / "model.yaml"
    target.write_text("old\n")

    def refuse(source, destination):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", refuse)
    with pytest.raises(fileio.OutputError, match=r"cannot write .*model.yaml: No space left"):
        fileio.write_text_atomically(target, "new\n")
    assert target.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["model.yaml"]


def test_a_writer_that_fails_midway_leaves_the_old_file(tmp_path):
    target = tmp_path / "figure.png"
    target.write_bytes(b"old")
    with pytest.raises(RuntimeError):
        with fileio.replacing(target) as temporary:
            assert temporary.suffix == ".png"  # for writers that pick the format by it
            temporary.write_bytes(b"half")
            raise RuntimeError("the plot failed")
    assert target.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["figure.png"]


def test_a_directory_that_could_not_be_made_is_one_line_naming_it_and_nothing_is_made(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    with pytest.raises(fileio.OutputError) as error:
        fileio.check_writable_directory(blocker / "out")
    assert str(error.value).startswith(f"cannot write in {blocker / 'out'}: ")
    assert "\n" not in str(error.value)
    assert fileio.check_writable_directory(tmp_path / "new" / "dir") == tmp_path / "new" / "dir"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]  # nothing made


def test_calibrate_finds_out_before_the_fit_that_it_could_not_write(tmp_path):
    """It fitted, then ended in a traceback (a read-only directory, or a file in the way)."""
    csv = tmp_path / "m.csv"
    csv.write_text("pressure_pa,alpha_deg\n10000,20\n20000,25\n30000,31\n")
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    result = subprocess.run([installed_executable("softgrip_calibrate"), str(csv), "--name", "x",
                             "--output", str(blocker / "x.yaml"), "--no-plot"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 1
    assert "Traceback" not in result.stderr and "fitting" not in result.stdout
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith(f"softgrip_calibrate: cannot write in {blocker}: ")
    assert line.endswith("; nothing written")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file", "m.csv"]
