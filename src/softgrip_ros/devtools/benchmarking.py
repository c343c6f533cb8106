"""Shared helpers of scripts/bench_*.py: medians of repeated timings and docs/benchmarks.md
sections.

Performance is measured here, never asserted in unit tests: the machines are shared
and noisy, so each figure is the median over repeats, and comparisons are ratios
taken in one run.
"""
from __future__ import annotations

import argparse
import contextlib
import datetime
import json
import math
import os
import pathlib
import platform
import shutil
import statistics
import subprocess
import tempfile
import time

import numpy as np

BENCHMARKS_MD = pathlib.Path(__file__).resolve().parents[3] / "docs" / "benchmarks.md"


def median_seconds(function, number: int, repeat: int) -> float:
    """Median over ``repeat`` runs of the time per call, each run timing ``number`` calls."""
    samples = []
    for _ in range(repeat):
        start = time.perf_counter()
        for _ in range(number):
            function()
        samples.append((time.perf_counter() - start) / number)
    return statistics.median(samples)


def interleaved_seconds(functions: dict, repeat: int) -> dict:
    """{name: [seconds of each of ``repeat`` calls]}, the functions called in turn, round after
    round (after one untimed round): a busy moment of a shared host then falls on all of them
    alike, where timing each one's calls in a row let it fall on one."""
    for function in functions.values():
        function()
    samples = {name: [] for name in functions}
    for _ in range(repeat):
        for name, function in functions.items():
            start = time.perf_counter()
            function()
            samples[name].append(time.perf_counter() - start)
    return samples


def repeat_count(text: str) -> int:
    """argparse type of every bench script's --repeat: a median needs at least 3 runs."""
    value = int(text)
    if value < 3:
        raise argparse.ArgumentTypeError(
            f"must be at least 3 for a meaningful median, got {value}")
    return value


def benchmark_parser(doc: str, quick_help: str, repeat_default: int | None = None,
                     repeat_help: str = "timed runs per figure (median)",
                     json_help: str = "print the figures as JSON, write nothing",
                     load: bool = False) -> argparse.ArgumentParser:
    """The options every scripts/bench_*.py has: --json, --quick (``quick_help``: what it cuts;
    quick writes nothing), with ``repeat_default`` --repeat, and with ``load`` --load N (the
    script runs under :func:`host_load`)."""
    parser = argparse.ArgumentParser(description=doc,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", action="store_true", help=json_help)
    parser.add_argument("--quick", action="store_true", help=quick_help)
    if repeat_default is not None:
        parser.add_argument("--repeat", type=repeat_count, default=repeat_default,
                            help=repeat_help)
    if load:
        parser.add_argument(
            "--load", type=load_count, default=0, metavar="N",
            help=f"run beside N busy processes at nice 0 (0-{MAX_LOAD_PROCESSES}), as on a "
            "robot's computer shared with perception and planning; prints, writes nothing")
    return parser


MAX_LOAD_PROCESSES = 64
# a busy loop that ends once its parent is gone (then its parent pid changes), so that a
# benchmark killed outright leaves no spinner behind
_SPINNER = "import os, sys\nparent = int(sys.argv[1])\nwhile os.getppid() == parent:\n    pass\n"


def load_count(text: str) -> int:
    """argparse type of --load: an integer in [0, MAX_LOAD_PROCESSES]."""
    try:
        count = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
    if not 0 <= count <= MAX_LOAD_PROCESSES:
        raise argparse.ArgumentTypeError(
            f"must lie in [0, {MAX_LOAD_PROCESSES}] processes, got {count}")
    return count


@contextlib.contextmanager
def host_load(processes: int):
    """``processes`` busy Python processes at this process's nice value for the block; yields
    their PIDs. Each is ended by its PID on the way out, and ends by itself if this process dies
    first."""
    import sys

    spinners = []
    try:
        for _ in range(processes):
            spinners.append(subprocess.Popen([sys.executable, "-c", _SPINNER, str(os.getpid())],
                                             stdin=subprocess.DEVNULL))
        yield [spinner.pid for spinner in spinners]
    finally:
        for spinner in spinners:
            spinner.terminate()
        for spinner in spinners:
            try:
                spinner.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                spinner.kill()
                spinner.wait()


def machine_line() -> str:
    return (
        f"{platform.python_implementation()} {platform.python_version()}, {platform.machine()}, "
        f"{os.cpu_count()} cores, {datetime.date.today().isoformat()}")


def update_section(name: str, markdown: str, path: pathlib.Path = BENCHMARKS_MD) -> None:
    """Replace (or append) the section between ``<!-- name:start -->`` and ``<!-- name:end
    -->``."""
    begin, end = f"<!-- {name}:start -->", f"<!-- {name}:end -->"
    block = f"{begin}\n{markdown.rstrip()}\n{end}"
    path.parent.mkdir(parents=True, exist_ok=True)
    text = path.read_text() if path.exists() else (
        "# Benchmarks\n\nMedians over repeated runs on a shared 2-core machine; ratios are taken "
        "within one run. "
        "Each section names the command that reproduces it.\n")
    if begin in text and end in text:
        head, rest = text.split(begin, 1)
        text = head + block + rest.split(end, 1)[1]
    else:
        text = text.rstrip() + "\n\n" + block + "\n"
    path.write_text(text)


def update_variant_section(name: str, heading: str, markdown: str, variant: str = "",
                           variant_heading: str = "", path: pathlib.Path = BENCHMARKS_MD) -> None:
    """:func:`update_section` of ``name`` under ``heading``; for a run with a ``variant`` (an
    option's, e.g. "pump_level"), its own section ``<name>_<variant>`` under ``variant_heading``
    instead, so that both tables stand."""
    if variant:
        update_section(f"{name}_{variant}", f"{variant_heading}\n\n{markdown}", path)
    else:
        update_section(name, f"{heading}\n\n{markdown}", path)


def strict_json(figures, indent: int | None = 2) -> str:
    """``figures`` as JSON that every reader takes: a value that is not finite (an interval
    without bounds, a figure not computed) as null. Python's own ``Infinity`` and ``NaN`` are not
    JSON, and jq or a browser refuse the whole document over one."""

    def finite(value):
        if isinstance(value, (np.generic, np.ndarray)):  # numpy's as Python's own
            value = value.tolist()
        if isinstance(value, float) and not math.isfinite(value):
            return None
        if isinstance(value, dict):
            return {key: finite(item) for key, item in value.items()}
        if isinstance(value, (list, tuple)):
            return [finite(item) for item in value]
        return value

    return json.dumps(finite(figures), indent=indent, allow_nan=False)


def verdict(value: float, target: float, smaller_is_better: bool = True) -> str:
    ok = value <= target if smaller_is_better else value >= target
    return "meets" if ok else "**misses**"


def figure_rows(figures: dict, targets: dict) -> list:
    """A markdown table of ``figures`` against ``targets`` {key: (target, smaller_is_better)};
    booleans are judged against True, keys without a target are reported."""
    rows = ["| key | median | target | |", "|---|---|---|---|"]
    for key, value in figures.items():
        if isinstance(value, bool):
            rows.append(
                f"| `{key}` | {str(value).lower()} | true | {'meets' if value else '**misses**'} |"
            )
        elif key in targets:
            target, smaller_is_better = targets[key]
            rows.append(
                f"| `{key}` | {value:.4g} | {'<=' if smaller_is_better else '>='} {target:g} | "
                f"{verdict(value, target, smaller_is_better)} |")
        else:
            rows.append(f"| `{key}` | {value:.4g} | reported | |")
    return rows


class UnknownReference(ValueError):
    """A git ref that names no commit of the repository."""


@contextlib.contextmanager
def reference_checkout(git_ref: str, repository):
    """The code at ``git_ref`` of the git ``repository``, for A/B pairs against this code: a
    temporary worktree, and the environment (os.environ with its ``src`` first on PYTHONPATH)
    in which this workspace's executables import the reference's sources instead of the
    installed package. Its messages, configuration files and dependencies stay this
    workspace's. Removed on leaving. UnknownReference naming the ref when git does not know it."""
    repository = pathlib.Path(repository)
    found = subprocess.run(["git", "-C", str(repository), "rev-parse", "--verify", "--quiet",
                            f"{git_ref}^{{commit}}"], capture_output=True, text=True)
    if found.returncode != 0:
        raise UnknownReference(f"{git_ref}: not a commit of {repository}")
    commit = found.stdout.strip()
    parent = pathlib.Path(tempfile.mkdtemp(prefix="softgrip_reference_"))
    tree = parent / "tree"
    subprocess.run(["git", "-C", str(repository), "worktree", "add", "--detach", "--quiet",
                    str(tree), commit], check=True, capture_output=True)
    try:
        environment = dict(os.environ)
        environment["PYTHONPATH"] = os.pathsep.join(
            [str(tree / "src")] + [p for p in [os.environ.get("PYTHONPATH")] if p])
        yield commit, environment
    finally:
        subprocess.run(["git", "-C", str(repository), "worktree", "remove", "--force",
                        str(tree)], capture_output=True)
        shutil.rmtree(parent, ignore_errors=True)


def paired_rows(pairs: dict, targets: dict, names=("reference", "this code")) -> list:
    """A markdown table of A/B pairs {key: [(reference, this), ...]}: each key's medians on both
    sides, its target, and every pair in the order run."""
    rows = [f"| key | {names[0]} (median) | {names[1]} (median) | target | pairs |",
            "|---|---|---|---|---|"]
    for key, values in pairs.items():
        before = statistics.median(a for a, _ in values)
        after = statistics.median(b for _, b in values)
        target = f"<= {targets[key][0]:g}" if key in targets else "reported"
        listed = ", ".join(f"{a:.3g} -> {b:.3g}" for a, b in values)
        rows.append(f"| `{key}` | {before:.4g} | {after:.4g} | {target} | {listed} |")
    return rows
