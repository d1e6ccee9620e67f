"""The run's time base: the :class:`Clock` protocol and the real one, :class:`WallClock`.

A floor module: the lab run engine (``gyrolab.acquisition.runner``) runs on a Clock, the
simulated bench supplies its own (``gyrolab.app.sim_bench``), tests a fake one.
"""

from __future__ import annotations

import time
from typing import Protocol


class Clock(Protocol):
    """Seconds on a monotonic timeline shared with the instruments."""

    def now(self) -> float: ...

    def sleep(self, dt: float) -> None: ...


class WallClock:
    """Real time (the lab): ``time.monotonic`` seconds."""

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, dt: float) -> None:
        if dt > 0:
            time.sleep(dt)
