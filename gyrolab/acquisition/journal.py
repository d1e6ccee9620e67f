"""The run's account of what happened: its ``/log`` messages, its fault count, and the
fault that ends it.

Every part of the run engine (the runner, the temperature intake, the communication
watchdog, the suspenders, the safe-state shutdown) reports through one :class:`Journal`,
so a fault is counted once, in one place, and the first fault that must end the run is the
one its result names.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any


class Journal:
    """``/log`` on the run clock (``now()``: run seconds) and the run's fault account:
    ``faults`` counts every fault logged; ``reason`` is the first fault that ends the run
    (None while nothing has)."""

    def __init__(self, writer: Any, now: Callable[[], float]) -> None:
        self.w = writer
        self.now = now
        self.faults = 0
        self.reason: str | None = None

    def log(
        self,
        level: str,
        source: str,
        message: str,
        kind: str = "",
        data: dict[str, Any] | None = None,
        t: float | None = None,
    ) -> None:
        """One ``/log`` message at run time ``t`` (default: now)."""
        self.w.write_log(self.now() if t is None else t, level, source, message, kind, data)

    def fault(
        self,
        level: str,
        source: str,
        message: str,
        kind: str = "fault",
        data: dict[str, Any] | None = None,
        t: float | None = None,
    ) -> None:
        """A fault the run survives (so far): counted and logged."""
        self.faults += 1
        self.log(level, source, message, kind, data, t)

    def fail(self, source: str, message: str, t: float | None = None) -> None:
        """A fault that ends the run (the first one only: later ones are consequences)."""
        if self.reason is None:
            self.fault("fault", source, message, t=t)
            self.reason = f"{source}: {message}"

    def end(self, reason: str) -> None:
        """End the run for ``reason`` (already logged by the caller), unless a fault
        already does."""
        if self.reason is None:
            self.reason = reason
