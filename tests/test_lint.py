"""The code passes ruff (pyflakes, pycodestyle, import order, bugbear) at 99 columns, the ROS 2
convention; the settings are in ruff.toml."""
import pathlib
import subprocess
import sys

REPO_ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_ruff_finds_nothing():
    result = subprocess.run(
        [sys.executable, "-m", "ruff", "check", "--no-cache", "--quiet",
         str(REPO_ROOT)], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, f"ruff check found problems:\n{result.stdout}{result.stderr}"
