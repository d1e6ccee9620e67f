"""The engine's device side: one poller per instrument, one reader per rate stream.

Each runs in its own thread during a lab run (``Acquisition(threaded=True)``), or is
stepped by the engine's own loop, one turn at a time, on any clock
(``Acquisition(threaded=False)``: ``tests/test_run_core.py`` drives it with a fake clock).
Neither interprets what it gets: every result or failure is posted to the engine's queue
as ``(kind, source, clock time, payload)`` (kinds: ``reading``, ``command``, ``stream``,
``error`` — retried —, ``fatal``, ``report``), classified by
:func:`gyrolab.instruments.roles.is_transient`.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from gyrolab.clock import Clock
from gyrolab.instruments.roles import RateStream, is_transient


@dataclass(frozen=True)
class UnitDevices:
    """One unit of a multi-unit run: its ``serial``, its connected rate ``stream`` (whose
    ``name`` is its source in /log, ``unit/<serial>``), the stream's config ``rate_stream`` and the
    scanner ``channel`` of its PT100 — None for a unit read by its internal sensor, whose
    stream delivers its temperature (``AdcBlock.temperature_c``)."""

    serial: str
    stream: RateStream
    rate_stream: Any
    channel: int | None

    @property
    def internal(self) -> bool:
        return self.channel is None


class Poller(threading.Thread):
    """Calls ``op`` every ``period`` run seconds and posts results or failures."""

    def __init__(
        self,
        name: str,
        op: Callable[[], Any],
        period: float,
        clock: Clock,
        post: Callable[[tuple[Any, ...]], None],
        stop: threading.Event,
        commands: queue.Queue[Callable[[], Any]] | None = None,
        reports: Callable[[], list[Any]] | None = None,
    ) -> None:
        super().__init__(name=f"poll-{name}", daemon=True)
        self.source = name
        self.reports = reports  # errors the instrument reported (InstrumentReport)
        self.op = op
        self.period = period
        self.clock = clock
        self.post = post
        self.stop_ev = stop
        self.commands = commands
        self._nxt: float | None = None
        self._pending: Callable[[], Any] | None = None

    def step(self) -> float:
        """One pass: the pending command, then the reading if it is due; returns the run
        clock time of the next reading (the thread waits for it; the single-threaded
        engine, ``Acquisition(threaded=False)``, calls this on every turn)."""
        if self._nxt is None:
            self._nxt = self.clock.now()
        # Commands (setpoints) go first: they share the port with the polls. A newer
        # setpoint supersedes an older one; a failed one is retried every period.
        while self.commands is not None:
            try:
                self._pending = self.commands.get_nowait()
            except queue.Empty:
                break
        if self._pending is not None and self._call(self._pending, "command"):
            self._pending = None
        if self.clock.now() >= self._nxt:  # not when woken early by a new command
            self._call(self.op, "reading")
            self._nxt += self.period
            now = self.clock.now()
            if self._nxt < now:  # fell behind (slow instrument): skip, don't burst
                self._nxt = now
        return self._nxt

    def run(self) -> None:
        while not self.stop_ev.is_set():
            self._wait(self.step())

    def _call(self, fn: Callable[[], Any], what: str) -> bool:
        t = self.clock.now()
        try:
            res = fn()
        except Exception as e:
            # roles.is_transient: a failed exchange is retried at the next poll; a refused
            # setting (LimitError), a fault or a bug ends the run.
            kind = "error" if is_transient(e) else "fatal"
            self.post((kind, self.source, t, f"{what} failed: {type(e).__name__}: {e}"))
            return False
        finally:
            self._post_reports()
        self.post((what, self.source, self.clock.now(), res))
        return True

    def _post_reports(self) -> None:
        if self.reports is None:
            return
        try:
            reps = self.reports()
        except Exception:  # reporting must never break polling
            return
        for r in reps:
            self.post(("report", self.source, self.clock.now(), r))

    def _wait(self, until: float) -> None:
        # Sleep in slices so that a stop request is honoured promptly, and so that a new
        # command (the next step's setpoint) goes out at once, not at the next poll, up to
        # a period later.
        while not self.stop_ev.is_set():
            if self.commands is not None and not self.commands.empty():
                return
            dt = until - self.clock.now()
            if dt <= 0:
                return
            self.clock.sleep(min(dt, 0.5))


# A stream reader's shortest wall time between the reads that bring data. A real stream
# (an ADC's 10 frames/s, an IMU's 25 messages/s) sends less often than this, so each of its
# frames is still read as it arrives; a simulated bench at 300x delivers a simulated
# second every 3.3 ms, and a read per delivery (8 units: 2 400 reads, posts and recorded
# blocks a wall second) was a large part of the run engine's CPU (docs/performance.md).
# Data waits at most this long in the port's buffer, none is lost.
READ_MIN_INTERVAL_S = 0.01


class StreamReader(threading.Thread):
    """Reads the ADC stream continuously and posts what arrives (at most one read that
    brings data per ``READ_MIN_INTERVAL_S`` of wall time)."""

    def __init__(
        self,
        dev: RateStream,
        post: Callable[[tuple[Any, ...]], None],
        stop: threading.Event,
        clock: Clock,
    ) -> None:
        super().__init__(name="rate_stream", daemon=True)
        self.dev, self.post, self.stop_ev, self.clock = dev, post, stop, clock
        self.failed = False

    def step(self, timeout_s: float = 0.05) -> bool:
        """One read; False after a failure (a fatal one sets ``failed``)."""
        try:
            got = self.dev.read(timeout_s)
        except Exception as e:
            if not is_transient(e):
                msg = f"{type(e).__name__}: {e}"
                self.post(("fatal", self.dev.name, self.clock.now(), msg))
                self.failed = True
                return False
            self.post(("error", self.dev.name, self.clock.now(), f"{type(e).__name__}: {e}"))
            return False
        if got.blocks or got.events or got.gaps:
            self.post(("stream", self.dev.name, self.clock.now(), got))
        return True

    def run(self) -> None:
        last = -READ_MIN_INTERVAL_S
        while not self.stop_ev.is_set() and not self.failed:
            # after a read, the next no sooner than READ_MIN_INTERVAL_S after it
            rest = last + READ_MIN_INTERVAL_S - time.monotonic()
            if rest > 0:
                time.sleep(rest)
            last = time.monotonic()
            if not self.step() and not self.failed:
                time.sleep(0.05)


def instrument_pollers(
    instruments: list[tuple[Any, float, queue.Queue[Callable[[], Any]] | None]],
    clock: Clock,
    post: Callable[[tuple[Any, ...]], None],
    stop: threading.Event,
) -> list[Poller]:
    """One :class:`Poller` per ``(instrument, period, commands)`` (an instrument None is
    left out: no thermometer when every unit is read by its internal sensor); each polls
    ``instrument.read`` and takes its ``reports``."""
    return [
        Poller(
            dev.name,
            dev.read,
            period,
            clock,
            post,
            stop,
            commands,
            reports=getattr(dev, "reports", None),
        )
        for dev, period, commands in instruments
        if dev is not None
    ]
