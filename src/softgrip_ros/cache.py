"""Results worth keeping between runs, each a JSON file under the user's cache directory
(``$XDG_CACHE_HOME/softgrip_ros/<kind>/<key>.json``, default ``~/.cache``).

A key is a hash of everything the result depends on (:func:`key_of`), so a changed input or
changed code makes a new key and the stale file is never read. A cached file that does not parse
is treated as absent, recomputed and overwritten; a write goes through
:func:`softgrip_ros.fileio.write_text_atomically`, so a reader never sees half of one.
"""
from __future__ import annotations

import hashlib
import json
import os
import pathlib

from softgrip_ros.fileio import write_text_atomically


def cache_dir(kind: str) -> pathlib.Path:
    """The directory of the cached results of ``kind`` (made only when one is written)."""
    root = os.environ.get("XDG_CACHE_HOME") or pathlib.Path.home() / ".cache"
    return pathlib.Path(root) / "softgrip_ros" / kind


def key_of(document: dict, digits: int = 16) -> str:
    """``digits`` hex digits of the SHA-256 of ``document`` as sorted JSON (values JSON cannot
    hold, by their ``str``)."""
    text = json.dumps(document, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:digits]


def source_digest(*modules) -> str:
    """A hash of the source files of ``modules``: part of a key whose result their code
    computes."""
    digest = hashlib.sha256()
    for module in modules:
        digest.update(pathlib.Path(module.__file__).read_bytes())
    return digest.hexdigest()[:16]


def read_cache(kind: str, key: str, parse):
    """``parse(document)`` of the cached result ``key``, or None if there is none, it cannot be
    read or ``parse`` refuses it (ValueError, KeyError or TypeError)."""
    cached = cache_dir(kind) / f"{key}.json"
    try:
        return parse(json.loads(cached.read_text()))
    except (OSError, ValueError, KeyError, TypeError):
        return None


def write_cache(kind: str, key: str, document: dict) -> None:
    """Store ``document`` as result ``key``, whole or not at all; OutputError (an OSError) if the
    cache directory cannot be written."""
    write_text_atomically(cache_dir(kind) / f"{key}.json", json.dumps(document))
