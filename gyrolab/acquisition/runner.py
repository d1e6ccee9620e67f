"""The profile runner: the run engine that walks the oven through a profile, safely.

Three parts, Bluesky/ophyd style — the plan never touches a port:

* :class:`~gyrolab.profiles.plan.ProfilePlan` is the plan: the one interpreter of a
  profile (steps, the stability rule, when a step ends on the run clock), shared with
  ``gyrolab simulate``. Fed the time and PT100 readings, it says what to do (command a
  setpoint, emit an event, log).
* Devices (:class:`Thermometer`, :class:`Chamber`, :class:`RateStream`, in
  ``gyrolab.instruments.roles``) are the hardware abstraction: the role protocols that
  every registered driver implements itself (``gyrolab.instruments.registry``).
* :class:`Acquisition` is the run engine: one polling thread per instrument feeding a
  queue, and the main thread that owns the recorder, runs the plan, watches the safety
  limits, and ends the run cleanly on completion, fault or SIGINT.

Safety: every profile setpoint is checked against the bench limits before anything
starts; the PT100 over/under-temperature watchdog, an instrument that raises a fatal
fault, an instrument silent for longer than ``comm_timeout_s`` (and, on a multi-unit
bench, no unit's temperature reading for that long) all end the run the same way as SIGINT
does: the oven is commanded to the configured safe state (and read back), the queued data
is written, the file is finalized. Every transition and fault goes
to ``/profile/event`` and ``/log``.
"""

from __future__ import annotations

import math
import queue
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from gyrolab.acquisition import interrupts
from gyrolab.acquisition.bench_config import Limits, SafeState
from gyrolab.acquisition.streams import RateRecorder
from gyrolab.clock import Clock
from gyrolab.instruments.roles import (  # noqa: F401 - re-exported for compatibility
    Chamber,
    ChamberReading,
    InstrumentFault,
    MultiThermometer,
    RateStream,
    RateStreamConfig,
    Thermometer,
    ThermometerReading,
    is_transient,
)
from gyrolab.profiles.plan import (
    Action,
    Event,
    Log,
    ProfilePlan,
    SetSetpoint,
    check_profile_limits,
)
from gyrolab.profiles.profile import Profile
from gyrolab.record.writer import RecordingWriter

# ------------------------------------------------------------------------ protocols


class SilencePolicy(Protocol):
    """When an instrument that has said nothing for a while counts as lost (the watchdog).

    :class:`RunTimeSilence` is the lab's rule; a simulated bench supplies its own
    (``gyrolab.app.sim_bench``)."""

    def heard(self, source: str) -> None:
        """``source`` just answered."""

    def lost(self, source: str, silent_s: float, timeout_s: float) -> bool:
        """Is ``source``, silent for ``silent_s`` run seconds, lost (limit ``timeout_s``)?"""
        ...


class RunTimeSilence:
    """The lab's rule: lost after more than ``comm_timeout_s`` seconds of run time."""

    def heard(self, source: str) -> None:
        pass

    def lost(self, source: str, silent_s: float, timeout_s: float) -> bool:
        return silent_s > timeout_s


# The silence policy's name for "some unit's temperature (PT100 or internal sensor) gave a
# reading" (multi-unit runs).
UNIT_TEMPERATURES = "unit temperatures"

# The role protocols and the error vocabulary live in roles.py; these names stay here for
# code that imported them from the runner.
Oven = Chamber
GyroStream = RateStream




# ------------------------------------------------------------------------- engine


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
    """A snapshot for the progress display (``units``: a multi-unit run's, in bench order;
    ``pt100_c`` is then the first unit's, the one the profile's stability rule watches)."""

    t: float = 0.0
    step: int = -1
    n_steps: int = 0
    setpoint_c: float = math.nan
    chamber_c: float = math.nan
    pt100_c: float = math.nan
    remaining_s: float = math.nan
    frames_lost: int = 0
    frames_bad: int = 0
    samples: int = 0
    units: list[UnitStatus] = field(default_factory=list)


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

    @property
    def exit_code(self) -> int:
        return {"completed": 0, "interrupted": 130}.get(self.outcome, 1)


@dataclass(frozen=True)
class UnitDevices:
    """One unit of a multi-unit run: its ``serial``, its connected rate ``stream`` (whose
    ``name`` is its source in /log, ``unit/<serial>``), the stream's config ``adc`` and the
    scanner ``channel`` of its PT100 — None for a unit read by its internal sensor, whose
    stream delivers its temperature (``AdcBlock.temperature_c``)."""

    serial: str
    stream: RateStream
    adc: Any
    channel: int | None

    @property
    def internal(self) -> bool:
        return self.channel is None


class _Poller(threading.Thread):
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


class _AdcThread(threading.Thread):
    """Reads the ADC stream continuously and posts what arrives."""

    def __init__(
        self,
        dev: GyroStream,
        post: Callable[[tuple[Any, ...]], None],
        stop: threading.Event,
        clock: Clock,
    ) -> None:
        super().__init__(name="adc", daemon=True)
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
            self.post(("adc", self.dev.name, self.clock.now(), got))
        return True

    def run(self) -> None:
        while not self.stop_ev.is_set() and not self.failed:
            if not self.step() and not self.failed:
                time.sleep(0.05)


class Acquisition:
    """The run engine: devices + plan + watchdogs + recorder.

    ``run()`` blocks until the profile is complete, a fault ends it, or SIGINT/SIGTERM
    (or :meth:`request_stop`) interrupts it; the oven is then left in the safe state and
    the recording closed. ``on_status`` is called (from the main thread) with a
    :class:`Status` at most every ``status_every_s`` wall seconds.

    A single-unit bench gives ``thermometer``, ``gyro`` and ``adc``. A multi-unit bench
    gives ``units`` (one :class:`UnitDevices` each) and, as ``thermometer``, the scanner
    (a :class:`~gyrolab.instruments.roles.MultiThermometer`) that reads every unit's
    PT100 — a unit read by its internal sensor (``UnitDevices.channel`` None) has it in its
    stream instead, and with every unit so ``thermometer`` is None; the writer must then be a
    multi-unit one (``RecordingWriter(units=…, internal_temperature=…)``). The profile's
    stability rule watches the first unit's temperature (as ``gyrolab simulate --units``
    does); the over/under-temperature watchdog watches every unit's. A unit whose
    stream fails (a fatal error, or silent longer than ``comm_timeout_s``) is logged and
    dropped; the run goes on with the others. A unit whose PT100 channel reads overload
    (an open lead) stays in the run with a gap in its temperature topic (logged when lost
    and when back); when no unit's temperature reads for longer than ``comm_timeout_s`` the run
    ends as for a silent thermometer (docs/fleet.md, "Acquisition").
    """

    def __init__(
        self,
        *,
        profile: Profile,
        writer: RecordingWriter,
        clock: Clock,
        thermometer: Thermometer | MultiThermometer | None,
        oven: Oven,
        gyro: GyroStream | None = None,
        adc: RateStreamConfig | None = None,
        limits: Limits,
        safe_state: SafeState,
        units: list[UnitDevices] | None = None,
        pt100_period_s: float = 1.0,
        oven_period_s: float = 2.0,
        on_status: Callable[[Status], None] | None = None,
        status_every_s: float = 0.5,
        on_samples: Callable[[float], None] | None = None,
        silence: SilencePolicy | None = None,
        threaded: bool = True,
        turn_s: float = 0.1,
    ) -> None:
        check_profile_limits(profile, limits)
        if (units is None) == (gyro is None) or (units is None) == (adc is None):
            raise ValueError("give gyro and adc (one unit) or units (several), not both")
        if thermometer is None and (units is None or not all(u.internal for u in units)):
            raise ValueError("a PT100 (a unit without its internal sensor) needs a thermometer")
        # threaded=False: no threads; every turn of the main loop polls the instruments
        # itself and then sleeps ``turn_s`` on ``clock`` (a fake clock in tests advances).
        self.threaded = threaded
        self.turn_s = turn_s
        self.silence: SilencePolicy = silence or RunTimeSilence()
        self.profile = profile
        self.plan = ProfilePlan(profile)
        self.w = writer
        self.clock = clock
        self.thermo, self.oven = thermometer, oven
        self.units = units
        self.limits = limits
        self.safe = safe_state
        self.pt100_period_s = pt100_period_s
        self.oven_period_s = oven_period_s
        self.on_status = on_status
        self.status_every_s = status_every_s
        self.q: queue.Queue[tuple[Any, ...]] = queue.Queue()
        self.stop_ev = threading.Event()
        self.oven_cmds: queue.Queue[Callable[[], Any]] = queue.Queue()
        self.status = Status(n_steps=len(profile.steps))
        self._t0 = 0.0
        self._interrupt: str | None = None
        self._fault: str | None = None
        self._last_ok: dict[str, float] = {}
        self._down_since: dict[str, float] = {}
        self._down_errors: dict[str, int] = {}
        self._pt_bad: dict[str | None, int] = {}  # consecutive out-of-limit readings per unit
        # Multi-unit: units whose PT100 channel reads overload now -> (since, sweeps lost);
        # each unit's last reading (°C); when any unit last had a reading (clock time).
        self._pt_missing: dict[str, tuple[float, int]] = {}
        self._unit_c: dict[str, float] = {}
        self._pt_any_at = 0.0
        self._faults = 0
        self._setpoint_pending: float | None = None
        # One recorder per rate stream, by its source name in /log.
        if units is None:
            assert gyro is not None and adc is not None
            recs = [RateRecorder(gyro, adc, writer, self.log, on_samples=on_samples)]
        else:
            recs = [
                RateRecorder(
                    u.stream,
                    u.adc,
                    writer,
                    self.log,
                    unit=u.serial,
                    on_samples=on_samples if k == 0 else None,
                    on_temperature=self._unit_temperature(k, u.serial) if u.internal else None,
                )
                for k, u in enumerate(units)
            ]
        self.streams: dict[str, RateRecorder] = {r.name: r for r in recs}
        if len(self.streams) != len(recs):
            raise ValueError("every unit's rate stream needs its own name")
        self._readers: dict[str, _AdcThread] = {}

    @property
    def gyro(self) -> GyroStream:
        """The (first) unit's rate stream."""
        return next(iter(self.streams.values())).dev

    # -- helpers
    def t(self) -> float:
        return self.clock.now() - self._t0

    def _rt(self, t_clock: float) -> float:
        return t_clock - self._t0

    def log(
        self,
        level: str,
        source: str,
        message: str,
        kind: str = "",
        data: dict[str, Any] | None = None,
        t: float | None = None,
    ) -> None:
        self.w.write_log(self.t() if t is None else t, level, source, message, kind, data)

    def request_stop(self, reason: str = "stop requested") -> None:
        """Ask the run to end cleanly (thread-safe; what SIGINT does)."""
        self._interrupt = reason

    # -- the run
    def run(self) -> RunResult:
        old = {}
        if threading.current_thread() is threading.main_thread():
            # SIGINT, SIGTERM, SIGHUP: a clean stop (safe state), never an exception mid-run.
            old = {sig: signal.signal(sig, self._on_signal) for sig in interrupts.STOP_SIGNALS}
            # One that came just before (noted by gyrolab.acquisition.interrupts) stops it too.
            name = interrupts.take()
            if name is not None:
                self._interrupt = f"interrupted by {name}"
        try:
            return self._run()
        finally:
            for sig, handler in old.items():
                signal.signal(sig, handler)

    def _on_signal(self, signum: int, _frame: Any) -> None:
        self._interrupt = f"interrupted by {signal.Signals(signum).name}"

    def _run(self) -> RunResult:
        # Samples that arrived before the run started are not part of it: drop them so
        # that sample 0 is the first one after t = 0.
        stale = {name: rec.dev.read(0.0) for name, rec in self.streams.items()}
        self._t0 = self.clock.now()
        for name, got in stale.items():
            n_stale = sum(int(b.counts.size) for b in got.blocks)
            if n_stale:
                self.log(
                    "info",
                    name,
                    f"discarded {n_stale} ADC samples received before the run started",
                    "startup",
                    {"samples": n_stale},
                    0.0,
                )
        now = self._t0
        thermo = [] if self.thermo is None else [self.thermo.name]
        for name in (*thermo, self.oven.name, *self.streams):
            self._last_ok[name] = now
            self.silence.heard(name)
        self._temperature_heard(now)
        self._do(self.plan.start(0.0))
        self._readers = {
            name: _AdcThread(rec.dev, self.q.put, self.stop_ev, self.clock)
            for name, rec in self.streams.items()
        }
        threads: list[Any] = []
        if self.thermo is not None:  # none when every unit is read by its internal sensor
            threads.append(
                _Poller(
                    self.thermo.name,
                    self.thermo.read,
                    self.pt100_period_s,
                    self.clock,
                    self.q.put,
                    self.stop_ev,
                    reports=getattr(self.thermo, "reports", None),
                )
            )
        threads += [
            _Poller(
                self.oven.name,
                self.oven.read,
                self.oven_period_s,
                self.clock,
                self.q.put,
                self.stop_ev,
                self.oven_cmds,
                reports=getattr(self.oven, "reports", None),
            ),
            *self._readers.values(),
        ]
        if self.threaded:
            for th in threads:
                th.start()
        stepped, threads = (threads, []) if not self.threaded else ([], threads)
        last_status = 0.0
        outcome, reason = "completed", "profile complete"
        try:
            while True:
                for dev in stepped:  # single-threaded engine: the pollers' turns
                    if isinstance(dev, _AdcThread):
                        if not dev.failed:
                            dev.step(0.0)
                    else:
                        dev.step()
                try:
                    item = self.q.get(timeout=0.02) if self.threaded else self.q.get_nowait()
                except queue.Empty:
                    item = None
                if item is not None:
                    self._handle(item)
                    # Drain what is already queued before the slower checks below.
                    for _ in range(200):
                        try:
                            self._handle(self.q.get_nowait())
                        except queue.Empty:
                            break
                t = self.t()
                self._do(self.plan.update(t))
                self._watchdog(t)
                self.w.maybe_flush(t)
                if self._interrupt:
                    outcome, reason = "interrupted", self._interrupt
                    break
                if self._fault:
                    outcome, reason = "fault", self._fault
                    break
                if self.plan.state == "done":
                    self._drain_adc_to(self.plan.ended_at)
                    break
                if self.on_status and time.monotonic() - last_status >= self.status_every_s:
                    last_status = time.monotonic()
                    self._update_status(t)
                    self.on_status(self.status)
                if stepped:
                    self.clock.sleep(self.turn_s)
        finally:
            safe_ok = self._shutdown(outcome, reason, threads)
        if self.on_status:
            self._update_status(self.t())
            self.on_status(self.status)
        recs = list(self.streams.values())
        first = recs[0]
        return RunResult(
            outcome=outcome,
            reason=reason,
            t_end=self.t(),
            samples=sum(r.samples for r in recs),
            gaps=sum(r.gaps for r in recs),
            samples_missing=sum(r.missing for r in recs),
            duplicates_dropped=sum(r.dups for r in recs),
            faults=self._faults + sum(r.faults for r in recs),
            safe_state_ok=safe_ok,
            first_device_index=first.idx0,
            units_dropped=[r.unit for r in recs if r.dropped and r.unit is not None],
        )

    def _drain_adc_to(self, t_end: float, wall_s: float = 1.0) -> None:
        """A completed run records the gyro up to the profile's end: keep handling what
        the device threads deliver until the ADC samples reach ``t_end`` (the stream lags
        the clock by the frames in flight), for at most ``wall_s`` wall seconds (an ADC
        that went quiet at the very end must not hold the oven; its gap stays visible)."""
        deadline = time.monotonic() + wall_s
        while (
            any(r.behind(t_end) for r in self.streams.values())
            and time.monotonic() < deadline
            and not self._interrupt
        ):
            try:
                self._handle(self.q.get(timeout=0.02))
            except queue.Empty:
                continue
            self.w.maybe_flush(self.t())

    def _update_status(self, t: float) -> None:
        st = self.status
        st.t = t
        st.step = self.plan.step_index
        st.setpoint_c = self.plan.step.setpoint_c if self.plan.step else math.nan
        st.remaining_s = self.plan.remaining_s(t)
        st.frames_lost = st.frames_bad = st.samples = 0
        st.units = []
        for rec in self.streams.values():
            c = rec.dev.counters()
            lost, bad = int(c.get("frames_lost", 0)), int(c.get("frames_bad", 0))
            st.frames_lost += lost
            st.frames_bad += bad
            st.samples += rec.samples
            if rec.unit is not None:
                lost_pt = rec.unit in self._pt_missing
                state = "dropped" if rec.dropped else "pt100_lost" if lost_pt else "recording"
                c_now = math.nan if lost_pt else self._unit_c.get(rec.unit, math.nan)
                st.units.append(UnitStatus(rec.unit, state, c_now, rec.samples, lost, bad))

    # -- actions from the plan
    def _do(self, actions: list[Action]) -> None:
        t = self.t()
        for a in actions:
            if isinstance(a, SetSetpoint):
                self._command_setpoint(a.setpoint_c)
            elif isinstance(a, Event):
                # Stamped with the plan's time (the step boundary on the run clock), not
                # with when the engine got to it; the setpoint command's own log says when
                # the oven took it.
                te = t if a.t is None else a.t
                self.w.write_event(te, a.event, a.step, a.setpoint_c, a.detail)
            elif isinstance(a, Log):
                self.log(a.level, "runner", a.message, a.kind, a.data, t)

    def _command_setpoint(self, sp: float) -> None:
        if not self.limits.setpoint_min_c <= sp <= self.limits.setpoint_max_c:
            # Unreachable after check_profile_limits; kept as the last line of defence.
            self._fail("runner", f"setpoint {sp:g} °C outside limits; not sent")
            return
        self._setpoint_pending = sp

        def cmd() -> tuple[str, float]:
            self.oven.set_setpoint(sp)
            return ("setpoint", sp)

        self.oven_cmds.put(cmd)

    # -- items from the device threads
    def _handle(self, item: tuple[Any, ...]) -> None:
        kind, source, t_clock, payload = item
        t = self._rt(t_clock)
        if kind in ("error", "fatal"):
            self._on_error(source, t, payload, fatal=kind == "fatal")
            return
        if kind == "report":
            self._on_report(source, t, payload)
            return
        if kind == "adc":
            rec = self.streams[source]

            def ok() -> None:
                # What a dropped stream had delivered is still written, but says nothing
                # about whether it is alive.
                if not rec.dropped:
                    self._on_ok(source, t, t_clock)

            rec.on_read(payload, t, ok)
            return
        self._on_ok(source, t, t_clock)
        if kind == "command":
            what, value = payload
            if what == "setpoint":
                if self._setpoint_pending == value:
                    self._setpoint_pending = None
                self.log(
                    "info",
                    source,
                    f"setpoint {value:g} °C written and verified",
                    "command",
                    {"setpoint_c": value},
                    t,
                )
        elif self.thermo is not None and source == self.thermo.name and self.units is not None:
            self._on_scan(t, payload)
        elif self.thermo is not None and source == self.thermo.name:
            ohm, c = payload
            self.w.write_pt100(t, ohm, c)
            self.status.pt100_c = c
            self._pt100_watch(t, c)
            self._do(self.plan.update(t, c))
        elif source == self.oven.name:
            sp, pv = payload
            self.status.chamber_c = pv
            mode = "run" if self.plan.state == "step" else "hold"
            self.w.write_oven(t, sp, pv, mode)

    def _on_scan(self, t: float, readings: dict[int, Any]) -> None:
        """A sweep of the scanner: every unit's PT100 to its topic and the watchdog; the
        first unit's to the plan's stability rule.

        A channel that reads overload (NaN: a PT100 lead open or unplugged) loses that
        unit's reading only: nothing is written for it (its temperature topic has a gap),
        the unit stays in the run (its rate is still recorded), and the loss and the
        recovery are logged once each. A lost reading neither clears nor adds to the unit's
        count of consecutive out-of-limit readings (it says nothing about the temperature).
        """
        assert self.units is not None and self.thermo is not None
        plan_c: float | None = None
        any_ok = False
        for k, u in enumerate(self.units):
            if u.internal:
                continue  # its stream reports its temperature (_unit_temperature)
            r = readings.get(u.channel)
            if r is None or not math.isfinite(r[1]):
                self._pt100_lost(t, u)
                continue
            any_ok = True
            self._pt100_back(t, u)
            ohm, c = r
            self.w.write_pt100(t, ohm, c, unit=u.serial)
            self._unit_c[u.serial] = c
            self._pt100_watch(t, c, u.serial)
            if k == 0:
                plan_c = c
        if any_ok:
            self._temperature_heard()
        if plan_c is not None:
            self.status.pt100_c = plan_c
        elif not self.units[0].internal:  # the plan's PT100 is lost: say so, not a stale value
            self.status.pt100_c = math.nan
        self._do(self.plan.update(t, plan_c))

    def _unit_temperature(self, k: int, serial: str) -> Callable[[float, float], None]:
        """The engine's side of unit ``k``'s internal sensor (its RateRecorder calls it with
        each recorded reading): the over/under-temperature watchdog, as for a PT100, and for
        the first unit the plan's stability rule."""

        def take(t: float, c: float) -> None:
            self._unit_c[serial] = c
            self._temperature_heard()
            self._pt100_watch(t, c, serial, "internal sensor")
            if k == 0:
                self.status.pt100_c = c
                self._do(self.plan.update(t, c))

        return take

    def _temperature_heard(self, at: float | None = None) -> None:
        """Some unit's temperature gave a reading at clock time ``at`` (default: now), for
        the blind-temperature watchdog (_watchdog)."""
        self._pt_any_at = self.clock.now() if at is None else at
        self.silence.heard(UNIT_TEMPERATURES)

    def _pt100_lost(self, t: float, u: UnitDevices) -> None:
        """Unit ``u``'s channel gave no reading at run time ``t``: a fault, logged once."""
        assert self.thermo is not None
        since, n = self._pt_missing.get(u.serial, (t, 0))
        self._pt_missing[u.serial] = (since, n + 1)
        if n:
            return
        self._faults += 1
        self.log(
            "warning",
            self.thermo.name,
            f"unit {u.serial}: no PT100 reading on channel {u.channel} "
            "(overload: sensor open or unplugged); the unit's rate is still recorded",
            "fault",
            {"unit": u.serial, "channel": u.channel},
            t,
        )

    def _pt100_back(self, t: float, u: UnitDevices) -> None:
        """Unit ``u``'s channel reads again at run time ``t``: a recovery, with how long."""
        if u.serial not in self._pt_missing:
            return
        assert self.thermo is not None
        since, n = self._pt_missing.pop(u.serial)
        self.log(
            "info",
            self.thermo.name,
            f"unit {u.serial}: PT100 on channel {u.channel} reads again after "
            f"{t - since:.1f} s ({n} sweep(s) without it)",
            "recovery",
            {
                "unit": u.serial,
                "channel": u.channel,
                "outage_s": round(t - since, 3),
                "sweeps_lost": n,
            },
            t,
        )

    def _drop_unit(self, source: str, t: float, reason: str) -> None:
        """Give up on a unit's rate stream: log it, stop reading it, carry on with the
        others (the run ends only when none is left)."""
        rec = self.streams[source]
        if rec.dropped:
            return
        rec.dropped = True
        self._faults += 1
        reader = self._readers.get(source)
        if reader is not None:
            reader.failed = True  # its thread (or turn) stops reading
        for d in (self._last_ok, self._down_since, self._down_errors):
            d.pop(source, None)
        rec.emit_block()
        left = sum(not r.dropped for r in self.streams.values())
        self.log(
            "fault",
            source,
            f"unit {rec.unit} dropped: {reason}; the run goes on with {left} unit(s)",
            "unit_dropped",
            {"unit": rec.unit, "units_left": left},
            t,
        )
        if not left:
            self._fail("runner", "every unit's rate stream failed", t)

    def _on_ok(self, source: str, t: float, t_clock: float) -> None:
        self._last_ok[source] = t_clock
        self.silence.heard(source)
        if source in self._down_since:
            since = self._down_since.pop(source)
            n = self._down_errors.pop(source, 0)
            self.log(
                "info",
                source,
                f"{source} recovered after {t - since:.1f} s ({n} failed attempts)",
                "recovery",
                {"outage_s": round(t - since, 3), "failed_attempts": n},
                t,
            )

    def _on_error(self, source: str, t: float, message: str, fatal: bool) -> None:
        if fatal and self.units is not None and source in self.streams:
            self._drop_unit(source, t, message)
            return
        if fatal:
            self._fail(source, message, t)
            return
        if source not in self._down_since:
            self._down_since[source] = t
            self._down_errors[source] = 1
            self._faults += 1
            self.log("warning", source, f"{source}: {message}", "fault", None, t)
        else:
            self._down_errors[source] += 1

    def _on_report(self, source: str, t: float, rep: Any) -> None:
        """An error the instrument reported itself (InstrumentReport): always a fault in
        /log with its code and text; a fatal one ends the run."""
        self._faults += 1
        msg = rep.message(source)
        self.log("fault", source, msg, "fault", rep.data(), t)
        if rep.fatal and self._fault is None:
            self._fault = msg  # names the instrument already

    def _fail(self, source: str, message: str, t: float | None = None) -> None:
        if self._fault is None:
            self._faults += 1
            self._fault = f"{source}: {message}"
            self.log("fault", source, message, "fault", None, t)

    def _pt100_watch(
        self, t: float, c: float, unit: str | None = None, sensor: str = "PT100"
    ) -> None:
        lim = self.limits
        if lim.pt100_min_c <= c <= lim.pt100_max_c:
            self._pt_bad[unit] = 0
            return
        n = self._pt_bad[unit] = self._pt_bad.get(unit, 0) + 1
        if n >= lim.watchdog_samples:
            which = "over" if c > lim.pt100_max_c else "under"
            whose = sensor if unit is None else f"unit {unit} {sensor}"
            self._fail(
                "watchdog",
                f"{whose} {which}-temperature: {c:.2f} °C outside "
                f"[{lim.pt100_min_c:g}, {lim.pt100_max_c:g}] °C "
                f"for {n} readings",
                t,
            )

    def _watchdog(self, t: float) -> None:
        now = self.clock.now()
        for source, last in list(self._last_ok.items()):
            silent = now - last
            if self.silence.lost(source, silent, self.limits.comm_timeout_s):
                message = (
                    f"lost communication with {source}: nothing for {silent:.1f} s "
                    f"(> comm_timeout_s {self.limits.comm_timeout_s:g} s)"
                )
                if self.units is not None and source in self.streams:
                    self._drop_unit(source, t, message)  # one unit lost, not the run
                    continue
                self._fail("watchdog", message, t)
                return
        if self.units is not None:
            # A scanner that answers with every channel overloaded is heard, yet the
            # over/under-temperature watchdog is blind: as bad as a silent thermometer.
            blind = now - self._pt_any_at
            if self.silence.lost(UNIT_TEMPERATURES, blind, self.limits.comm_timeout_s):
                self._fail(
                    "watchdog",
                    f"no unit's temperature reading for {blind:.1f} s (every PT100 channel "
                    f"overloaded; > comm_timeout_s {self.limits.comm_timeout_s:g} s): the "
                    "temperature watchdog cannot watch the chamber",
                    t,
                )

    # -- ending
    def _shutdown(self, outcome: str, reason: str, threads: list[threading.Thread]) -> bool:
        """Stop the device threads, put the oven in the safe state, write the rest.

        The oven comes first: if the recording cannot be written (disk full, a bug in a
        record), the oven is still commanded to the safe state before anything is raised.
        """
        t_end = self.t()
        if outcome != "completed":
            self.plan.abort()
        self.stop_ev.set()
        for th in threads:
            th.join(timeout=5.0)
        ok, attempts = self._command_safe_state()
        reports = getattr(self.oven, "reports", None)
        for rep in reports() if reports is not None else []:
            # Exception responses to the safe-state commands: logged like any other.
            self._on_report(self.oven.name, self.t(), rep)
        if outcome != "completed":
            self.w.write_event(
                t_end,
                "aborted",
                self.plan.step_index,
                self.plan.step.setpoint_c if self.plan.step else None,
                reason,
            )
            level = "fault" if outcome == "fault" else "warning"
            self.log(level, "runner", f"run aborted: {reason}", "abort", None, t_end)
        # What the device threads had already delivered: no sample is dropped here.
        while True:
            try:
                self._handle(self.q.get_nowait())
            except queue.Empty:
                break
        t_stop = self.plan.ended_at if outcome == "completed" else t_end
        for rec in self.streams.values():
            rec.emit_block()
            rec.record_tail_gap(t_stop)
        self._record_safe_state(ok, attempts)
        self.w.flush()
        return ok

    def _command_safe_state(self) -> tuple[bool, list[tuple[float, str, Any]]]:
        """Command the safe setpoint and verify it by reading it back (three attempts).

        Returns ``(ok, attempts)``: each attempt ``(t, error or "", (sp, pv) or None)``.
        """
        ss = self.safe
        attempts: list[tuple[float, str, Any]] = []
        for _ in range(3):
            t = self.t()
            try:
                self.oven.set_setpoint(ss.setpoint_c)
                sp, pv = self.oven.read()
                if abs(sp - ss.setpoint_c) > 0.05:
                    raise RuntimeError(f"setpoint read back {sp:g} °C")
                if ss.mode == "off":
                    self.oven.switch_off()  # Chamber.switch_off verifies by read-back
            except Exception as e:
                attempts.append((t, f"{type(e).__name__}: {e}", None))
                self.clock.sleep(0.2)
                continue
            attempts.append((self.t(), "", (sp, pv)))
            return True, attempts
        return False, attempts

    def _record_safe_state(self, ok: bool, attempts: list[tuple[float, str, Any]]) -> None:
        ss = self.safe
        for k, (t, err, _res) in enumerate(attempts, start=1):
            if err:
                self.log(
                    "error",
                    self.oven.name,
                    f"safe-state attempt {k} failed: {err}",
                    "fault",
                    None,
                    t,
                )
        t, err, res = attempts[-1]
        if ok:
            sp, pv = res
            detail = f"setpoint {ss.setpoint_c:g} °C verified"
            if ss.mode == "off":
                detail += ", chamber off verified"
            self.w.write_oven(t, sp, pv, "safe")
            self.w.write_event(t, "safe_state", -1, sp, detail)
            self.log(
                "info",
                self.oven.name,
                f"oven in safe state: {detail}",
                "safe_state",
                {"setpoint_c": sp, "process_value_c": pv},
                t,
            )
        else:
            self.w.write_event(t, "safe_state", -1, None, f"FAILED: {err}")
            self.log(
                "fault",
                self.oven.name,
                f"could not put the oven in the safe state: {err}",
                "fault",
                None,
                t,
            )
