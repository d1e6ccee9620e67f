"""The run's one temperature intake: every temperature reading of a run — the bench's
PT100 (a multimeter), a unit's PT100 on the scanner, a unit's internal sensor — enters
through :meth:`TemperatureIntake.take`, and the plan's stability rule, the
over/under-temperature watchdog, the blind-temperature watchdog and the status read it
from here.

Recording a reading is its producer's job (the engine writes ``/temperature/pt100``, a
unit's :class:`~gyrolab.acquisition.streams.RateRecorder` its
``/temperature/internal``); what the run makes of it is this module's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from gyrolab.acquisition.bench_config import Limits
from gyrolab.acquisition.journal import Journal
from gyrolab.acquisition.watchdog import UNIT_TEMPERATURES, SilencePolicy
from gyrolab.clock import Clock

PT100 = "pt100"
INTERNAL = "internal"
SENSOR_NAMES = {PT100: "PT100", INTERNAL: "internal sensor"}


@dataclass(frozen=True)
class Sensor:
    """Where one unit's temperature comes from: its ``serial`` (None: the single-unit
    bench's one PT100), its ``source`` (``pt100`` | ``internal``) and, for a PT100 on a
    scanner, its ``channel``."""

    serial: str | None
    source: str = PT100
    channel: int | None = None


class TemperatureIntake:
    """Every temperature reading of the run (module doc). ``sensors``: one per unit, the
    first one the plan's (the profile's stability rule watches it, as ``gyrolab simulate
    --units`` does); ``scanner``: the name (in ``/log``) of the instrument that reads the
    PT100s, for the messages about a lost channel."""

    def __init__(
        self,
        sensors: list[Sensor],
        *,
        scanner: str,
        limits: Limits,
        journal: Journal,
        clock: Clock,
        silence: SilencePolicy,
    ) -> None:
        self.sensors = {s.serial: s for s in sensors}
        self.plan_sensor = sensors[0]
        self.scanner = scanner
        self.limits = limits
        self.journal = journal
        self.clock = clock
        self.silence = silence
        # The plan's temperature now (NaN while its sensor has no reading) and each unit's.
        self.plan_c = math.nan
        self.last_c: dict[str | None, float] = {}
        self._bad: dict[str | None, int] = {}  # consecutive out-of-limit readings per unit
        # Units whose sensor gives no reading now -> (since, readings missed).
        self._missing: dict[str | None, tuple[float, int]] = {}
        self._heard_at = 0.0  # clock time of the last reading of any unit

    @property
    def plan_source(self) -> str:
        """What the plan's temperature is: ``pt100`` or ``internal``."""
        return self.plan_sensor.source

    def start(self, now: float) -> None:
        """The run starts at clock time ``now``: the blind watchdog counts from there."""
        self._heard(now)

    def take(self, t: float, serial: str | None, value: float, source: str) -> bool:
        """A reading of unit ``serial``'s ``source`` sensor taken at run time ``t``:
        ``value`` °C, or NaN for none (an open PT100 channel: overload).

        A missing reading is logged once, when the sensor is lost, and its recovery once
        when it reads again; it neither clears nor adds to the unit's count of
        consecutive out-of-limit readings (it says nothing about the temperature).
        Returns whether the reading is the plan's (its unit's sensor the one it
        watches): the caller then hands it to the plan."""
        sensor = self.sensors[serial]
        if sensor.source != source:
            raise ValueError(f"unit {serial}: a {source} reading from a {sensor.source} unit")
        plan = sensor is self.plan_sensor
        if not math.isfinite(value):
            self._lost(t, sensor)
            if plan:
                self.plan_c = math.nan
            return False
        self._back(t, sensor)
        self.last_c[serial] = value
        if plan:
            self.plan_c = value
        self._heard()
        self._watch(t, value, sensor)
        return plan

    def unit_c(self, serial: str | None) -> float:
        """Unit ``serial``'s last reading (NaN while its sensor is lost)."""
        return math.nan if self.lost(serial) else self.last_c.get(serial, math.nan)

    def lost(self, serial: str | None) -> bool:
        """Whether unit ``serial``'s sensor gives no reading now."""
        return serial in self._missing

    def lost_since(self, serial: str | None) -> float | None:
        """The run time unit ``serial``'s sensor last failed to read since (None: it reads)."""
        return self._missing[serial][0] if serial in self._missing else None

    def blind_for(self) -> float:
        """Clock seconds since any unit's sensor last gave a reading."""
        return self.clock.now() - self._heard_at

    def check_blind(self, t: float) -> None:
        """The blind-temperature watchdog (a multi-unit run): a scanner that answers with
        every channel overloaded is heard, yet the over/under-temperature watchdog is
        blind — as bad as a silent thermometer."""
        blind = self.blind_for()
        timeout = self.limits.comm_timeout_s
        if self.silence.lost(UNIT_TEMPERATURES, blind, timeout):
            self.journal.fail(
                "watchdog",
                f"no unit's temperature reading for {blind:.1f} s (every PT100 channel "
                f"overloaded; > comm_timeout_s {timeout:g} s): the "
                "temperature watchdog cannot watch the chamber",
                t,
            )

    def _heard(self, at: float | None = None) -> None:
        self._heard_at = self.clock.now() if at is None else at
        self.silence.heard(UNIT_TEMPERATURES)

    def _where(self, s: Sensor) -> str:
        return f" on channel {s.channel}" if s.channel is not None else ""

    def _lost(self, t: float, s: Sensor) -> None:
        since, n = self._missing.get(s.serial, (t, 0))
        self._missing[s.serial] = (since, n + 1)
        if n:
            return
        whose = "" if s.serial is None else f"unit {s.serial}: "
        self.journal.fault(
            "warning",
            self.scanner,
            f"{whose}no {SENSOR_NAMES[s.source]} reading{self._where(s)} "
            "(overload: sensor open or unplugged); the unit's rate is still recorded",
            data={"unit": s.serial, "channel": s.channel},
            t=t,
        )

    def _back(self, t: float, s: Sensor) -> None:
        if s.serial not in self._missing:
            return
        since, n = self._missing.pop(s.serial)
        whose = "" if s.serial is None else f"unit {s.serial}: "
        self.journal.log(
            "info",
            self.scanner,
            f"{whose}{SENSOR_NAMES[s.source]}{self._where(s)} reads again after "
            f"{t - since:.1f} s ({n} sweep(s) without it)",
            "recovery",
            {
                "unit": s.serial,
                "channel": s.channel,
                "outage_s": round(t - since, 3),
                "sweeps_lost": n,
            },
            t,
        )

    def _watch(self, t: float, c: float, s: Sensor) -> None:
        """The over/under-temperature watchdog: ``watchdog_samples`` consecutive
        readings outside ``[pt100_min_c, pt100_max_c]`` end the run."""
        lim = self.limits
        if lim.pt100_min_c <= c <= lim.pt100_max_c:
            self._bad[s.serial] = 0
            return
        n = self._bad[s.serial] = self._bad.get(s.serial, 0) + 1
        if n >= lim.watchdog_samples:
            which = "over" if c > lim.pt100_max_c else "under"
            sensor = SENSOR_NAMES[s.source]
            whose = sensor if s.serial is None else f"unit {s.serial} {sensor}"
            self.journal.fail(
                "watchdog",
                f"{whose} {which}-temperature: {c:.2f} °C outside "
                f"[{lim.pt100_min_c:g}, {lim.pt100_max_c:g}] °C "
                f"for {n} readings",
                t,
            )
