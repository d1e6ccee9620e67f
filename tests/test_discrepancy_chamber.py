"""Issue 18 point 1: a chamber whose cooling derates smoothly near its floor (not with
the simulator's linear knee). The oven fit chooses the smooth rate limit by BIC there,
keeps the knee on the simulator's own chamber, and the thermal-chain effects are still
found on the smooth chamber."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from gyrolab.profiles.profile import Profile, Step
from gyrolab.sim.discrepancy.channels import temperature
from gyrolab.sim.discrepancy.fitting import Fitter, Structure
from gyrolab.sim.discrepancy.synth import simulate_bench
from gyrolab.sim.discrepancy.thermal_fit import air_model, fit_oven
from gyrolab.sim.model import nominal_model
from gyrolab.sim.thermal import lowpass

STEPS = [(25.0, 1800.0), (60.0, 2400.0), (20.0, 2400.0), (-20.0, 2400.0), (-40.0, 2400.0)]
PROFILE = Profile("stairs", tuple(Step(sp, d) for sp, d in STEPS))
SMOOTH = np.array([240.0, 0.05, 0.025, -45.0, 30.0])
"""τ_air 240 s, heating 3 °C/min, cooling 1.5 °C/min derating as 1 − e^{−(T+45)/30}."""


@pytest.fixture(scope="module")
def nominal():
    return simulate_bench(nominal_model(), PROFILE, 2.0, 41)


def smooth_chamber(d, overshoot=None, seed=3):
    """``d``'s bench with its air replaced by a smoothly derating chamber (PV with 2 mK
    noise, not rounded: a 0.01 °C register makes the air at power-on, and so the PT100
    offset's only signature, too uncertain for a 0.3 °C offset on this profile) and the
    PT100 moved by what the new air does to the case: the case model ``τ dTc/dt = air +
    ΔT_self − Tc`` is linear in the air, so the simulator's own reading (its noise,
    self-heating, any ``rtd_self_heating``) plus the low-passed air difference is the
    reading on the new chamber."""
    th = nominal_model().thermal
    rng = np.random.default_rng(seed)
    a0 = float(d.oven_pv[0])
    air = air_model(d.oven_t, d.oven_t, d.oven_sp, a0, SMOOTH, overshoot, "smooth")
    pv = air + 0.002 * rng.standard_normal(air.size)
    grid = np.arange(d.oven_t[0], d.oven_t[-1] + 1.0, 1.0)
    diff = np.interp(grid, d.oven_t, air - d.oven_pv)
    dmid = np.concatenate([0.5 * (diff[:-1] + diff[1:]), [diff[-1]]])
    dcase = lowpass(dmid, 1.0 - math.exp(-1.0 / th.case_tau_s), 0.0)
    return replace(d, oven_pv=pv, pt100_c=d.pt100_c + np.interp(d.pt100_t, grid, dcase))


def test_smooth_rate_limit_chosen_on_a_smooth_chamber_and_knee_kept_on_nominal(nominal):
    th = nominal_model().thermal
    assert fit_oven(nominal, th).form == "knee"
    ds = smooth_chamber(nominal)
    knee = fit_oven(ds, th, form="knee")
    best = fit_oven(ds, th)
    assert best.form == "smooth" and best.smooth is not None
    assert knee.rms > 0.1  # the knee form leaves a chamber-shaped residual
    assert best.rms < 0.005  # the smooth form leaves the PV noise
    assert best.smooth["cool_floor_c"] == pytest.approx(-45.0, abs=1.0)


def test_thermal_chain_effects_found_on_a_smooth_chamber(nominal):
    rtd = simulate_bench(nominal_model().with_effect("rtd_self_heating"), PROFILE, 2.0, 41)
    ds = smooth_chamber(rtd, overshoot=(0.15, 1200.0))
    fx = Fitter(ds, nominal_model())
    cur = fx.fit(Structure([]))
    sig = {c.effect for c in temperature.score(fx, cur) if c.significant}
    assert sig == {"oven_overshoot", "rtd_self_heating"}
    clean = Fitter(smooth_chamber(nominal), nominal_model())
    cur = clean.fit(Structure([]))
    assert not [c for c in temperature.score(clean, cur) if c.significant]
