"""Every tool's --namespace is checked as it is parsed (#52, class 5): a namespace no topic can
live under gave a traceback from deep in rclpy, and softgrip_record left an empty bag behind."""
import subprocess

import pytest

from softgrip_ros.client import GripperClient, check_namespace
from softgrip_ros.devtools.processes import installed_executable

TOOLS = [
    ("softgrip", ["state"]),
    ("softgrip_identify", []),
    ("softgrip_record", ["{out}", "--duration", "1"]),
    ("softgrip_calibrate", ["live", "{out}"]),
]


@pytest.mark.parametrize("name, arguments", TOOLS)
def test_a_bad_namespace_is_a_usage_error_and_nothing_is_written(name, arguments, tmp_path):
    """One bad namespace per tool (the kinds of bad are the library test's below)."""
    namespace, out = "bad ns", tmp_path / "out"
    command = [installed_executable(name)] + [a.format(out=out) for a in arguments]
    result = subprocess.run(command + ["--namespace", namespace], capture_output=True,
                            text=True, timeout=60, cwd=tmp_path)
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith(f"{name}") and f"invalid namespace {namespace!r}" in last, last
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("namespace", ["", "/g1", "g1", "/g1/", "/arm/left_gripper"])
def test_a_good_namespace_passes_as_it_was_given(namespace):
    assert check_namespace(namespace) == namespace


@pytest.mark.parametrize("namespace, why", [
    ("bad ns", "must not contain characters"), ("/g1//x", "repeated '/'"),
    ("{x}", "unknown substitution"), (None, "is a string"),
])
def test_the_library_refuses_what_the_tools_refuse(namespace, why):
    with pytest.raises(ValueError, match=why):
        check_namespace(namespace)
    with pytest.raises(ValueError, match=why):
        GripperClient(namespace=namespace)  # before it makes a node
