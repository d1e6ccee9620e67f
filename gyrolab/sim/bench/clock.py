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
import threading
import time


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
        self._set_speed(speed)

    def _set_speed(self, speed: float | None) -> None:
        if speed is not None and not (speed > 0 and math.isfinite(speed)):
            speed = None
        self._speed = speed
        self._anchor_wall = time.monotonic()
        self._anchor_sim = self._t

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
            self._cond.notify_all()
        return True

    def stop(self) -> None:
        """Wake every waiter; the clock no longer advances."""
        with self._cond:
            self._stopped = True
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
