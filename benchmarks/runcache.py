"""Cached benchmark runs, kept in the repository: gzip-compressed compact JSON.

``save(stem, obj)`` writes ``<stem>.json.gz`` (no whitespace, gzip header time 0, so the
same run always gives the same bytes and git stores it once), atomically through
:func:`gyrolab.outputs.atomic_file`; ``load(stem)`` reads ``<stem>.json.gz`` or, for runs
cached before, the plain ``<stem>.json``. The break suite's 38 cached runs took 14.7 MB as
pretty-printed JSON and take 2.5 MB so (17 %), the prior suite's tables 231 kB → 37 kB,
every one loading equal to its original (``break_suite.py``, ``prior_suite.py``).
"""

from __future__ import annotations

import gzip
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gyrolab.outputs import atomic_file


def path_of(stem: Path) -> Path:
    """The cache file of ``stem`` (a path without suffix): ``.json.gz``, else the
    ``.json`` of an older run; the ``.json.gz`` name when neither exists."""
    gz, plain = stem.with_name(stem.name + ".json.gz"), stem.with_name(stem.name + ".json")
    return plain if plain.exists() and not gz.exists() else gz


def load(stem: Path) -> Any:
    """The cached object of ``stem`` (``FileNotFoundError`` naming the file if none)."""
    p = path_of(stem)
    if p.suffix == ".gz":
        return json.loads(gzip.decompress(p.read_bytes()))
    return json.loads(p.read_text(encoding="utf-8"))


def encode(obj: Any, default: Callable[[Any], Any] = float) -> bytes:
    """``obj`` as compact JSON (what JSON lacks through ``default``: numpy scalars through
    ``float``), gzip level 9, mtime 0."""
    text = json.dumps(obj, separators=(",", ":"), ensure_ascii=False, default=default)
    return gzip.compress(text.encode("utf-8"), compresslevel=9, mtime=0)


def save(stem: Path, obj: Any, default: Callable[[Any], Any] = float) -> Path:
    """Write ``obj`` to ``<stem>.json.gz`` atomically (replacing an earlier run); a plain
    ``<stem>.json`` beside it is left alone and no longer read."""
    out = stem.with_name(stem.name + ".json.gz")
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(out, force=True) as tmp:
        tmp.write_bytes(encode(obj, default))
    return out
