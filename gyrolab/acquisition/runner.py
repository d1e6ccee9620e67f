"""The profile runner: the run engine that walks the oven through a profile, safely.

Three parts, Bluesky/ophyd style — the plan never touches a port:

* :class:`~gyrolab.profiles.plan.ProfilePlan` is the plan: the one interpreter of a
  profile (steps, the stability rule, when a step ends on the run clock), shared with
  ``gyrolab simulate``. Fed the time and temperature readings, it says what to do
  (command a setpoint, emit an event, log).
* Devices (:class:`Thermometer`, :class:`Chamber`, :class:`RateStream`, in
  ``gyrolab.instruments.roles``) are the hardware abstraction: the role protocols that
  every registered driver implements itself (``gyrolab.instruments.registry``).
* :class:`Acquisition` is the run engine: the pollers (``pollers.py``: one per
  instrument, each in its thread) feed a queue; the main thread owns the recorder, hands
  every temperature reading to the one intake (``temperature.py``) that the plan and the
  watchdogs read, runs the plan, watches communication (``watchdog.py``) and ends the run
  in the verified safe state (``safe_state.py``) on completion, fault or SIGINT. Every
  part reports to one :class:`~gyrolab.acquisition.journal.Journal` (``/log``, faults).

Safety: every profile setpoint is checked against the bench limits before anything
starts; the over/under-temperature watchdog, an instrument that raises a fatal
fault, an instrument silent for longer than ``comm_timeout_s`` (and, on a multi-unit
bench, no unit's temperature reading for that long) all end the run the same way as SIGINT
does: the oven is commanded to the configured safe state (and read back), the queued data
is written, the file is finalized. Every transition and fault goes
to ``/profile/event`` and ``/log``.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from collections.abc import Callable
from typing import Any

from gyrolab.acquisition import interrupts
from gyrolab.acquisition.bench_config import Limits, SafeState, Suspend
from gyrolab.acquisition.journal import Journal
from gyrolab.acquisition.pollers import StreamReader, UnitDevices, instrument_pollers
from gyrolab.acquisition.resume import ResumePoint
from gyrolab.acquisition.safe_state import command_safe_state, record_safe_state
from gyrolab.acquisition.status import RunResult, Status, UnitStatus
from gyrolab.acquisition.streams import RateRecorder
from gyrolab.acquisition.suspend import NO_SUSPENDERS, TEMPERATURE_LOST, Suspenders, conditions
from gyrolab.acquisition.temperature import INTERNAL, PT100, Sensor, TemperatureIntake
from gyrolab.acquisition.watchdog import CommWatch, RunTimeSilence, SilencePolicy
from gyrolab.clock import Clock
from gyrolab.instruments.roles import (
    Chamber,
    MultiThermometer,
    RateStream,
    RateStreamConfig,
    Thermometer,
)
from gyrolab.profiles.plan import Action, Event, Log, ProfilePlan, SetSetpoint, check_profile_limits
from gyrolab.profiles.profile import Profile
from gyrolab.record.writer import RecordingWriter

__all__ = ["Acquisition", "RunResult", "Status", "UnitDevices", "UnitStatus"]


class Acquisition:
    """The run engine: devices + plan + watchdogs + recorder.

    ``run()`` blocks until the profile is complete, a fault ends it, or SIGINT/SIGTERM
    (or :meth:`request_stop`) interrupts it; the oven is then left in the safe state and
    the recording closed. ``on_status`` is called (from the main thread) with a
    :class:`Status` at most every ``status_every_s`` wall seconds.

    A single-unit bench gives ``thermometer``, ``gyro`` and ``rate_stream`` (the gyro's
    stream config). A multi-unit bench gives ``units`` (one :class:`UnitDevices` each)
    and, as ``thermometer``, the scanner (a
    :class:`~gyrolab.instruments.roles.MultiThermometer`) that reads every unit's PT100
    — a unit read by its internal sensor (``UnitDevices.channel`` None) has it in its
    stream instead, and with every unit so ``thermometer`` is None; the writer must then be a
    multi-unit one (``RecordingWriter(units=…, internal_temperature=…)``). The profile's
    stability rule watches the first unit's temperature (as ``gyrolab simulate --units``
    does); the over/under-temperature watchdog watches every unit's. A unit whose
    stream fails (a fatal error, or silent longer than ``comm_timeout_s``) is logged and
    dropped; the run goes on with the others. A unit whose PT100 channel reads overload
    (an open lead) stays in the run with a gap in its temperature topic (logged when lost
    and when back); when no unit's temperature reads for longer than ``comm_timeout_s`` the run
    ends as for a silent thermometer (docs/fleet.md, "Acquisition").

    ``suspend`` (BENCH.toml ``[suspend]``; None: none) says which conditions hold the run
    instead of ending it, and for how long (gyrolab/acquisition/suspend.py): a chamber
    alarm, the watched temperature lost, a stalled rate stream, an operator pause
    (:meth:`request_pause`, :meth:`request_resume`; SIGUSR1, SIGUSR2). ``resume``: this
    run continues an interrupted one (gyrolab/acquisition/resume.py): its clock starts at
    ``resume.at_t``, the profile at ``resume.step`` (re-soaked), each stream's samples at
    the run index its time says (the interruption: a gap).
    """

    def __init__(
        self,
        *,
        profile: Profile,
        writer: RecordingWriter,
        clock: Clock,
        thermometer: Thermometer | MultiThermometer | None,
        chamber: Chamber,
        gyro: RateStream | None = None,
        rate_stream: RateStreamConfig | None = None,
        limits: Limits,
        safe_state: SafeState,
        units: list[UnitDevices] | None = None,
        pt100_period_s: float = 1.0,
        chamber_period_s: float = 2.0,
        on_status: Callable[[Status], None] | None = None,
        status_every_s: float = 0.5,
        on_samples: Callable[[float], None] | None = None,
        silence: SilencePolicy | None = None,
        hold_silence: SilencePolicy | None = None,
        threaded: bool = True,
        turn_s: float = 0.1,
        suspend: Suspend | None = None,
        resume: ResumePoint | None = None,
    ) -> None:
        check_profile_limits(profile, limits)
        if (units is None) == (gyro is None) or (units is None) == (rate_stream is None):
            raise ValueError("give gyro and rate_stream (one unit) or units (several), not both")
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
        self.thermo, self.chamber = thermometer, chamber
        self.units = units
        self.limits = limits
        self.safe = safe_state
        self.pt100_period_s = pt100_period_s
        self.chamber_period_s = chamber_period_s
        self.on_status = on_status
        self.status_every_s = status_every_s
        self.q: queue.Queue[tuple[Any, ...]] = queue.Queue()
        self.stop_ev = threading.Event()
        self.chamber_cmds: queue.Queue[Callable[[], Any]] = queue.Queue()
        self.status = Status(n_steps=len(profile.steps))
        self._t0 = 0.0
        self._interrupt: str | None = None
        self.journal = Journal(writer, self.t)
        self.log = self.journal.log
        self.comm = CommWatch(self.journal, clock, self.silence, limits.comm_timeout_s)
        sensors = (
            [Sensor(None)]
            if units is None
            else [Sensor(u.serial, INTERNAL if u.internal else PT100, u.channel) for u in units]
        )
        self.temps = TemperatureIntake(
            sensors,
            scanner=thermometer.name if thermometer is not None else "runner",
            limits=limits,
            journal=self.journal,
            clock=clock,
            silence=self.silence,
        )
        self.status.temperature_source = self.temps.plan_source
        # when a silence is long enough to hold the run; a hold outlasts its limit by the
        # watchdog's rule (a condition that lasts is a loss, as a silent instrument is)
        self.hold_silence: SilencePolicy = hold_silence or self.silence
        self.suspend = Suspenders(suspend or NO_SUSPENDERS, self.journal, self.silence)
        if self.suspend.enabled(TEMPERATURE_LOST) and thermometer is not None:
            self.comm.unjudged.add(thermometer.name)  # lost: the suspender's limit decides
        self._chamber_alarm = ""
        self._pause: str | None = None  # the operator's pause request
        self.resume = resume
        t_start = 0.0 if resume is None else resume.at_t
        self._setpoint_pending: float | None = None
        # One recorder per rate stream, by its source name in /log.
        if units is None:
            assert gyro is not None and rate_stream is not None
            recs = [RateRecorder(gyro, rate_stream, writer, self.log, on_samples=on_samples)]
            resume_index = [None if resume is None else resume.next_index.get(None, (0, 0.0))]
        else:
            recs = [
                RateRecorder(
                    u.stream,
                    u.rate_stream,
                    writer,
                    self.log,
                    unit=u.serial,
                    on_samples=on_samples if k == 0 else None,
                    internal=u.internal,
                )
                for k, u in enumerate(units)
            ]
            resume_index = [
                None if resume is None else resume.next_index.get(u.serial, (0, 0.0)) for u in units
            ]
        for rec, index in zip(recs, resume_index, strict=True):
            rec.resume_index, rec.t_start = index, t_start
        self.streams: dict[str, RateRecorder] = {r.name: r for r in recs}
        if len(self.streams) != len(recs):
            raise ValueError("every unit's rate stream needs its own name")
        self._readers: dict[str, StreamReader] = {}

    @property
    def gyro(self) -> RateStream:
        """The (first) unit's rate stream."""
        return next(iter(self.streams.values())).dev

    # -- helpers
    def t(self) -> float:
        return self.clock.now() - self._t0

    def _rt(self, t_clock: float) -> float:
        return t_clock - self._t0

    def request_stop(self, reason: str = "stop requested") -> None:
        """Ask the run to end cleanly (thread-safe; what SIGINT does)."""
        self._interrupt = reason

    def request_pause(self, reason: str = "paused by the operator") -> None:
        """Hold the run until :meth:`request_resume` (thread-safe; SIGUSR1)."""
        self._pause = reason

    def request_resume(self) -> None:
        """End the operator's pause (thread-safe; SIGUSR2)."""
        self._pause = None

    # -- the run
    def run(self) -> RunResult:
        # SIGINT, SIGTERM, SIGHUP (and one that came just before): a clean stop;
        # SIGUSR1, SIGUSR2: the operator's pause and resume.
        with (
            interrupts.stop_requests(self.request_stop),
            interrupts.pause_requests(self.request_pause, self.request_resume),
        ):
            return self._run()

    def _start(self) -> list[Any]:
        """Start the run's clock, the plan and the watchdogs; returns the pollers."""
        # Samples that arrived before the run started are not part of it: drop them so
        # that sample 0 is the first one after t = 0.
        stale = {name: rec.dev.read(0.0) for name, rec in self.streams.items()}
        t_start = 0.0 if self.resume is None else self.resume.at_t
        self._t0 = self.clock.now() - t_start
        for name, got in stale.items():
            n_stale = sum(int(b.counts.size) for b in got.blocks)
            if n_stale:
                self.log(
                    "info",
                    name,
                    f"discarded {n_stale} ADC samples received before the run started",
                    "startup",
                    {"samples": n_stale},
                    t_start,
                )
        thermo = [] if self.thermo is None else [self.thermo.name]
        now = self.clock.now()
        self.comm.start([*thermo, self.chamber.name, *self.streams], now)
        self.temps.start(now)
        r = self.resume
        if r is None:
            self._do(self.plan.start(0.0))
        else:
            why = f"segment {r.segment} of run {r.run_id}, after {r.previous.name}"
            self._do(self.plan.start(t_start, r.step, why))
        self._readers = {
            name: StreamReader(rec.dev, self.q.put, self.stop_ev, self.clock)
            for name, rec in self.streams.items()
        }
        pollers = instrument_pollers(
            [
                (self.thermo, self.pt100_period_s, None),
                (self.chamber, self.chamber_period_s, self.chamber_cmds),
            ],
            self.clock,
            self.q.put,
            self.stop_ev,
        )
        return pollers + list(self._readers.values())

    def _run(self) -> RunResult:
        threads = self._start()
        if self.threaded:
            for th in threads:
                th.start()
        stepped, threads = (threads, []) if not self.threaded else ([], threads)
        last_status = 0.0
        outcome, reason = "completed", "profile complete"
        try:
            while True:
                for dev in stepped:  # single-threaded engine: the pollers' turns
                    if isinstance(dev, StreamReader):
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
                self._suspenders(t)
                self._do(self.plan.update(t))
                self._watchdog(t)
                self.w.maybe_flush(t)
                if self._interrupt:
                    outcome, reason = "interrupted", self._interrupt
                    break
                if self.journal.reason:
                    outcome, reason = "fault", self.journal.reason
                    break
                if self.plan.state == "done":
                    self._drain_streams_to(self.plan.ended_at)
                    break
                if self.on_status and time.monotonic() - last_status >= self.status_every_s:
                    last_status = time.monotonic()
                    self.status.update(t, self.plan, self.temps, self.streams.values())
                    self.on_status(self.status)
                if stepped:
                    self.clock.sleep(self.turn_s)
        finally:
            safe_ok = self._shutdown(outcome, reason, threads)
        if self.on_status:
            self.status.update(self.t(), self.plan, self.temps, self.streams.values())
            self.on_status(self.status)
        faults = self.journal.faults
        recs = list(self.streams.values())
        res = RunResult.of(outcome, reason, self.t(), recs, faults, safe_ok)
        res.suspensions = self.suspend.count
        return res

    def _drain_streams_to(self, t_end: float, wall_s: float = 1.0) -> None:
        """A completed run records the gyro up to the profile's end: keep handling what
        the device threads deliver until the streams' samples reach ``t_end`` (a stream lags
        the clock by the frames in flight), for at most ``wall_s`` wall seconds (a stream
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
            self.journal.fail("runner", f"setpoint {sp:g} °C outside limits; not sent")
            return
        self._setpoint_pending = sp

        def cmd() -> tuple[str, float]:
            self.chamber.set_setpoint(sp)
            return ("setpoint", sp)

        self.chamber_cmds.put(cmd)

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
        if kind == "stream":
            rec = self.streams[source]

            def ok() -> None:
                # What a dropped stream had delivered is still written, but says nothing
                # about whether it is alive.
                if not rec.dropped:
                    self.comm.ok(source, t, t_clock)

            rec.on_read(payload, t, ok)
            self._internal_readings(rec)
            return
        self.comm.ok(source, t, t_clock)
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
            self._on_sweep(t, payload)
        elif self.thermo is not None and source == self.thermo.name:
            ohm, c = payload
            self.w.write_pt100(t, ohm, c)
            self._take(t, None, c, PT100)
        elif source == self.chamber.name:
            sp, pv = payload[:2]
            self._chamber_alarm = getattr(payload, "alarm", "")
            self.status.chamber_c = pv
            running = self.plan.state == "step" and self.plan.held_at is None
            self.w.write_oven(t, sp, pv, "run" if running else "hold")

    def _take(self, t: float, serial: str | None, c: float, source: str) -> None:
        """A temperature reading into the intake, and to the plan if it watches it."""
        if self.temps.take(t, serial, c, source):
            self._do(self.plan.update(t, c))

    def _on_sweep(self, t: float, readings: dict[int, Any]) -> None:
        """A sweep of the scanner: every unit's PT100 to its topic and the intake; the
        plan is asked once per sweep, with the first unit's reading when it has one. A
        channel that reads overload (NaN: a PT100 lead open or unplugged) loses that unit's
        reading only: nothing is written for it (its temperature topic has a gap)."""
        assert self.units is not None
        plan_c: float | None = None
        for u in self.units:
            if u.internal:
                continue  # its stream reports its temperature (_internal_readings)
            r = readings.get(u.channel)
            c = math.nan if r is None else float(r[1])
            if math.isfinite(c):
                self.w.write_pt100(t, r[0], c, unit=u.serial)
            if self.temps.take(t, u.serial, c, PT100):
                plan_c = c
        self._do(self.plan.update(t, plan_c))

    def _internal_readings(self, rec: RateRecorder) -> None:
        """The internal-sensor readings ``rec`` recorded, into the intake."""
        for t, c in rec.take_readings():
            self._take(t, rec.unit, c, INTERNAL)

    def _drop_unit(self, source: str, t: float, reason: str) -> None:
        """Give up on a unit's rate stream: log it, stop reading it, carry on with the
        others (the run ends only when none is left)."""
        rec = self.streams[source]
        if rec.dropped:
            return
        rec.dropped = True
        reader = self._readers.get(source)
        if reader is not None:
            reader.failed = True  # its thread (or turn) stops reading
        self.comm.forget(source)
        rec.emit_block()
        self._internal_readings(rec)
        left = sum(not r.dropped for r in self.streams.values())
        self.journal.fault(
            "fault",
            source,
            f"unit {rec.unit} dropped: {reason}; the run goes on with {left} unit(s)",
            "unit_dropped",
            {"unit": rec.unit, "units_left": left},
            t,
        )
        if not left:
            self.journal.fail("runner", "every unit's rate stream failed", t)

    def _on_error(self, source: str, t: float, message: str, fatal: bool) -> None:
        if fatal and self.units is not None and source in self.streams:
            self._drop_unit(source, t, message)
        elif fatal:
            self.journal.fail(source, message, t)
        else:
            self.comm.failed(source, t, message)

    def _on_report(self, source: str, t: float, rep: Any) -> None:
        """An error the instrument reported itself (InstrumentReport): always a fault in
        /log with its code and text; a fatal one ends the run."""
        msg = rep.message(source)
        self.journal.fault("fault", source, msg, data=rep.data(), t=t)
        if rep.fatal:
            self.journal.end(msg)  # names the instrument already

    def _suspenders(self, t: float) -> None:
        """The conditions that hold now, to the suspenders; the plan held or resumed as
        they say (gyrolab/acquisition/suspend.py)."""
        holding = conditions(
            self._chamber_alarm,
            self.chamber.name,
            self.thermo.name if self.thermo is not None else None,
            self.comm,
            self.temps,
            [s for s, rec in self.streams.items() if not rec.dropped],
            self.suspend.cfg.hold_after_s,
            t,
            self._pause,
            self.hold_silence,
        )
        c = self.temps.last_c.get(self.temps.plan_sensor.serial, math.nan)
        change = self.suspend.update(t, holding, c)
        if change == "suspend":
            self._do(self.plan.hold(t, self.suspend.describe()))
        elif change == "resume":
            self._do(self.plan.resume(t, self.suspend.resumed(t)[1]))
        self.status.suspended = list(self.suspend.active)

    def _watchdog(self, t: float) -> None:
        for source, silent in self.comm.silent():
            message = (
                f"lost communication with {source}: nothing for {silent:.1f} s "
                f"(> comm_timeout_s {self.limits.comm_timeout_s:g} s)"
            )
            if self.units is not None and source in self.streams:
                self._drop_unit(source, t, message)  # one unit lost, not the run
                continue
            self.journal.fail("watchdog", message, t)
            return
        if self.units is not None and not self.suspend.enabled(TEMPERATURE_LOST):
            self.temps.check_blind(t)

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
        ok, attempts = command_safe_state(self.chamber, self.safe, self.clock, self.t)
        reports = getattr(self.chamber, "reports", None)
        for rep in reports() if reports is not None else []:
            # Exception responses to the safe-state commands: logged like any other.
            self._on_report(self.chamber.name, self.t(), rep)
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
            self._internal_readings(rec)
            rec.record_tail_gap(t_stop)
        record_safe_state(self.w, self.journal, self.chamber.name, self.safe, ok, attempts)
        self.w.flush()
        return ok
