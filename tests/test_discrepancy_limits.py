"""Issue 18 end to end on short simulated oven runs: detection limits that mean what they
say, no verdict from one reading, real-like noise, revisiting an earlier choice.

The 3.2 h staircase at 2 Hz of test_discrepancy_workflow.py keeps each run to seconds;
the full battery (13 h paper profile) is benchmarks/discrepancy_battery.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from gyrolab.profiles.profile import Profile, Step
from gyrolab.sim.discrepancy.fitting import Structure
from gyrolab.sim.discrepancy.reallike import RealLike, digital_output
from gyrolab.sim.discrepancy.synth import simulate_bench
from gyrolab.sim.discrepancy.workflow import Workflow, run_discrepancy
from gyrolab.sim.model import nominal_model

STEPS = [(25.0, 1800.0), (60.0, 2400.0), (20.0, 2400.0), (-20.0, 2400.0), (-40.0, 2400.0)]
PROFILE = Profile("stairs", tuple(Step(sp, d) for sp, d in STEPS))
RATE = 2.0


def _model(base=None, **effects: dict[str, float]):
    m = base or nominal_model()
    for name, params in effects.items():
        m = m.with_effect(name, **params)
    return m


@pytest.fixture(scope="module")
def nominal_limits():
    """A nominal run whose chamber register rounds to 0.1 °C and whose first reading is
    0.1 °C low: nothing may be named, and its detection limits are the reference."""
    d = simulate_bench(nominal_model(), PROFILE, RATE, 41)
    d.oven_pv = np.round(d.oven_pv, 1)
    d.oven_pv[0] -= 0.1
    res = run_discrepancy(d)
    return res


def test_one_low_first_reading_names_nothing_and_limits_cover_the_vocabulary(nominal_limits):
    res = nominal_limits
    assert res.effects_found == [] and res.ambiguous == []
    lim = res.detection_limits
    expected = {
        "cubic_temp",
        "thermal_rate",
        "thermal_lag",
        "hysteresis",
        "warmup",
        "aging_ramp",
        "periodic",
        "rate_random_walk",
        "quantization",
        "outliers",
        "rtd_self_heating",
        "oven_overshoot",
    }
    assert set(lim) == expected
    for name in expected - {"oven_overshoot"}:
        assert lim[name]["limit"] is not None and lim[name]["limit"] > 0, name
    assert lim["aging_ramp"]["parameter"] == "r" and lim["warmup"]["at"] == {"tau_s": 600.0}
    assert res.to_json()["detection_limits"] == lim


@pytest.mark.parametrize(
    ("strong", "weak"), [("aging_ramp", "cubic_temp"), ("cubic_temp", "aging_ramp")]
)
def test_effect_at_twice_its_limit_is_found_and_at_half_is_not(nominal_limits, strong, weak):
    lim = nominal_limits.detection_limits
    p = {e: lim[e]["parameter"] for e in (strong, weak)}
    m = _model(**{strong: {p[strong]: 2.0 * lim[strong]["limit"]}})
    m = m.with_effect(weak, **{p[weak]: 0.5 * lim[weak]["limit"]})
    res = run_discrepancy(simulate_bench(m, PROFILE, RATE, 42))
    named = set(res.effects_found) | {e for s in res.ambiguous for e in s}
    assert strong in named
    assert weak not in named
    # the effect added states its own gap metric, and that metric shrank
    step = next(s for s in res.steps if s.get("added") == strong)
    b, a = step["gap_metric_before_after"]
    assert step["gap_metric"] == "lf_residual_rms_dps" and a < b


def test_reallike_noise_nominal_clean_and_slow_effects_still_found(nominal_limits):
    """A record with a resonance, a Gauss–Markov hump at long τ and a lattice seen only in
    the first differences, at the simulator's noise level: the lattice is measured (and
    is the ADC's: fine against the noise), nothing is named on the nominal run, and an
    aging ramp plus a cubic term at 2.5× the limits stated under the simulator's own
    noise are both found."""
    quiet = _model(arw={"N": 0.0}, bias_instability={"B": 0.0})
    sw = RealLike().n_arw / 60.0 * np.sqrt(RATE)
    post = digital_output(RealLike(lattice_q=0.05 * sw), 3)
    d0 = simulate_bench(quiet, PROFILE, RATE, 43, post=post)
    assert d0.hr.lattice_step == pytest.approx(0.05 * sw, rel=0.01)
    r0 = run_discrepancy(d0)
    assert r0.effects_found == [] and r0.ambiguous == []
    lim = nominal_limits.detection_limits
    m = _model(
        quiet,
        aging_ramp={"r": 2.5 * lim["aging_ramp"]["limit"]},
        cubic_temp={"c3": 2.5 * lim["cubic_temp"]["limit"]},
    )
    r1 = run_discrepancy(simulate_bench(m, PROFILE, RATE, 43, post=post))
    named = set(r1.effects_found) | {e for s in r1.ambiguous for e in s}
    assert {"aging_ramp", "cubic_temp"} <= named


def test_revisit_drops_an_earlier_choice_the_later_one_explains():
    """Truth: a rate sensitivity. A model that (wrongly) took an aging ramp first and then
    the rate term: the drop-one move removes the ramp."""
    d = simulate_bench(_model(thermal_rate={"k": 5e-3}), PROFILE, RATE, 44)
    wf = Workflow(d, nominal_model())
    names = [e.name for e in nominal_model().effects]
    cur = wf.fitter.fit(Structure(names + ["aging_ramp", "thermal_rate"]))
    out = wf.revisit(cur, ["aging_ramp", "thermal_rate"], "thermal_rate")
    assert out is not None
    fitted, moves = out
    assert moves == [{"move": "drop", "effect": "aging_ramp"}]
    assert "aging_ramp" not in fitted.structure.effects
    assert "thermal_rate" in fitted.structure.effects
