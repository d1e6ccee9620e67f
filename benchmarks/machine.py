"""The line a benchmark prints first: when, on how many CPUs, at what load average (the
figures in docs/performance.md are stated with these)."""

from __future__ import annotations

import os
import time


def stamp() -> str:
    """``# YYYY-MM-DD HH:MM N CPUs, load (1 min, 5 min, 15 min)``."""
    return f"# {time.strftime('%Y-%m-%d %H:%M')} {os.cpu_count()} CPUs, load {os.getloadavg()}"
