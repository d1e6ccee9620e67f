"""Unit checks of the discrepancy workflow's numerical pieces (fast, fixed seeds)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import cholesky, solve_triangular, toeplitz

from gyrolab.numerics.allan import allan_deviation
from gyrolab.sim.discrepancy.data import from_arrays
from gyrolab.sim.discrepancy.gls import CovWhitener, bin_noise_autocov, gls_ar, gls_cov
from gyrolab.sim.discrepancy.noise_fit import fit_outliers, lattice_phase_hist


def test_fast_oadev_matches_stable32_reference(shared_dir):
    """The discrepancy's Allan call (a τ subset, no confidence work) against Stable32."""
    ref = shared_dir / "ref" / "allan"
    f = np.loadtxt(ref / "ocxo_frequency.txt", comments="#")
    y = f / 1e7 - 1.0
    rows = np.loadtxt(ref / "stable32_oadev_alltau.txt", comments="#")
    m = rows[:, 0].astype(int)
    pick = np.isin(m, [1, 2, 4, 8, 16, 64, 256, 1024])
    res = allan_deviation(y, 1.0, taus=m[pick], confidence=None)
    tau, ad = res.taus, res.dev
    assert np.allclose(tau, rows[pick, 1])
    np.testing.assert_allclose(ad, rows[pick, 5], rtol=2e-3)


def test_fast_oadev_white_noise_slope():
    rng = np.random.default_rng(1)
    x = rng.standard_normal(200_000) * 0.01
    res = allan_deviation(x, 100.0, confidence=None)
    tau, ad = res.taus, res.dev
    # white rate noise: σ(τ) = σ_x √(dt/τ)
    np.testing.assert_allclose(ad[:8], 0.01 * np.sqrt(0.01 / tau[:8]), rtol=0.05)


def test_fast_oadev_of_a_noiseless_channel_is_zero():
    """A noiseless simulated axis is valid input to the workflow: zeros, not an error."""
    from gyrolab.errors import InputError

    x = np.full(1000, -0.5)
    res = allan_deviation(x, 20.0, taus=np.array([0.05, 0.1]), confidence=None, allow_constant=True)
    assert np.array_equal(res.dev, [0.0, 0.0])
    with pytest.raises(InputError, match="constant"):
        allan_deviation(x, 20.0, confidence=None)


def test_bin_autocov_reproduces_allan_model():
    """The bins' covariance from the PSDs gives back the Allan variance it was built from."""
    n, dlt = 2000, 10.0
    nw, b, k = 1.5e-3, 7e-5, 3e-6
    r = bin_noise_autocov(n, dlt, nw, b, k)
    for m in (1, 2, 4, 16, 64):
        # AVAR(mΔ) = var of the difference of adjacent m-bin means / 2, from R
        w = np.concatenate([np.full(m, 1.0 / m), np.full(m, -1.0 / m)])
        c = toeplitz(r[: 2 * m])
        avar = 0.5 * w @ c @ w
        tau = m * dlt
        expect = nw**2 / tau + b**2 + k**2 * tau / 3.0
        # the model's 1/f cut-off and the sinc tail cost a few per cent at most
        assert avar == pytest.approx(expect, rel=0.06)


def test_levinson_whitener_is_inverse_cholesky():
    r = bin_noise_autocov(400, 10.0, 1e-3, 7e-5)
    x = np.random.default_rng(2).standard_normal((400, 3))
    exact = solve_triangular(cholesky(toeplitz(r), lower=True), x, lower=True)
    np.testing.assert_allclose(CovWhitener(r, p=399)(x), exact, rtol=1e-8, atol=1e-6)


def test_gls_recovers_a_trend_in_correlated_noise():
    rng = np.random.default_rng(3)
    n = 3000
    e = np.zeros(n)
    for i in range(1, n):
        e[i] = 0.9 * e[i - 1] + rng.standard_normal()
    t = np.linspace(0, 1, n)
    y = 2.0 + 5.0 * t + e
    X = np.column_stack([np.ones(n), t])
    g = gls_ar(y, X, p=2)
    assert g.phi[0] == pytest.approx(0.9, abs=0.05)
    assert g.beta[1] == pytest.approx(5.0, abs=1.0)
    # an irrelevant regressor does not lower the BIC
    X2 = np.column_stack([X, np.sin(40 * t)])
    assert gls_ar(y, X2, p=2).bic > g.bic - 2.0
    # known-covariance GLS on white noise equals OLS
    w = CovWhitener(np.r_[1.0, np.zeros(n - 1)])
    gc = gls_cov(2.0 + 5.0 * t + rng.standard_normal(n), X, w)
    assert gc.beta[1] == pytest.approx(5.0, abs=0.2)


def _bench(x: np.ndarray, dt: float):
    n_s = int(x.size * dt) + 2
    tt = np.arange(n_s, dtype=float)
    return from_arrays(0.0, dt, x, tt, np.full(n_s, 25.0), tt, np.full(n_s, 25.0), tt + 0.0)


def test_spike_detection_and_lattice():
    rng = np.random.default_rng(4)
    x = 0.01 + 0.003 * rng.standard_normal(300_000)
    idx = rng.choice(x.size - 10, 40, replace=False) + 5
    x[idx] += rng.choice([-1, 1], 40) * 0.08
    d = _bench(x, 0.1)
    assert 36 <= d.hr.spike_t.size <= 40
    o = fit_outliers(d)
    assert o.lr > 40
    assert o.amplitude == pytest.approx(0.08, rel=0.15)
    # no spikes: no evidence
    d0 = _bench(0.01 + 0.003 * rng.standard_normal(300_000), 0.1)
    assert fit_outliers(d0).lr < 20
    # a quantized output sits on its lattice
    q = 0.004
    dq = _bench(np.round(x / q) * q, 0.1)
    assert dq.hr.lattice_step == pytest.approx(q, rel=1e-3)
    assert dq.hr.lattice_fraction > 0.95
    h = lattice_phase_hist(dq, dq.hr.lattice_step)
    assert h.max() > 0.95


def test_select_reports_indistinguishable_candidates_together():
    from gyrolab.sim.discrepancy.scored import Scored
    from gyrolab.sim.discrepancy.workflow import AMBIGUITY_MARGIN, select

    def c(name: str, score: float) -> Scored:
        return Scored(name, "gyro", score, True, {})

    best, amb = select([c("warmup", 150.0), c("aging_ramp", 157.0), c("hysteresis", 60.0)])
    assert best.effect == "aging_ramp"
    assert amb == ["aging_ramp", "warmup"]
    close = [c(n, 100.0 - i) for i, n in enumerate(["a", "b", "c", "d"])]
    assert select(close)[1] == ["a", "b", "c"]  # at most three
    _, alone = select([c("cubic_temp", 80.0), c("thermal_rate", 80.0 - AMBIGUITY_MARGIN)])
    assert alone == ["cubic_temp"]
