"""One simulated clock for the whole simulated bench (the real-time one: ``gyrolab.clock``).

Simulated time (s since power-on) is advanced by a single master (the bench's tick
thread); everybody else reads it (:meth:`SimClock.now`) or waits for it
(:meth:`SimClock.sleep`, :meth:`SimClock.wait_until`). With ``speed = X`` simulated time
runs X times faster than the wall clock (``speed = 1`` is real time, the lab script's
dry run); with ``speed = None`` it runs as fast as the master can go (the master is then
throttled only by the consumers of its output, e.g. the ADC reader draining its pty).

Slipping, not leaping. When the master falls behind its schedule (the process was starved
of CPU: a loaded machine, a GC pause) by more than ``max_catch_up_s`` simulated seconds,
the clock does not race to catch up; it re-anchors and the lost wall time is never made
up. Racing would move the simulated world many seconds ahead in a burst in which nobody
else in the process — the runner included — gets to look at it: at 200x a 35 ms stall is
7 simulated seconds, and a profile step would start that late. Everything that lives on
this clock is starved together, so slipping keeps them in step; only the achieved speed
drops (``slipped_s`` counts the simulated seconds given up).
"""

from __future__ import annotations

import math
import mmap
import os
import struct
import threading
import time
from collections.abc import Callable
from pathlib import Path


class SimClock:
    """Simulated time in seconds, paced against ``time.monotonic`` (see module doc)."""

    def __init__(
        self, speed: float | None = 1.0, start_s: float = 0.0, max_catch_up_s: float | None = None
    ) -> None:
        self._cond = threading.Condition()
        self._t = float(start_s)
        self._stopped = False
        # None: always catch up (the schedule is kept whatever the stalls; see module doc).
        self.max_catch_up_s = max_catch_up_s
        self.slipped_s = 0.0  # simulated seconds of schedule given up after stalls
        # Told the time, speed and stop after every change (SharedTime.publish: a bench in
        # its own process shows its clock to the run engine's).
        self.on_change: Callable[[float, float | None, bool], None] | None = None
        self._set_speed(speed)

    def _set_speed(self, speed: float | None) -> None:
        if speed is not None and not (speed > 0 and math.isfinite(speed)):
            speed = None
        self._speed = speed
        self._anchor_wall = time.monotonic()
        self._anchor_sim = self._t
        self._changed()

    def _changed(self) -> None:
        if self.on_change is not None:
            self.on_change(self._t, self._speed, self._stopped)

    @property
    def speed(self) -> float | None:
        """Simulated seconds per wall second; None = as fast as possible."""
        return self._speed

    @speed.setter
    def speed(self, speed: float | None) -> None:
        with self._cond:
            self._set_speed(speed)

    def now(self) -> float:
        """Simulated time now, s."""
        return self._t

    @property
    def stopped(self) -> bool:
        return self._stopped

    def wall_time_for(self, t_sim: float) -> float | None:
        """``time.monotonic()`` value at which simulated time ``t_sim`` is due (paced mode)."""
        if self._speed is None:
            return None
        return self._anchor_wall + (t_sim - self._anchor_sim) / self._speed

    # ---------------------------------------------------------------- master side
    def advance_to(self, t_sim: float) -> bool:
        """Move simulated time to ``t_sim`` (master only). In paced mode, first sleep
        until that moment is due on the wall clock. Returns False once stopped."""
        due = self.wall_time_for(t_sim)
        if due is not None:
            now = time.monotonic()
            delay = due - now
            if delay > 0:
                with self._cond:  # sleep interruptibly: stop() wakes us
                    self._cond.wait_for(lambda: self._stopped, timeout=delay)
            elif self._speed is not None and self.max_catch_up_s is not None:
                behind_s = -delay * self._speed  # simulated seconds behind schedule
                if behind_s > self.max_catch_up_s:
                    with self._cond:  # slip: this step is due now, the backlog is dropped
                        self.slipped_s += behind_s
                        self._anchor_wall = now
                        self._anchor_sim = t_sim
        with self._cond:
            if self._stopped:
                return False
            if t_sim > self._t:
                self._t = t_sim
                self._changed()
            self._cond.notify_all()
        return True

    def stop(self) -> None:
        """Wake every waiter; the clock no longer advances."""
        with self._cond:
            self._stopped = True
            self._changed()
            self._cond.notify_all()

    # ---------------------------------------------------------------- waiting side
    def wait_until(self, t_sim: float, timeout_wall_s: float | None = None) -> bool:
        """Block until simulated time reaches ``t_sim``. False on stop or wall timeout."""
        with self._cond:
            ok = self._cond.wait_for(
                lambda: self._t >= t_sim or self._stopped, timeout=timeout_wall_s
            )
            return bool(ok) and self._t >= t_sim

    def sleep(self, dt_sim: float, timeout_wall_s: float | None = None) -> bool:
        """Wait ``dt_sim`` simulated seconds (the runner's ``time.sleep``)."""
        return self.wait_until(self._t + dt_sim, timeout_wall_s)


class SharedTime:
    """A :class:`SimClock` seen from another process: its time, speed and stop flag in a
    small file mapped into memory by both (``path``, in the bench's scratch directory).

    The bench's process :meth:`publish` es every change (``SimClock.on_change``); the run
    engine's reads :meth:`now` and waits with :meth:`sleep` — on the wall clock, the
    simulated interval divided by the speed, then checking again (never past a stop or
    ``timeout_wall_s``). A sequence counter, odd while a write is under way, keeps a reader
    from taking a half-written record (a seqlock)."""

    _REC = struct.Struct("<Qdd?")  # sequence, simulated s, speed (0: as fast as it goes), stopped

    def __init__(self, path: str | os.PathLike[str], create: bool = False) -> None:
        self.path = Path(path)
        if create:
            self.path.write_bytes(bytes(self._REC.size))
        with open(self.path, "r+b") as fh:
            self._mm = mmap.mmap(fh.fileno(), self._REC.size)
        self._seq = 0
        self._lock = threading.Lock()

    def publish(self, t: float, speed: float | None, stopped: bool) -> None:
        """Write the clock's state (the bench's process: its threads take turns)."""
        with self._lock:
            self._seq += 1  # odd: a write is under way
            self._mm[:8] = struct.pack("<Q", self._seq)
            self._mm[8:] = self._REC.pack(0, t, speed or 0.0, stopped)[8:]
            self._seq += 1
            self._mm[:8] = struct.pack("<Q", self._seq)

    def read(self) -> tuple[float, float | None, bool]:
        """``(simulated s, speed or None, stopped)`` as last published."""
        while True:
            seq, t, speed, stopped = self._REC.unpack(self._mm[:])
            if seq % 2 == 0 and struct.unpack("<Q", self._mm[:8])[0] == seq:
                return t, (speed or None), stopped
            time.sleep(0)

    def now(self) -> float:
        return self.read()[0]

    def sleep(self, dt_sim: float, timeout_wall_s: float | None = None) -> bool:
        """Wait until the simulated time is ``dt_sim`` later (False on stop or timeout)."""
        t, speed, stopped = self.read()
        target = t + dt_sim
        deadline = None if timeout_wall_s is None else time.monotonic() + timeout_wall_s
        while not stopped and t < target:
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                return False
            # The interval at the current speed; as fast as it goes: a millisecond.
            wait = 0.001 if speed is None else min(max((target - t) / speed, 0.0002), 0.05)
            time.sleep(wait if left is None else min(wait, left))
            t, speed, stopped = self.read()
        return t >= target

    def close(self) -> None:
        self._mm.close()

