"""Reading the project's TOML files (profiles, bench configurations, simulator models)."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

from gyrolab.errors import InputError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


def read_toml(path: str | os.PathLike[str], what: str = "file") -> dict[str, Any]:
    """The table of a TOML file; ``InputError`` naming the file if missing or invalid.

    ``what`` names the kind of file in the "not found" message (e.g. ``"profile file"``).
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(path, f"{what} not found")
    try:
        return tomllib.loads(p.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise InputError(path, f"not valid TOML: {e}") from None
