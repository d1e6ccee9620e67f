"""The hashes the catalogue keys things by: SHA-256 of a file's bytes, ``sha256:<hex>``."""

from __future__ import annotations

import hashlib
import os

PREFIX = "sha256:"
_CHUNK = 1 << 20


def file_digest(path: str | os.PathLike[str]) -> str:
    """``sha256:<hex>`` of the file's bytes (read in 1 MiB pieces: bounded memory)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            h.update(chunk)
    return PREFIX + h.hexdigest()


def short(digest: str | None, n: int = 12) -> str:
    """The first ``n`` hex digits of a digest, for people (``—`` for none)."""
    return digest.split(":")[-1][:n] if digest else "—"
