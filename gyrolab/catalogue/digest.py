"""The hashes the catalogue keys things by: SHA-256 of a file's bytes, ``sha256:<hex>``."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

PREFIX = "sha256:"
_CHUNK = 1 << 20


def file_digest(path: str | os.PathLike[str]) -> str:
    """``sha256:<hex>`` of the file's bytes (read in 1 MiB pieces: bounded memory)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            h.update(chunk)
    return PREFIX + h.hexdigest()


def model_digest(model_dir: str | os.PathLike[str]) -> str:
    """A model directory's identity: the SHA-256 of its ``model.json`` (which holds every
    setting and no clock reading: the same fit gives the same bytes); for a 2–3-axis model,
    of the head ``model.json`` followed by each axis's, in the head's order."""
    head = Path(model_dir) / "model.json"
    data = head.read_bytes()
    try:
        axis_dirs = json.loads(data).get("axis_dirs")
    except (ValueError, AttributeError):
        axis_dirs = None
    if not isinstance(axis_dirs, list):
        return PREFIX + hashlib.sha256(data).hexdigest()
    h = hashlib.sha256(data)
    for name in axis_dirs:
        h.update((Path(model_dir) / str(name) / "model.json").read_bytes())
    return PREFIX + h.hexdigest()


def short(digest: str | None, n: int = 12) -> str:
    """The first ``n`` hex digits of a digest, for people (``—`` for none)."""
    return digest.split(":")[-1][:n] if digest else "—"
