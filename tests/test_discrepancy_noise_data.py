"""Issue 18: what the discrepancy workflow learns from the data itself — the output
lattice (from values or first differences), initial temperatures from a window, the
PT100 channel's effective number of readings, the bins' noise model learned from the
residual — and the simulator's wider effect forms (fast unit checks, fixed seeds)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import toeplitz

from gyrolab.sim.discrepancy.data import _lattice
from gyrolab.sim.discrepancy.gls import bin_noise_autocov
from gyrolab.sim.discrepancy.noise_fit import AllanCurve, fit_cov_noise, gm_avar
from gyrolab.sim.discrepancy.reallike import RealLike, reallike_noise
from gyrolab.sim.discrepancy.thermal_fit import delta_bic_channel, initial_value
from gyrolab.sim.model import SimModel, make_effect_spec
from gyrolab.sim.physics import Physics


def f32(x: np.ndarray) -> np.ndarray:
    return x.astype(np.float32).astype(np.float64)


def test_lattice_is_measured_from_values_or_first_differences():
    rng = np.random.default_rng(1)
    x = 0.003 * rng.standard_normal(100_000)
    q = 0.004
    drift = 0.02 + 1e-3 * np.sin(np.arange(x.size) / 20_000)
    # codes as the output
    qv, fv = _lattice(f32(np.round(x / q) * q))
    assert qv == pytest.approx(q, rel=1e-4) and fv > 0.99
    # a digital gyro adding a slow bias after its quantizer: off-lattice values,
    # on-lattice differences
    qd, fd = _lattice(f32(np.round(x / q) * q + drift))
    assert qd == pytest.approx(q, rel=1e-3) and fd > 0.9
    # another ADC step is measured, not assumed
    lsb = 7.3e-5
    assert _lattice(f32(np.round(x / lsb) * lsb))[0] == pytest.approx(lsb, rel=1e-3)
    # a continuum has no lattice
    assert _lattice(f32(x + drift))[1] < 0.5


def test_initial_temperature_comes_from_a_window_not_one_sample():
    t = np.arange(600.0)
    pv = np.round((25.04 + 0.002 * rng_normal(600)) / 0.1) * 0.1  # register rounds to 0.1
    pv[0] -= 0.1  # one bad first reading
    init = initial_value(t, pv)
    assert abs(init.value - 25.0) < 0.01  # the register's value, not the bad sample
    assert init.sigma >= 0.1 / math.sqrt(12) * 0.99  # its rounding is in the uncertainty
    assert init.n > 100


def rng_normal(n: int) -> np.ndarray:
    return np.random.default_rng(7).standard_normal(n)


def test_temperature_channel_counts_effective_readings():
    n = 40_000
    t = np.arange(n)
    white = 0.005 * rng_normal(n)
    # a smooth misfit (another chamber's dynamics) that a constant offset halves
    misfit = 0.02 * np.sin(2 * np.pi * t / 7000.0) + 0.01
    corr, ne_corr = delta_bic_channel(misfit + white, misfit - 0.01 + white, 0.0025, 1)
    iid = 40_000 * math.log(np.mean((misfit + white) ** 2) / np.mean((misfit - 0.01 + white) ** 2))
    assert iid > 1000  # what independent readings would have claimed
    assert ne_corr < 0.01 * n and corr < 25
    # a real constant offset on white readings keeps its full weight
    off, ne = delta_bic_channel(white + 0.01, white, 0.0025, 1)
    assert ne > 0.9 * n and off > 1000


def test_gauss_markov_allan_and_psd_agree():
    """The learned model's Gauss–Markov part: its PSD (folded into bins) gives back its
    Allan variance, and a fit on a record with a hump finds it."""
    n, dlt, sg, tc = 1500, 10.0, 3e-5, 400.0
    r = bin_noise_autocov(n, dlt, 1e-3, 0.0, 0.0, sg, tc)
    for m in (1, 4, 16, 64):
        w = np.concatenate([np.full(m, 1.0 / m), np.full(m, -1.0 / m)])
        avar = 0.5 * w @ toeplitz(r[: 2 * m]) @ w
        expect = 1e-6 / (m * dlt) + gm_avar(np.array([m * dlt]), sg, tc)[0]
        assert avar == pytest.approx(expect, rel=0.05)
    tau = dlt * 2.0 ** np.arange(0, 10)
    truth = 1e-6 / tau + (6e-5) ** 2 + gm_avar(tau, 1e-4, 300.0)
    cn = fit_cov_noise(AllanCurve(tau, np.sqrt(truth), np.full(tau.size, 200.0)), dlt, False)
    assert cn.gm_sigma == pytest.approx(1e-4, rel=0.2)
    assert cn.b_floor == pytest.approx(6e-5, rel=0.2)


def test_reallike_noise_has_the_simulators_level_and_its_own_shape():
    from gyrolab.numerics.allan import allan_deviation

    dt = 0.1
    x = reallike_noise(int(4 * 3600 / dt), dt, np.random.default_rng(3), RealLike())
    ad = allan_deviation(x, 1 / dt, taus=np.array([1, 10, 2560, 5120]) * dt, confidence=None).dev
    # white level as the simulator's N = 0.0523 °/√h at 1 s (plus the resonance's hump)
    assert ad[1] * 3600 == pytest.approx(0.0523 * 60 / math.sqrt(1.0), rel=0.35)
    assert 0.15 < ad[2] * 3600 < 0.45  # the nominal floor's level at a few hundred s


def _out(effects, seconds=4000.0, schedule=((0.0, 60.0), (1500.0, -20.0), (2800.0, 40.0))):
    m = SimModel(effects=tuple(make_effect_spec(n, p) for n, p in effects))
    p = Physics(m, rate_hz=1.0, seed=0)
    out = []
    ch = list(schedule)
    while p.index < seconds:
        while ch and ch[0][0] <= p.index:
            p.set_setpoint(ch.pop(0)[1])
        nxt = min([int(seconds)] + [int(c) for c, _ in ch if c > p.index])
        out.append(p.advance(nxt - p.index).rate_dps)
    return np.concatenate(out), p


def test_wider_effect_forms_default_to_the_old_ones():
    a, _ = _out([("warmup", {"A": 5e-3, "tau_s": 600.0})])
    b, _ = _out([("warmup", {"A": 5e-3, "tau_s": 600.0, "A2": 0.0, "tau2_s": 50.0})])
    np.testing.assert_array_equal(a, b)
    two, p = _out([("warmup", {"A": -4e-3, "tau_s": 2000.0, "A2": 5e-3, "tau2_s": 250.0})])
    t = np.arange(two.size)
    np.testing.assert_allclose(two, -4e-3 * np.exp(-t / 2000) + 5e-3 * np.exp(-t / 250), atol=1e-12)
    h0, _ = _out([("hysteresis", {"h": 2e-3, "width_c": 1.0})])
    h1, _ = _out([("hysteresis", {"h": 2e-3, "width_c": 1.0, "width_tc": 0.0})])
    np.testing.assert_array_equal(h0, h1)
    # a temperature-dependent width changes where the branch flips; it stays within ±h/2
    hw, _ = _out([("hysteresis", {"h": 2e-3, "width_c": 1.0, "width_tc": 0.05})])
    assert np.max(np.abs(hw)) <= 1e-3 + 1e-12
    assert np.max(hw) == pytest.approx(1e-3)
    assert np.max(np.abs(hw - h0)) > 1e-4
