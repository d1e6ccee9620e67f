"""What the run engine reports: :class:`Status` snapshots while it runs (the progress
line, the live view's ``/live/status``) and :class:`RunResult` when it ends."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any


@dataclass
class UnitStatus:
    """One unit of a multi-unit run in a :class:`Status`: ``state`` is ``recording``,
    ``pt100_lost`` (its PT100 channel reads overload: its rate is still recorded) or
    ``dropped`` (its rate stream was given up)."""

    serial: str
    state: str = "recording"
    temperature_c: float = math.nan  # its last reading: PT100, or its internal sensor
    samples: int = 0
    frames_lost: int = 0
    frames_bad: int = 0


@dataclass
class Status:
    """A snapshot for the progress display. ``temperature_c`` is the temperature the
    profile's stability rule watches (a multi-unit run: the first unit's), read by
    ``temperature_source`` (``pt100`` or ``internal``: the unit's own sensor); NaN while
    that sensor gives no reading. ``units``: a multi-unit run's, in bench order.
    ``suspended``: the conditions holding the run now (gyrolab/acquisition/suspend.py),
    empty while it runs."""

    t: float = 0.0
    step: int = -1
    n_steps: int = 0
    setpoint_c: float = math.nan
    chamber_c: float = math.nan
    temperature_c: float = math.nan
    temperature_source: str = "pt100"
    remaining_s: float = math.nan
    frames_lost: int = 0
    frames_bad: int = 0
    samples: int = 0
    units: list[UnitStatus] = field(default_factory=list)
    suspended: list[str] = field(default_factory=list)

    def update(self, t: float, plan: Any, temps: Any, recorders: Iterable[Any]) -> None:
        """This snapshot at run time ``t``: the ``plan``'s step
        (:class:`~gyrolab.profiles.plan.ProfilePlan`), the temperatures of the run's
        intake (:class:`~gyrolab.acquisition.temperature.TemperatureIntake`), each rate
        stream's counts (its :class:`~gyrolab.acquisition.streams.RateRecorder`)."""
        self.t = t
        self.step = plan.step_index
        self.setpoint_c = plan.step.setpoint_c if plan.step else math.nan
        self.remaining_s = plan.remaining_s(t)
        self.temperature_c = temps.plan_c
        self.frames_lost = self.frames_bad = self.samples = 0
        self.units = []
        for rec in recorders:
            c = rec.dev.counters()
            lost, bad = int(c.get("frames_lost", 0)), int(c.get("frames_bad", 0))
            self.frames_lost += lost
            self.frames_bad += bad
            self.samples += rec.samples
            if rec.unit is not None:
                lost_pt = temps.lost(rec.unit)
                state = "dropped" if rec.dropped else "pt100_lost" if lost_pt else "recording"
                c_now = temps.unit_c(rec.unit)
                self.units.append(UnitStatus(rec.unit, state, c_now, rec.samples, lost, bad))

    @property
    def pt100_c(self) -> float:
        """The watched temperature if it is a PT100's (NaN for an internal sensor's)."""
        return self.temperature_c if self.temperature_source == "pt100" else math.nan


@dataclass
class RunResult:
    """How a run ended."""

    outcome: str  # "completed" | "interrupted" | "fault"
    reason: str
    t_end: float
    samples: int
    gaps: int
    samples_missing: int
    duplicates_dropped: int
    faults: int
    safe_state_ok: bool
    first_device_index: int | None = None
    units_dropped: list[str] = field(default_factory=list)  # multi-unit: streams given up
    suspensions: int = 0  # times the run was held (gyrolab/acquisition/suspend.py)

    @classmethod
    def of(
        cls,
        outcome: str,
        reason: str,
        t_end: float,
        recorders: Sequence[Any],
        faults: int,
        safe_state_ok: bool,
    ) -> RunResult:
        """The result of a run that recorded its rate streams with ``recorders``
        (:class:`~gyrolab.acquisition.streams.RateRecorder`, the first one the first
        unit's) and logged ``faults`` faults besides theirs."""
        return cls(
            outcome=outcome,
            reason=reason,
            t_end=t_end,
            samples=sum(r.samples for r in recorders),
            gaps=sum(r.gaps for r in recorders),
            samples_missing=sum(r.missing for r in recorders),
            duplicates_dropped=sum(r.dups for r in recorders),
            faults=faults + sum(r.faults for r in recorders),
            safe_state_ok=safe_state_ok,
            first_device_index=recorders[0].idx0,
            units_dropped=[r.unit for r in recorders if r.dropped and r.unit is not None],
        )

    @property
    def exit_code(self) -> int:
        return {"completed": 0, "interrupted": 130}.get(self.outcome, 1)
