"""The profile plan (pure state machine) and the bench configuration."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from gyrolab.acquisition.bench_config import BenchConfig, Limits, bench_from_dict, load_bench
from gyrolab.errors import InputError
from gyrolab.profiles.plan import (
    Event,
    Log,
    ProfilePlan,
    SetSetpoint,
    check_profile_limits,
    slope_c_per_min,
)
from gyrolab.profiles.profile import Profile, Step, load_profile

REPO = Path(__file__).resolve().parents[1]


def _run_plan(plan: ProfilePlan, temps, t_end: float, dt: float = 10.0) -> list:
    """Drive ``plan`` with a PT100 reading every ``dt`` s from ``temps(t)``."""
    acts = [(0.0, a) for a in plan.start(0.0)]
    t = 0.0
    while plan.state == "step" and t < t_end:
        t += dt
        acts += [(t, a) for a in plan.update(t, temps(t))]
    return acts


def test_time_only_profile_walks_every_step_in_order() -> None:
    prof = load_profile("short")
    plan = ProfilePlan(prof)
    first = plan.start(0.0)
    assert first[0] == Event("run_started", detail="profile short", t=0.0)
    assert SetSetpoint(25.0) in first
    acts = []
    t = 0.0
    while plan.state == "step":
        t += 1.0
        acts += [(t, a) for a in plan.update(t, 20.0)]
    setpoints = [a.setpoint_c for _, a in acts if isinstance(a, SetSetpoint)]
    assert setpoints == [s.setpoint_c for s in prof.steps[1:]]
    started = [(t, a.step) for t, a in acts if isinstance(a, Event) and a.event == "step_started"]
    # Each step starts exactly when the previous one's minimum duration has passed.
    assert [t for t, _ in started] == pytest.approx(list(prof.step_starts()[1:]))
    assert plan.state == "done" and t == pytest.approx(prof.duration_s)
    names = [a.event for _, a in acts if isinstance(a, Event)]
    assert names[-1] == "run_ended"
    assert names.count("soaked") == names.count("step_ended") == len(prof.steps)


def test_steps_start_on_the_run_clock_however_late_the_engine_looks() -> None:
    """A late ``update`` (a busy engine) ends a step at its due time, not when noticed:
    the events carry the boundary's time, the next step is timed from it, and the
    lateness never accumulates over the profile."""
    prof = load_profile("short")
    plan = ProfilePlan(prof)
    plan.start(0.0)
    rng = np.random.default_rng(1)
    acts = []
    t = 0.0
    while plan.state == "step":
        t += float(rng.uniform(0.5, 9.0))  # the engine looks every 0.5-9 s
        acts += [(t, a) for a in plan.update(t)]
    events = [(tt, a) for tt, a in acts if isinstance(a, Event)]
    starts = [a.t for _, a in events if a.event == "step_started"]
    assert starts == pytest.approx(list(prof.step_starts()[1:]), abs=1e-9)
    ended = [a.t for _, a in events if a.event == "step_ended"]
    assert ended == pytest.approx(list(prof.step_starts()[1:]) + [prof.duration_s], abs=1e-9)
    assert plan.ended_at == pytest.approx(prof.duration_s)
    # Each was noticed late (by up to 9 s), and is stamped no later than it was noticed.
    assert all(a.t <= tt for tt, a in events) and any(tt - a.t > 1.0 for tt, a in events)
    # The transition log (written when the engine acts) names the step's start time.
    logs = [a for _, a in acts if isinstance(a, Log) and a.kind == "transition"]
    assert [m.data["step_start_t"] for m in logs[:-1]] == pytest.approx(starts)


def test_stability_rule_ends_a_step_at_the_reading_that_showed_it_stable() -> None:
    step = Step(40.0, 100.0, stable_slope_c_per_min=0.05, stable_window_s=50.0)
    plan = ProfilePlan(Profile("s", (step, Step(25.0, 100.0))))
    plan.start(0.0)
    for k in range(1, 12):  # steady readings at 9, 19, ..., 109 s
        plan.update(10.0 * k - 1.0, 40.0)
    # Stable before the minimum duration was over: the first reading after 100 s (at
    # 109 s) is the first look, and ends it there.
    assert plan.step_index == 1 and plan.step_started_at == pytest.approx(109.0)
    plan2 = ProfilePlan(Profile("s", (step, Step(25.0, 100.0))))
    plan2.start(0.0)
    for k in range(1, 11):
        plan2.update(10.0 * k - 1.0, 40.0)  # readings up to 99 s: duration not yet over
    acts = plan2.update(130.0)  # the engine looks late, with no new reading
    (ev,) = [a for a in acts if isinstance(a, Event) and a.event == "step_ended"]
    assert ev.t == pytest.approx(100.0)  # stable already when the 100 s ran out
    assert plan2.step_started_at == pytest.approx(100.0)


def test_stability_rule_holds_until_the_pt100_settles() -> None:
    step = Step(40.0, 600.0, "hot", stable_slope_c_per_min=0.05, stable_window_s=300.0)
    prof = Profile("s", (Step(25.0, 100.0), step, Step(25.0, 100.0)))
    plan = ProfilePlan(prof)

    # PT100 approaches 40 °C with a 600 s time constant from t = 100 s.
    def temp(t: float) -> float:
        return 25.0 if t < 100 else 40.0 - 15.0 * math.exp(-(t - 100.0) / 600.0)

    acts = _run_plan(plan, temp, 10_000.0)
    soaked = [(t, a) for t, a in acts if isinstance(a, Event) and a.event == "soaked"]
    t_soak, ev = soaked[1]
    assert ev.step == 1 and "slope" in ev.detail and "NOT" not in ev.detail
    # The slope 1.5·exp(-τ/600) °C/min falls below 0.05 at τ = 600·ln 30 ≈ 2041 s; the
    # 300 s least-squares window lags by about half its length: ≈ 2190 s, long after 600 s.
    assert 2150.0 <= t_soak - 100.0 <= 2250.0


def test_stability_rule_gives_up_after_max_extra_with_a_warning() -> None:
    step = Step(40.0, 600.0, stable_slope_c_per_min=0.01, stable_window_s=300.0, max_extra_s=900)
    plan = ProfilePlan(Profile("s", (step,)))
    acts = _run_plan(plan, lambda t: 20.0 + 0.1 * t / 60.0, 5000.0)  # never stable
    soaked = [(t, a) for t, a in acts if isinstance(a, Event) and a.event == "soaked"]
    assert len(soaked) == 1 and soaked[0][0] == pytest.approx(1500.0)
    assert "NOT stable" in soaked[0][1].detail
    assert any(isinstance(a, Log) and a.kind == "stability" for _, a in acts)
    assert plan.state == "done"


def test_remaining_and_abort() -> None:
    prof = load_profile("short")
    plan = ProfilePlan(prof)
    assert plan.remaining_s(0) == prof.duration_s
    plan.start(0.0)
    plan.update(100.0)
    assert plan.remaining_s(100.0) == pytest.approx(prof.duration_s - 100.0)
    plan.abort()
    assert plan.update(1e9) == [] and plan.remaining_s(1e9) == 0.0


def test_slope() -> None:
    t = np.arange(0, 600, 10.0)
    assert slope_c_per_min(t, 3.0 + 0.2 * t / 60) == pytest.approx(0.2)
    assert slope_c_per_min(t[:2], t[:2]) == math.inf


def test_profile_outside_bench_limits_is_refused_before_any_io() -> None:
    lim = Limits(setpoint_min_c=-30.0, setpoint_max_c=70.0)
    with pytest.raises(InputError, match="step 12 setpoint -40 °C is outside"):
        check_profile_limits(load_profile("paper"), lim, "paper")
    check_profile_limits(load_profile("paper"), Limits())


def test_example_bench_file_loads_and_round_trips() -> None:
    cfg = load_bench(REPO / "examples" / "lab.toml")
    assert cfg.thermometer.resource.startswith(("ASRL", "TCPIP"))
    assert cfg.run.operator and cfg.run.unit_serial
    again = bench_from_dict({**cfg.to_dict()}, "again")
    assert again.to_dict() == cfg.to_dict()
    # 24-bit ADC, 2.5 V reference, 10 mV/(°/s): one count is about 30 µ°/s.
    assert BenchConfig().rate_stream.dps_per_count() == pytest.approx(2.5 / 2**23 / 0.01)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("[oven]\nprot = 'x'\n", r"\[oven\]: unknown key"),
        ("[limits]\npt100_max_c = 'hot'\n", "pt100_max_c"),
        ("[limits]\nsetpoint_min_c = 80\n", "setpoint_min_c must be below"),
        ("[safe_state]\nsetpoint_c = 200\n", "outside the setpoint limits"),
        ("[recorder]\nflush_every_s = 5\n", "flush_every_s"),
        ("[ovenz]\n", "unknown table"),
        ("[rate_stream]\nport = '/dev/x'\n", r"\[thermometer\] resource is required"),
    ],
)
def test_bad_bench_files_name_the_file_and_key(tmp_path: Path, text: str, match: str) -> None:
    f = tmp_path / "b.toml"
    f.write_text(text)
    with pytest.raises(InputError, match=match) as ei:
        load_bench(f)
    assert str(f) in str(ei.value)
