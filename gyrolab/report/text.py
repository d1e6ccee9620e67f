"""Numbers, times and metadata as the report's tables show them."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def fmt(x: Any, digits: int = 4) -> str:
    """A number for a table: ``digits`` significant digits, '—' for missing/NaN."""
    if x is None:
        return "—"
    if isinstance(x, (int, np.integer)) and not isinstance(x, bool):
        return str(int(x))
    try:
        v = float(x)
    except (TypeError, ValueError):
        return str(x)
    if not math.isfinite(v):
        return "—"
    return f"{v:.{digits}g}"


def hms(t: float) -> str:
    """Seconds since run start as ``h:mm:ss``."""
    t = max(0.0, float(t))
    h, rem = divmod(int(round(t)), 3600)
    m, s = divmod(rem, 60)
    return f"{h}:{m:02d}:{s:02d}"


def flatten(d: Any, prefix: str = "") -> list[tuple[str, str]]:
    """Nested metadata as ``(dotted.key, value)`` rows (lists of scalars joined)."""
    rows: list[tuple[str, str]] = []
    if isinstance(d, dict):
        for k, v in d.items():
            rows.extend(flatten(v, f"{prefix}.{k}" if prefix else str(k)))
    elif isinstance(d, list) and d and all(isinstance(v, dict) for v in d):
        for i, v in enumerate(d):
            rows.extend(flatten(v, f"{prefix}[{i}]"))
    elif isinstance(d, list):
        rows.append((prefix, ", ".join(str(v) for v in d)))
    else:
        rows.append((prefix, "" if d is None else str(d)))
    return rows


def dotted(d: dict[str, Any], path: str) -> dict[str, Any]:
    """The dict at a dotted key path (``baselines.poly``); ``{}`` when missing."""
    v: Any = d
    for p in path.split("."):
        v = v.get(p, {}) if isinstance(v, dict) else {}
    return v if isinstance(v, dict) else {}
