"""The line a benchmark prints first: when, on how many CPUs, at what load average (the
figures in docs/performance.md are stated with these)."""

from __future__ import annotations

import os
import platform
import time


def stamp() -> str:
    """``# YYYY-MM-DD HH:MM N CPUs, load (1 min, 5 min, 15 min)``."""
    return f"# {time.strftime('%Y-%m-%d %H:%M')} {os.cpu_count()} CPUs, load {os.getloadavg()}"


def load() -> str:
    """The load average now, ``"1min 5min 15min"`` to one decimal."""
    return "{:.1f} {:.1f} {:.1f}".format(*os.getloadavg())


def run_meta(t0: float, load_before: str) -> dict[str, object]:
    """A cached benchmark run's when, where and how long (``t0``: its
    ``time.perf_counter()`` start; ``load_before``: :func:`load` then)."""
    return {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "machine": f"{platform.machine()} {os.cpu_count()} cores, Python "
        f"{platform.python_version()}",
        "wall_s": time.perf_counter() - t0,
        "load": f"{load_before} before, {load()} after",
    }
