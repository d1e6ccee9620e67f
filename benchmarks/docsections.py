"""Marked sections of a docs page that a benchmark script owns and rewrites.

A script writes its text between ``<!-- NAME:begin -->`` and ``<!-- NAME:end -->``; the
rest of the page (other scripts' sections, hand-written text) is left as it is. A page
without the markers gets the section appended at its end.
"""

from __future__ import annotations

import os
from pathlib import Path


def write_section(path: Path, name: str, body: str) -> None:
    """Replace section ``name`` of the page ``path`` with ``body`` (atomically)."""
    start, end = f"<!-- {name}:begin -->", f"<!-- {name}:end -->"
    text = path.read_text() if path.exists() else ""
    block = f"{start}\n{body.strip()}\n{end}"
    if start in text and end in text:
        a, rest = text.split(start, 1)
        _, b = rest.split(end, 1)
        text = a + block + b
    else:
        text = text.rstrip() + "\n\n" + block + "\n"
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)
