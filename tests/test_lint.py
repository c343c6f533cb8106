"""The code passes ruff (pyflakes, pycodestyle, import order, bugbear) at 99 columns, the ROS 2
convention; the settings are in ruff.toml."""
import pathlib
import subprocess
import sys

import pytest

pytestmark = pytest.mark.cpu  # computation only: scripts/test.sh runs it beside another

REPO_ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_ruff_finds_nothing():
    result = subprocess.run(
        [sys.executable, "-m", "ruff", "check", "--no-cache", "--quiet",
         str(REPO_ROOT)], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, f"ruff check found problems:\n{result.stdout}{result.stderr}"


def test_every_test_file_the_tree_names_exists():
    """Every tests/... file that code, docs or config name (config/paper_results.yaml once
    named one that did not exist)."""
    import re
    named = set()
    for path in REPO_ROOT.rglob("*"):
        if (path.suffix in (".py", ".md", ".yaml", ".sh", ".txt") and path.is_file()
                and not {"build", "install", "log", ".venv", ".git"} & set(path.parts)):
            text = path.read_text(errors="ignore")
            named.update(re.findall(r"tests/(?:helpers/)?test_\w+\.py", text))
    missing = sorted(n for n in named if not (REPO_ROOT / n).is_file())
    assert named and not missing, f"named but missing: {missing}"
