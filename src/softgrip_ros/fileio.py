"""Writing the files the tools produce, whole or not at all; and reading YAML input with a
one-line error.

Every file a tool writes goes through :func:`replacing` (or :func:`write_text_atomically`): the
content is written to a temporary file beside the target, flushed to disk, then renamed over the
target, so that a reader sees the old file or the new one, never half of one, and a failure
leaves the old one as it was. :func:`check_writable_directory` lets a tool find out before a
long computation that it could not write its result, without making anything. Errors are
:class:`OutputError`, whose message is one line naming the path. :func:`read_yaml` reads an input
file and refuses one it cannot read or parse with a one-line ValueError.
"""
from __future__ import annotations

import contextlib
import os
import pathlib


class OutputError(OSError):
    """A file or directory could not be written; the message names it and says why."""


def _why(error: OSError) -> str:
    return error.strerror or str(error)


def check_writable_directory(directory) -> pathlib.Path:
    """``directory`` if a file could be written in it, making nothing: it exists and takes a
    file, or its nearest existing ancestor is a directory this process may write in.
    OutputError if not."""
    directory = pathlib.Path(directory)
    try:
        if directory.is_dir():
            probe = directory / f".softgrip-write-probe-{os.getpid()}"
            probe.touch()
            probe.unlink()
            return directory
        ancestor = directory
        while not ancestor.exists():
            ancestor = ancestor.parent
        if not ancestor.is_dir():
            raise NotADirectoryError(20, f"{ancestor} is not a directory")
        if not os.access(ancestor, os.W_OK | os.X_OK):
            raise PermissionError(13, f"{ancestor} is not writable")
    except OSError as error:
        raise OutputError(f"cannot write in {directory}: {_why(error)}") from None
    return directory


@contextlib.contextmanager
def replacing(path):
    """A temporary path beside ``path`` to write the new content to; on leaving without an
    exception it is flushed to disk and renamed over ``path``, otherwise removed. Its parent
    directory is made if missing. OutputError for what the file system refused."""
    path = pathlib.Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise OutputError(f"cannot write in {path.parent}: {_why(error)}") from None
    # the suffix kept last, for writers that choose the format by it (matplotlib)
    temporary = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    try:
        yield temporary
        with open(temporary, "rb+") as stream:
            os.fsync(stream.fileno())
        os.replace(temporary, path)
    except OSError as error:
        raise OutputError(f"cannot write {path}: {_why(error)}") from None
    finally:
        with contextlib.suppress(FileNotFoundError):
            temporary.unlink()


def write_text_atomically(path, text: str) -> pathlib.Path:
    """Write ``text`` to ``path`` whole or not at all (see :func:`replacing`)."""
    path = pathlib.Path(path)
    with replacing(path) as temporary:
        temporary.write_text(text)
    return path


def read_yaml(path):
    """The YAML document in ``path`` (None if empty). ValueError, in one line naming the path,
    if it cannot be read or is not YAML (with where the parser stopped)."""
    import yaml

    path = pathlib.Path(path)
    try:
        text = path.read_text()
    except OSError as error:
        raise ValueError(f"{path}: cannot read: {_why(error)}") from None
    except UnicodeDecodeError:
        raise ValueError(f"{path}: cannot read: not UTF-8 text") from None
    try:
        return yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
    except yaml.YAMLError as error:
        problem = getattr(error, "problem", None) or "cannot parse"
        mark = getattr(error, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        raise ValueError(f"{path}: not YAML: {' '.join(str(problem).split())}{where}") from None
