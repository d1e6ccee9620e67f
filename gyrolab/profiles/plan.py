"""The one interpreter of a profile: :class:`ProfilePlan`, used by ``acquire`` and ``simulate``.

A pure state machine over the profile (Bluesky-style plan: it never touches a port and has
no clock of its own). Fed the run time and the PT100 readings, it says what to do: command
a setpoint, emit an event, log. Each step starts by commanding its setpoint and is held
at least ``duration_s``; a step with a stability rule is then held until the PT100 is
stable, at most ``max_extra_s`` more (then it moves on with a warning). The first step is
the power-on soak.

**The stability rule** (docs/profiles.md): the readings of the step taken in the last
``stable_window_s`` seconds, judged only once they span at least 0.9 of the window
(:data:`WINDOW_FILL`) and number three or more; stable when the least-squares slope of
°C against s (:func:`slope_c_per_min`) is below ``stable_slope_c_per_min`` in magnitude.

**When a step ends** (on the run clock, never when the caller got round to looking):
``start + duration_s`` for a time-only step; for a stability step, the later of
``start + duration_s`` and the time of the reading that showed it stable, or
``start + duration_s + max_extra_s`` when it never was. The next step starts at that time,
so the caller's reaction time never accumulates over a profile. :meth:`ProfilePlan.wake_at`
says when the plan must be asked again without a new reading (``simulate`` cuts its sample
blocks there; the acquisition engine asks on every turn anyway).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from gyrolab.errors import InputError
from gyrolab.profiles.profile import Profile, Step

#: A stability window is judged only once its readings span this fraction of it.
WINDOW_FILL = 0.9


@dataclass(frozen=True)
class SetSetpoint:
    setpoint_c: float


@dataclass(frozen=True)
class Event:
    event: str
    step: int = -1
    setpoint_c: float | None = None
    detail: str = ""
    # Run time the event happened at, on the run clock (None: when the engine records it).
    t: float | None = None


@dataclass(frozen=True)
class Log:
    level: str
    message: str
    kind: str = ""
    data: dict[str, Any] = field(default_factory=dict)


Action = SetSetpoint | Event | Log


class SetpointLimits(Protocol):
    """The bench's setpoint range (``gyrolab.acquisition.bench_config.Limits`` has it)."""

    setpoint_min_c: float
    setpoint_max_c: float


def check_profile_limits(profile: Profile, limits: SetpointLimits, source: str = "profile") -> None:
    """Refuse a profile whose setpoints are outside the bench's limits (before any I/O)."""
    for i, s in enumerate(profile.steps):
        if not limits.setpoint_min_c <= s.setpoint_c <= limits.setpoint_max_c:
            raise InputError(
                source,
                f"step {i + 1} setpoint {s.setpoint_c:g} °C is outside the bench limits "
                f"[{limits.setpoint_min_c:g}, {limits.setpoint_max_c:g}] °C",
            )


def slope_c_per_min(t: np.ndarray, c: np.ndarray) -> float:
    """Least-squares slope of ``c`` (°C) against ``t`` (s), in °C/min (inf: < 3 points)."""
    if t.size < 3 or t[-1] - t[0] <= 0:
        return math.inf
    tt = t - t.mean()
    return float(60.0 * np.dot(tt, c - c.mean()) / np.dot(tt, tt))


class ProfilePlan:
    """The profile as a state machine: ``idle`` → ``step`` (each) → ``done``.

    Pure: no I/O and no clock of its own; :meth:`start` and :meth:`update` return the
    actions for the caller to carry out. Times are run seconds.
    """

    def __init__(self, profile: Profile) -> None:
        self.profile = profile
        self.state = "idle"
        self.step_index = -1
        self.step_started_at = math.nan
        self.ended_at = math.nan  # run time the profile was complete
        self.soaked = False
        self.held_at: float | None = None  # run time the profile was held (a suspension)
        self._hist: deque[tuple[float, float]] = deque()
        self._t_last = -math.inf  # run time of the latest update

    @property
    def step(self) -> Step | None:
        if 0 <= self.step_index < len(self.profile.steps):
            return self.profile.steps[self.step_index]
        return None

    def start(self, t: float, first_step: int = 0, resumed: str = "") -> list[Action]:
        """Start at run time ``t`` with step ``first_step``. ``resumed`` (a continuation of
        an interrupted run, gyrolab acquire --resume: what it continues): the run resumes
        there instead of starting (``run_resumed``) and that step, which was running when
        the run was interrupted, is soaked again from its beginning."""
        if self.state != "idle":
            raise RuntimeError("plan already started")
        if not 0 <= first_step < len(self.profile.steps):
            raise ValueError(f"no step {first_step} in profile {self.profile.name}")
        if resumed:
            acts: list[Action] = [Event("run_resumed", first_step, detail=resumed, t=t)]
            return acts + self._begin(first_step, t, " (re-soak)")
        acts = [Event("run_started", detail=f"profile {self.profile.name}", t=t)]
        acts += self._begin(first_step, t)
        return acts

    def _begin(self, i: int, t: float, again: str = "") -> list[Action]:
        self.state = "step"
        self.step_index = i
        self.step_started_at = t
        self.soaked = False
        self._hist.clear()
        s = self.profile.steps[i]
        label = (s.label or ("power-on" if i == 0 else f"{s.setpoint_c:g} C")) + again
        return [
            SetSetpoint(s.setpoint_c),
            Event("step_started", i, s.setpoint_c, label, t=t),
            Log(
                "info",
                f"step {i + 1}/{len(self.profile.steps)} ({label}): setpoint {s.setpoint_c:g} °C",
                "transition",
                {"step_start_t": round(t, 6)},
            ),
        ]

    def hold(self, t: float, why: str) -> list[Action]:
        """Hold the profile at run time ``t`` (a suspension, ``why``): the step's clock
        stops and its setpoint stays; :meth:`update` does nothing until :meth:`resume`."""
        s = self.step
        if self.state != "step" or self.held_at is not None or s is None:
            return []
        self.held_at = t
        return [Event("suspended", self.step_index, s.setpoint_c, why, t=t)]

    def resume(self, t: float, resoak: bool) -> list[Action]:
        """Go on at run time ``t`` after a hold. The held step either goes on for what it
        had left (its start moves by the time held; its stability window starts afresh)
        or, ``resoak`` (the temperature left its band while held), starts again: its
        whole duration and stability rule from ``t``. Either way its setpoint is
        commanded again (a chamber that stopped on an alarm needs it)."""
        s = self.step
        if self.held_at is None or s is None:
            return []
        held = t - self.held_at
        self.held_at = None
        if self.state != "step":
            return []
        how = "the step re-soaks" if resoak else "the step goes on"
        acts: list[Action] = [
            Event("resumed", self.step_index, s.setpoint_c, f"held {held:.0f} s; {how}", t=t)
        ]
        if resoak:
            return acts + self._begin(self.step_index, t, " (re-soak)")
        self.step_started_at += held
        self._hist.clear()
        return acts + [SetSetpoint(s.setpoint_c)]

    def _due(self, s: Step) -> float:
        # the one expression of the minimum duration's end (wake_at and update agree on it)
        return self.step_started_at + s.duration_s

    def wake_at(self) -> float:
        """The next run time at which the current step can end without a new reading:
        the end of its minimum duration, then (stability rule) the end of ``max_extra_s``.
        ``update(wake_at())`` at that time ends the step or moves this on; inf when done."""
        s = self.step
        if self.state != "step" or s is None or self.held_at is not None:
            return math.inf
        due = self._due(s)
        if s.stable_slope_c_per_min is None or self._t_last < due:
            return due
        return due + s.max_extra_s

    def update(self, t: float, pt100_c: float | None = None) -> list[Action]:
        """Advance to time ``t``, optionally with a new PT100 reading (°C) taken at ``t``.

        A step that ends is ended at the run time its rule was met (module docstring), which
        may be earlier than ``t`` when ``update`` is called late; its events carry that time
        and the next step starts then."""
        if self.state != "step" or self.held_at is not None:
            return []
        self._t_last = max(self._t_last, t)
        s = self.profile.steps[self.step_index]
        # A reading taken before this step began (delivered late) says nothing about it.
        if pt100_c is not None and math.isfinite(pt100_c) and t >= self.step_started_at:
            self._hist.append((t, pt100_c))
            keep = s.stable_window_s if s.stable_slope_c_per_min is not None else 0.0
            while self._hist and self._hist[0][0] < t - keep:
                self._hist.popleft()
        due = self._due(s)
        if t < due:
            return []
        acts: list[Action] = []
        if s.stable_slope_c_per_min is not None:
            stable, slope = self._stable(s)
            if not stable and t < due + s.max_extra_s:
                return []
            if stable:
                # Met when the last reading of the window was taken (or when the minimum
                # duration ran out, if it was stable before that).
                t_end = min(t, max(due, self._hist[-1][0]))
            else:
                t_end = min(t, due + s.max_extra_s)
            held = t_end - self.step_started_at
            if stable:
                detail = f"held {held:.0f} s; PT100 slope {slope:+.4f} °C/min"
            else:
                detail = f"held {held:.0f} s; NOT stable (slope {slope:+.4f} °C/min)"
                acts.append(
                    Log(
                        "warning",
                        f"step {self.step_index + 1}: stability rule not met "
                        f"after max_extra_s={s.max_extra_s:g} s; moving on",
                        "stability",
                        {"slope_c_per_min": slope},
                    )
                )
        else:
            t_end = due
            detail = f"held {s.duration_s:.0f} s"
        acts.append(Event("soaked", self.step_index, s.setpoint_c, detail, t=t_end))
        acts.append(Event("step_ended", self.step_index, s.setpoint_c, t=t_end))
        if self.step_index + 1 < len(self.profile.steps):
            acts += self._begin(self.step_index + 1, t_end)
        else:
            self.state = "done"
            self.ended_at = t_end
            acts.append(Event("run_ended", detail="profile complete", t=t_end))
            acts.append(Log("info", "profile complete", "transition"))
        return acts

    def _stable(self, s: Step) -> tuple[bool, float]:
        """The stability rule (module docstring) on the step's readings in the window."""
        if not self._hist:
            return False, math.inf
        a = np.asarray(self._hist, dtype=float)
        # Only judge a window that is (nearly) full of readings.
        if a[-1, 0] - a[0, 0] < WINDOW_FILL * s.stable_window_s:
            return False, math.inf
        slope = slope_c_per_min(a[:, 0], a[:, 1])
        assert s.stable_slope_c_per_min is not None
        return abs(slope) < s.stable_slope_c_per_min, slope

    def abort(self) -> None:
        self.state = "aborted"

    def remaining_s(self, t: float) -> float:
        """Nominal run seconds left (time rule only)."""
        if self.state == "idle":
            return self.profile.duration_s
        if self.state != "step":
            return 0.0
        steps = self.profile.steps
        t = t if self.held_at is None else self.held_at  # held: its clock stopped
        cur = max(0.0, steps[self.step_index].duration_s - (t - self.step_started_at))
        return cur + sum(s.duration_s for s in steps[self.step_index + 1 :])
