"""The run engine's one error vocabulary (gyrolab.instruments.roles.is_transient), with
in-memory instruments that implement the roles: a failed exchange is retried, a refused
setting (LimitError) and a fault end the run at once, in the safe state."""

from __future__ import annotations

import time
from pathlib import Path

from gyrolab.acquisition.bench_config import Limits, SafeState
from gyrolab.acquisition.runner import Acquisition
from gyrolab.clock import WallClock
from gyrolab.instruments.drivers.gyroadc import GyroAdcConfig
from gyrolab.instruments.roles import (
    AdcRead,
    ChamberReading,
    InstrumentError,
    InstrumentTimeout,
    LimitError,
    ThermometerReading,
)
from gyrolab.profiles.profile import Profile, Step
from gyrolab.pt100 import cvd_resistance
from gyrolab.record.reader import read_recording
from gyrolab.record.writer import RecordingWriter


class MemoryThermometer:
    """A PT100 at a fixed temperature; the first ``failures`` readings time out."""

    name = "multimeter"

    def __init__(self, c: float = 25.0, failures: int = 0) -> None:
        self.c, self.failures, self.calls = c, failures, 0

    def read(self) -> ThermometerReading:
        self.calls += 1
        if self.calls <= self.failures:
            raise InstrumentTimeout("memory", "no reply")
        return ThermometerReading(float(cvd_resistance(self.c)), self.c)

    def reports(self) -> list:
        return []


class MemoryChamber:
    """A controller whose own setpoint range is ``range_c`` (LimitError outside, before
    anything is 'sent'); ``busy`` setpoint writes fail first (transient)."""

    name = "oven"

    def __init__(self, range_c=(-45.0, 70.0), busy: int = 0) -> None:
        self.range_c, self.busy = range_c, busy
        self.sp, self.sent, self.attempts = 25.0, [], 0

    def set_setpoint(self, c: float) -> float:
        self.attempts += 1
        if not self.range_c[0] <= c <= self.range_c[1]:
            raise LimitError("memory", f"setpoint {c} outside {self.range_c}")
        if self.busy > 0:
            self.busy -= 1
            raise InstrumentError("memory", "device busy")
        self.sp = c
        self.sent.append(c)
        return c

    def read(self) -> ChamberReading:
        return ChamberReading(self.sp, 25.0)

    def reports(self) -> list:
        return []


class SilentStream:
    name = "adc"

    def read(self, timeout_s: float) -> AdcRead:
        time.sleep(min(timeout_s, 0.01))
        return AdcRead()

    def counters(self) -> dict[str, int]:
        return {"frames_ok": 0, "frames_bad": 0, "frames_lost": 0}


def _run(tmp_path: Path, chamber: MemoryChamber, thermo: MemoryThermometer, duration_s=1.5):
    prof = Profile("t", (Step(25.0, 0.3), Step(60.0, duration_s)))
    out = tmp_path / "run.mcap"
    w = RecordingWriter(out, start_time_ns=0, run={}, bench={})
    acq = Acquisition(
        profile=prof,
        writer=w,
        clock=WallClock(),
        thermometer=thermo,
        chamber=chamber,
        gyro=SilentStream(),
        rate_stream=GyroAdcConfig(),
        limits=Limits(comm_timeout_s=30.0),
        safe_state=SafeState(),
        pt100_period_s=0.05,
        chamber_period_s=0.05,
    )
    t0 = time.monotonic()
    res = acq.run()
    w.close()
    return res, time.monotonic() - t0, read_recording(out)


def test_limit_error_is_never_retried(tmp_path: Path) -> None:
    # The bench allows 60 °C, this controller only 50 °C: the step's setpoint is refused.
    ch = MemoryChamber(range_c=(-40.0, 50.0))
    res, wall, rec = _run(tmp_path, ch, MemoryThermometer(), duration_s=30.0)
    assert res.outcome == "fault" and "LimitError" in res.reason
    assert wall < 10.0  # ended at the refusal, not after the 30 s step
    # Step 1's 25 °C, the refused 60 °C once (never retried), the safe state's 25 °C.
    assert ch.attempts == 3
    assert ch.sent == [25.0, 25.0] and res.safe_state_ok


def test_failed_exchanges_are_retried_and_the_run_completes(tmp_path: Path) -> None:
    ch = MemoryChamber(busy=3)
    th = MemoryThermometer(failures=3)
    res, _, rec = _run(tmp_path, ch, th)
    assert res.outcome == "completed" and res.safe_state_ok
    assert 60.0 in ch.sent  # the busy controller took the setpoint on a later try
    kinds = [(e["source"], e["kind"]) for e in rec.logs]
    assert ("multimeter", "recovery") in kinds and ("oven", "recovery") in kinds
