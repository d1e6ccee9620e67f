"""Suspenders: conditions that hold a run instead of ending it (Bluesky's suspenders).

While any condition holds, the run is *suspended*: the chamber keeps its setpoint, the
profile does not advance (``ProfilePlan.hold``) and the data go on being recorded. When
every condition has cleared the run resumes (``ProfilePlan.resume``): the step that was
held goes on for what it had left, or, if the temperature left its band while the run was
held, starts again (a re-soak). A condition that lasts longer than its limit ends the run
the way any fault does, in the verified safe state. Conditions (``[suspend]`` in
BENCH.toml, docs/bench-config.md; a limit of 0 switches one off):

* ``chamber alarm`` — the chamber reports an alarm (or an open door) where its driver can
  tell (``ChamberReading.alarm``; docs/instruments.md); limit ``chamber_alarm_s``;
* ``temperature lost`` — the temperature the profile watches has given no reading for
  ``hold_after_s`` (the thermometer or scanner fails, the PT100 channel overloads); limit
  ``temperature_lost_s``, which then replaces ``comm_timeout_s`` for that sensor;
* ``stream stall`` — a rate stream silent for more than ``hold_after_s``; its limit stays
  the stream's own, ``comm_timeout_s`` (then the run ends, or a multi-unit run drops it);
* ``operator pause`` — SIGUSR1 (``Acquisition.request_pause``) until SIGUSR2
  (``request_resume``); limit ``operator_pause_s``.

Each condition is logged when it starts (``/log`` kind ``suspend``) and when it clears
(kind ``suspend_cleared``, with how long it held); the run's suspension itself is a
``suspended`` and a ``resumed`` event on ``/profile/event`` and a ``resume`` log message
with the time held and whether the step re-soaked (docs/recording-format.md). The report
lists every suspension.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from gyrolab.acquisition.bench_config import Suspend
from gyrolab.acquisition.journal import Journal
from gyrolab.acquisition.temperature import PT100, TemperatureIntake
from gyrolab.acquisition.watchdog import CommWatch, RunTimeSilence, SilencePolicy

CHAMBER_ALARM = "chamber alarm"
TEMPERATURE_LOST = "temperature lost"
STREAM_STALL = "stream stall"
OPERATOR_PAUSE = "operator pause"
CONDITIONS = (CHAMBER_ALARM, TEMPERATURE_LOST, STREAM_STALL, OPERATOR_PAUSE)

# Each condition's key in [suspend]: its limit (0: not a suspender). A stall's key is when
# a stream counts as stalled; its limit is the stream's own comm_timeout_s.
KEYS = {
    CHAMBER_ALARM: "chamber_alarm_s",
    TEMPERATURE_LOST: "temperature_lost_s",
    STREAM_STALL: "hold_after_s",
    OPERATOR_PAUSE: "operator_pause_s",
}

_HELD = "held: "  # the silence rule's name for a condition holding the run

#: An engine without suspenders: every condition is what it was before there were any.
NO_SUSPENDERS = Suspend(
    chamber_alarm_s=0.0, temperature_lost_s=0.0, hold_after_s=0.0, operator_pause_s=0.0
)


@dataclass(frozen=True)
class Holding:
    """A condition that holds now: the ``source`` that reports it (an instrument, a
    unit's stream, ``operator``) and what it says."""

    source: str
    detail: str


def conditions(
    chamber_alarm: str,
    chamber: str,
    thermometer: str | None,
    comm: CommWatch,
    temps: TemperatureIntake,
    streams: list[str],
    hold_after_s: float,
    t: float,
    pause: str | None,
    silence: SilencePolicy | None = None,
) -> dict[str, Holding]:
    """The conditions that hold at run time ``t``: the ``chamber``'s alarm (its last
    reading's); the watched temperature lost for ``hold_after_s`` (a PT100's: its
    ``thermometer`` silent — by the bench's silence rule — or its channel reading
    overload; a unit's internal sensor stops with its stream: a stall); the first of the
    ``streams`` silent for more than ``hold_after_s`` (0: never looked at); the
    operator's ``pause``. Silence is judged by ``silence`` (default: the watchdog's rule)."""
    holding: dict[str, Holding] = {}
    if chamber_alarm:
        holding[CHAMBER_ALARM] = Holding(chamber, chamber_alarm)
    silent = dict(comm.silent(hold_after_s, silence)) if hold_after_s > 0 else {}
    if thermometer is not None and hold_after_s <= 0 and comm.down(thermometer):
        silent[thermometer] = 0.0  # no wait: its first failed reading holds the run
    plan = temps.plan_sensor
    since = temps.lost_since(plan.serial)
    if plan.source == PT100 and thermometer is not None and thermometer in silent:
        why = f"no reading for {silent[thermometer]:.0f} s ({comm.last_error.get(thermometer, '')})"
        holding[TEMPERATURE_LOST] = Holding(thermometer, why)
    elif plan.source == PT100 and since is not None and t - since >= hold_after_s:
        holding[TEMPERATURE_LOST] = Holding(temps.scanner, "the watched PT100 reads overload")
    stalled = [s for s in streams if s in silent] if hold_after_s > 0 else []
    if stalled:
        holding[STREAM_STALL] = Holding(stalled[0], f"no samples for > {hold_after_s:g} s")
    if pause:
        holding[OPERATOR_PAUSE] = Holding("operator", pause)
    return holding


@dataclass
class _Active:
    since: float
    holding: Holding


class Suspenders:
    """The run's suspenders (module doc): fed the conditions that hold at each turn of
    the engine (:meth:`update`), it logs them, says when the run is to be held and
    resumed, and fails the run through the ``journal`` when one outlasts its limit."""

    def __init__(
        self, cfg: Suspend, journal: Journal, silence: SilencePolicy | None = None
    ) -> None:
        self.cfg = cfg
        self.journal = journal
        # When a condition held for so many run seconds has outlasted its limit: the
        # bench's silence rule (a simulated bench also wants wall time: a stall of its
        # process is not a condition lasting).
        self.silence: SilencePolicy = silence or RunTimeSilence()
        self.active: dict[str, _Active] = {}
        self._refused = False  # an operator pause refused (logged once)
        self.suspended_at: float | None = None
        self.count = 0  # suspensions so far
        self._band: tuple[float, float] | None = None  # the temperature band of the hold
        self.left_band = False

    def enabled(self, condition: str) -> bool:
        """Whether ``condition`` suspends the run (its key in [suspend] is not 0)."""
        return getattr(self.cfg, KEYS[condition]) > 0

    def limit_s(self, condition: str) -> float:
        """How long ``condition`` may hold the run (inf: its own watchdog decides)."""
        return math.inf if condition == STREAM_STALL else float(getattr(self.cfg, KEYS[condition]))

    @property
    def suspended(self) -> bool:
        return self.suspended_at is not None

    def update(self, t: float, holding: dict[str, Holding], temperature_c: float) -> str | None:
        """The conditions that hold at run time ``t`` (``holding``: condition → who and
        what) and the temperature the profile watches (its last reading, °C). Returns
        ``"suspend"`` when the run is to be held from now, ``"resume"`` when it may go on,
        else None. A condition that is not a suspender (:meth:`enabled`) holds nothing: a
        chamber alarm then ends the run, an operator pause is refused (logged once), a lost
        sensor is the watchdogs' business."""
        if OPERATOR_PAUSE not in holding:
            self._refused = False
        holding = dict(holding)
        for name in [n for n in holding if not self.enabled(n)]:
            h = holding.pop(name)
            if name == CHAMBER_ALARM:
                self.journal.fail(h.source, f"chamber alarm: {h.detail}", t)
            elif name == OPERATOR_PAUSE and not self._refused:
                self._refused = True
                self.journal.log(
                    "warning",
                    h.source,
                    f"{name} refused: [suspend] {KEYS[name]} = 0",
                    "suspend",
                    {"condition": name, "refused": True},
                    t,
                )
        for name in [n for n in self.active if n not in holding]:
            a = self.active.pop(name)
            self.journal.log(
                "info",
                a.holding.source,
                f"{name} cleared after {t - a.since:.1f} s",
                "suspend_cleared",
                {"condition": name, "held_s": round(t - a.since, 3)},
                t,
            )
        for name, h in holding.items():
            if name in self.active:
                if self.active[name].holding != h:
                    self.active[name].holding = h  # the same condition, said otherwise
                continue
            self.active[name] = _Active(t, h)
            self.silence.heard(_HELD + name)
            self.journal.log(
                "warning",
                h.source,
                f"{name}: {h.detail}; the run is held (limit {self._limit_text(name)})",
                "suspend",
                {"condition": name, "detail": h.detail},
                t,
            )
        for name, a in self.active.items():
            held = t - a.since
            if self.silence.lost(_HELD + name, held, self.limit_s(name)):
                self.journal.fail(
                    "suspender",
                    f"{name} for {held:.1f} s (> {KEYS[name]} "
                    f"{self.limit_s(name):g} s): {a.holding.detail}",
                    t,
                )
        self._watch_band(temperature_c)
        if self.active and self.suspended_at is None:
            self.suspended_at = t
            self.count += 1
            self.left_band = False
            self._band = None
            self._watch_band(temperature_c)
            return "suspend"
        if not self.active and self.suspended_at is not None:
            return "resume"
        return None

    def resumed(self, t: float) -> tuple[float, bool]:
        """The run goes on at ``t``: ``(seconds held, whether the step re-soaks)``."""
        assert self.suspended_at is not None
        held = t - self.suspended_at
        self.suspended_at = None
        return held, self.left_band

    def describe(self) -> str:
        """The conditions holding the run now, for its events and status."""
        return "; ".join(
            f"{n} ({a.holding.source}: {a.holding.detail})" for n, a in self.active.items()
        )

    def _limit_text(self, name: str) -> str:
        limit = self.limit_s(name)
        return f"{limit:g} s" if math.isfinite(limit) else "the stream's comm_timeout_s"

    def _watch_band(self, c: float) -> None:
        """The band of the hold: the watched temperature when the run was held
        ± ``resoak_band_c``; a reading outside it means the step must re-soak."""
        if self.suspended_at is None or not math.isfinite(c):
            return
        if self._band is None:
            b = self.cfg.resoak_band_c
            self._band = (c - b, c + b)
        elif not self._band[0] <= c <= self._band[1]:
            self.left_band = True
