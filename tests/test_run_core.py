"""The run engine without threads or pseudo-terminals (``Acquisition(threaded=False)``):
scripted instruments that implement the roles and a fake clock drive it through the soak,
a step, a transient fault, the PT100 and communication watchdogs and the safe state,
deterministically, in well under a second of wall time each."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from gyrolab.acquisition.bench_config import Limits, SafeState
from gyrolab.acquisition.runner import Acquisition
from gyrolab.instruments.drivers.gyroadc import GyroAdcConfig
from gyrolab.instruments.roles import (
    AdcBlock,
    AdcRead,
    ChamberReading,
    InstrumentTimeout,
    ThermometerReading,
)
from gyrolab.profiles.profile import Profile, Step
from gyrolab.pt100 import cvd_resistance
from gyrolab.record.reader import read_recording
from gyrolab.record.writer import RecordingWriter


class FakeClock:
    """Run time that moves only when someone sleeps on it."""

    def __init__(self) -> None:
        self.t = 1000.0

    def now(self) -> float:
        return self.t

    def sleep(self, dt: float) -> None:
        self.t += max(dt, 0.0)


class Chamber:
    """Air follows the setpoint with a 30 s time constant; silent from ``silent_from``."""

    name = "oven"

    def __init__(self, clock: FakeClock, silent_from: float = math.inf) -> None:
        self.clock, self.silent_from = clock, silent_from
        self.sp, self.air, self.t_last = 25.0, 25.0, clock.now()
        self.commands: list[tuple[float, float]] = []

    def _advance(self) -> None:
        dt = self.clock.now() - self.t_last
        self.air += (self.sp - self.air) * (1.0 - math.exp(-dt / 30.0))
        self.t_last = self.clock.now()
        if self.clock.now() - 1000.0 >= self.silent_from:
            raise InstrumentTimeout("chamber", "no reply")

    def set_setpoint(self, c: float) -> float:
        self._advance()
        self.sp = c
        self.commands.append((round(self.clock.now() - 1000.0, 3), c))
        return c

    def read(self) -> ChamberReading:
        self._advance()
        return ChamberReading(self.sp, self.air)

    def reports(self) -> list:
        return []


class Thermometer:
    """The gyro case: the chamber air; scripted (start, end, kind) faults in run seconds:
    ``timeout`` (a failed reading) or ``hot`` (the case reads 90 °C)."""

    name = "multimeter"

    def __init__(self, clock: FakeClock, chamber: Chamber, faults=()) -> None:
        self.clock, self.chamber, self.faults = clock, chamber, list(faults)

    def read(self) -> ThermometerReading:
        t = self.clock.now() - 1000.0
        c = self.chamber.air
        for a, b, kind in self.faults:
            if a <= t < b:
                if kind == "timeout":
                    raise InstrumentTimeout("thermometer", "no reply")
                c = 90.0
        return ThermometerReading(float(cvd_resistance(c)), c)

    def reports(self) -> list:
        return []


class Stream:
    """A gap-free 100 Hz stream up to the clock's present."""

    name = "adc"

    def __init__(self, clock: FakeClock, rate_hz: float = 100.0) -> None:
        self.clock, self.rate, self.next = clock, rate_hz, 0

    def read(self, timeout_s: float) -> AdcRead:
        n = int((self.clock.now() - 1000.0) * self.rate) - self.next
        if n <= 0:
            return AdcRead()
        counts = np.arange(self.next, self.next + n, dtype=np.int32) % 1000
        blk = AdcBlock(
            self.next // 10, self.next, 1000.0 + self.next / self.rate, 1 / self.rate, counts
        )
        self.next += n
        return AdcRead(blocks=[blk])

    def counters(self) -> dict[str, int]:
        return {"frames_ok": self.next // 10, "frames_bad": 0, "frames_lost": 0}


def _run(
    tmp_path: Path, *, therm_faults=(), silent_from=math.inf, comm_timeout_s=20.0, silence=None
):
    clock = FakeClock()
    chamber = Chamber(clock, silent_from)
    prof = Profile("t", (Step(25.0, 60.0, "soak"), Step(40.0, 120.0)))
    out = tmp_path / "run.mcap"
    w = RecordingWriter(out, start_time_ns=0, run={}, bench={})
    acq = Acquisition(
        profile=prof,
        writer=w,
        clock=clock,
        thermometer=Thermometer(clock, chamber, therm_faults),
        chamber=chamber,
        gyro=Stream(clock),
        rate_stream=GyroAdcConfig(sample_rate_hz=100.0),
        limits=Limits(comm_timeout_s=comm_timeout_s, pt100_max_c=75.0, watchdog_samples=3),
        safe_state=SafeState(setpoint_c=25.0),
        pt100_period_s=1.0,
        chamber_period_s=2.0,
        silence=silence,
        threaded=False,
        turn_s=0.125,  # exact in binary: the scripted times are hit exactly
    )
    res = acq.run()
    w.close()
    return res, read_recording(out), chamber


def test_soak_step_and_safe_state(tmp_path: Path) -> None:
    res, rec, chamber = _run(tmp_path)
    assert res.outcome == "completed" and res.safe_state_ok
    assert res.t_end == pytest.approx(180.0, abs=1e-9)
    assert res.samples == pytest.approx(18000, abs=20) and res.gaps == 0
    starts = [e["t"] for e in rec.events if e["event"] == "step_started"]
    assert starts == pytest.approx([0.0, 60.0], abs=1e-6)  # on the run clock exactly
    assert [c for _, c in chamber.commands] == [25.0, 40.0, 25.0]  # soak, step, safe
    assert [e["event"] for e in rec.events][-2:] == ["run_ended", "safe_state"]
    assert rec.pt100_c.size == pytest.approx(180, abs=2)  # one reading per second


def test_transient_thermometer_fault_recovers(tmp_path: Path) -> None:
    res, rec, _ = _run(tmp_path, therm_faults=[(30.0, 40.0, "timeout")])
    assert res.outcome == "completed" and res.faults == 1
    (rec_log,) = [e for e in rec.logs if e["kind"] == "recovery"]
    assert rec_log["source"] == "multimeter" and rec_log["data"]["failed_attempts"] == 10


def test_over_temperature_watchdog_ends_in_the_safe_state(tmp_path: Path) -> None:
    res, rec, chamber = _run(tmp_path, therm_faults=[(100.0, 1e9, "hot")])
    assert res.outcome == "fault" and "over-temperature" in res.reason
    # The third consecutive hot reading (100, 101, 102 s) trips it.
    assert res.t_end == pytest.approx(102.0, abs=1e-9)
    assert chamber.commands[-1][1] == 25.0 and res.safe_state_ok


def test_lost_chamber_ends_the_run_and_the_safe_state_is_reported_failed(tmp_path: Path) -> None:
    res, rec, chamber = _run(tmp_path, silent_from=50.0, comm_timeout_s=20.0)
    assert res.outcome == "fault" and "lost communication with oven" in res.reason
    # Last good exchange at 48 s (2 s polls), lost 20 s later (the next 0.125 s turn).
    (ab,) = [e for e in rec.events if e["event"] == "aborted"]
    assert ab["t"] == pytest.approx(68.125, abs=1e-9)
    # Three safe-state attempts, 0.2 s apart, all unanswered.
    assert not res.safe_state_ok and res.t_end == pytest.approx(68.125 + 0.6, abs=1e-9)
    (ev,) = [e for e in rec.events if e["event"] == "safe_state"]
    assert ev["detail"].startswith("FAILED")


class PatientSilence:
    """A silence rule of a bench's own (as the simulated bench supplies one): lost only
    ``extra_s`` run seconds after the configured timeout; counts who was heard."""

    def __init__(self, extra_s: float) -> None:
        self.extra_s = extra_s
        self.heard_from: dict[str, int] = {}

    def heard(self, source: str) -> None:
        self.heard_from[source] = self.heard_from.get(source, 0) + 1

    def lost(self, source: str, silent_s: float, timeout_s: float) -> bool:
        return silent_s > timeout_s + self.extra_s


def test_the_bench_s_silence_rule_decides_when_an_instrument_is_lost(tmp_path: Path) -> None:
    """The engine has no simulator knobs: the watchdog asks the SilencePolicy it is given."""
    patient = PatientSilence(extra_s=10.0)
    res, rec, _ = _run(tmp_path, silent_from=50.0, comm_timeout_s=20.0, silence=patient)
    assert res.outcome == "fault" and "lost communication with oven" in res.reason
    (ab,) = [e for e in rec.events if e["event"] == "aborted"]
    assert ab["t"] == pytest.approx(78.125, abs=1e-9)  # 10 s later than the lab rule
    # the oven: at the start, the soak's setpoint command, its reads every 2 s up to 48 s
    assert patient.heard_from["oven"] == 1 + 1 + 25 and patient.heard_from["multimeter"] > 60


def test_the_simulated_bench_s_silence_rule_needs_wall_time_too() -> None:
    """SimSilence: silent past the run-time limit AND for min_wall_s wall seconds."""
    from gyrolab.app.sim_bench import SimSilence

    never_heard = SimSilence(min_wall_s=3600.0)
    assert never_heard.lost("oven", 61.0, 60.0)  # nothing heard yet: the run time decides
    strict = SimSilence(min_wall_s=3600.0)
    strict.heard("oven")
    assert not strict.lost("oven", 1e6, 60.0)  # a sped-up clock alone does not lose it
    lab_like = SimSilence(min_wall_s=0.0)
    lab_like.heard("oven")
    assert lab_like.lost("oven", 61.0, 60.0) and not lab_like.lost("oven", 59.0, 60.0)


def test_a_stream_reader_reads_at_most_once_per_interval_and_loses_nothing() -> None:
    """``StreamReader`` (a lab run's reader thread) on a stream that always has data: no
    more reads than one per ``READ_MIN_INTERVAL_S`` of wall time, and every block read is
    posted (what waits between reads stays in the port, none is dropped)."""
    import threading
    import time

    from gyrolab.acquisition.pollers import READ_MIN_INTERVAL_S, StreamReader

    class Busy:
        name = "adc"
        reads = 0

        def read(self, timeout_s: float) -> AdcRead:
            Busy.reads += 1
            blk = AdcBlock(Busy.reads, 10 * Busy.reads, 0.1 * Busy.reads, 0.01, np.zeros(10))
            return AdcRead(blocks=[blk])

    posted: list[tuple] = []
    stop = threading.Event()
    reader = StreamReader(Busy(), posted.append, stop, FakeClock())  # type: ignore[arg-type]
    t0 = time.monotonic()
    reader.start()
    time.sleep(0.3)
    while Busy.reads < 3:  # a starved thread (load) reads late, but it reads
        time.sleep(0.01)
    stop.set()
    reader.join(60.0)  # a guard against a hang, not a bound on time
    window = time.monotonic() - t0  # the wall time it had, as measured (sleeps overrun)
    assert not reader.is_alive()
    assert 3 <= Busy.reads <= window / READ_MIN_INTERVAL_S + 2
    assert [p[3].blocks[0].first_seq for p in posted] == list(range(1, Busy.reads + 1))
