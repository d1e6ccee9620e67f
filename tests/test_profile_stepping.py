"""One profile interpreter (gyrolab.profiles.plan.ProfilePlan, docs/profiles.md): the same
PT100 trace through ``simulate``'s stepping and through ``acquire``'s run engine ends every
step at the same time — by the time rule, by the stability rule at a reading, at the end of
``max_extra_s``, and at the minimum duration when stable before it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_run_core import Chamber, FakeClock, Stream

from gyrolab.acquisition.bench_config import Limits, SafeState
from gyrolab.acquisition.runner import Acquisition
from gyrolab.instruments.drivers.gyroadc import GyroAdcConfig
from gyrolab.instruments.roles import ThermometerReading
from gyrolab.profiles.profile import Profile, Step
from gyrolab.pt100 import cvd_resistance
from gyrolab.record.reader import read_recording
from gyrolab.record.writer import RecordingWriter
from gyrolab.sim.model import nominal_model
from gyrolab.sim.simulate import simulate_run

# Step ends off the 1 s reading grid (x.5 s) unless a reading ends them; all on the
# engine's 0.125 s turn grid, so both sides are asked at exactly those times.
PROFILE = Profile(
    "stepping",
    (
        Step(25.0, 60.5, "time rule"),
        # judged once its readings span 0.9 x 62.5 s: stable at the reading at 61 + 57 s
        Step(40.0, 30.5, "stable at a reading", 5.0, 62.5, 200.0),
        # never stable: ends when max_extra_s runs out
        Step(30.0, 40.5, "times out", 1e-6, 20.0, 20.0),
        # stable before its minimum duration ends: ends then
        Step(35.0, 60.0, "stable early", 5.0, 30.0, 100.0),
        Step(25.0, 20.0, "last"),
    ),
)
EXPECTED_ENDS = [60.5, 118.0, 178.5, 238.5, 258.5]


class Replay:
    """A thermometer that reads the simulated trace at the engine's run time."""

    name = "multimeter"

    def __init__(self, clock: FakeClock, t: np.ndarray, c: np.ndarray) -> None:
        self.clock, self.t, self.c = clock, t, c

    def read(self) -> ThermometerReading:
        i = int(np.searchsorted(self.t, self.clock.now() - 1000.0 + 1e-9)) - 1
        c = float(self.c[max(i, 0)])
        return ThermometerReading(float(cvd_resistance(c)), c)

    def reports(self) -> list:
        return []


def _steps(events: list[dict]) -> list[tuple]:
    kinds = ("step_started", "soaked", "step_ended")
    return [(e["event"], e["step"], e["t"], e["detail"]) for e in events if e["event"] in kinds]


def test_simulate_and_acquire_end_every_step_at_the_same_time(tmp_path: Path) -> None:
    sim = tmp_path / "sim.mcap"
    simulate_run(sim, PROFILE, nominal_model(), rate_hz=4.0, seed=0, show_progress=False)
    srec = read_recording(sim)
    assert np.array_equal(srec.pt100_t, np.arange(srec.pt100_t.size, dtype=float))

    clock = FakeClock()
    acq_path = tmp_path / "acq.mcap"
    w = RecordingWriter(acq_path, start_time_ns=0, run={}, bench={})
    res = Acquisition(
        profile=PROFILE,
        writer=w,
        clock=clock,
        thermometer=Replay(clock, srec.pt100_t, srec.pt100_c),
        chamber=Chamber(clock),
        gyro=Stream(clock),
        rate_stream=GyroAdcConfig(sample_rate_hz=100.0),
        limits=Limits(),
        safe_state=SafeState(setpoint_c=25.0),
        pt100_period_s=1.0,
        chamber_period_s=2.0,
        threaded=False,
        turn_s=0.125,
    ).run()
    w.close()
    assert res.outcome == "completed"
    arec = read_recording(acq_path)

    sim_steps, acq_steps = _steps(srec.events), _steps(arec.events)
    ends = [t for ev, _, t, _ in sim_steps if ev == "step_ended"]
    assert ends == pytest.approx(EXPECTED_ENDS, abs=1e-9)
    assert len(sim_steps) == len(acq_steps) == 3 * len(PROFILE.steps)
    for s, a in zip(sim_steps, acq_steps, strict=True):
        assert s[:2] == a[:2] and s[2] == pytest.approx(a[2], abs=1e-9) and s[3] == a[3]
    soaked = [d for ev, _, _, d in sim_steps if ev == "soaked"]
    assert "NOT stable" in soaked[2] and "NOT stable" not in soaked[1] + soaked[3]
    # the simulated chamber took each new setpoint when the plan ended the step (the 1 Hz
    # oven record shows the setpoint of the step in force at each whole second)
    run = np.array([m == "run" for m in srec.oven_mode])
    in_force = np.searchsorted(EXPECTED_ENDS, srec.oven_t[run], side="right")
    expect = [PROFILE.steps[i].setpoint_c for i in in_force]
    assert np.array_equal(srec.oven_setpoint_c[run], expect)
