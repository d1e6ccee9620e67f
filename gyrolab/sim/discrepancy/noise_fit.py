"""Stochastic terms: the Allan curve of the residual, the spike tail, the value lattice.

**Allan fit.** The measured curve is the overlapping ADEV of the despiked output at
τ ≤ one bin and of the low-frequency residual (output − deterministic fit) above. The model
(IEEE 952 Annex C; ``Q = q Δt/√12`` for the simulator's angle-carrying quantization)::

    σ²(τ) = 3Q²/τ² + N²/τ + B² + K²τ/3

is fitted by weighted least squares on ``ln σ²`` with weights ``edf/2`` (the variance of
``ln σ̂²`` is ≈ 2/edf); ``χ² = Σ (edf_i/2)(ln σ̂²_i − ln σ²_i)²``. ``rate_random_walk`` is
named when adding ``K`` lowers χ² by more than :data:`RRW_CHI2`.

**Outliers.** Every centred second difference ``e_i = x_i − (x_{i−1}+x_{i+1})/2`` is
``N(0, σ_e²)`` for Gaussian noise. A spike of height ±A adds one value near A and two near
A/2 (its neighbours). Above ``c = 3σ_e`` the values of ``|e|`` are fitted as a Poisson
process of intensity::

    λ(v) = n [2φ(v/σ)/σ + p (g(v; A) + 2 g(v; A/2))],   g(v; a) = [φ((v−a)/σ) + φ((v+a)/σ)]/σ

(σ free, p the spike probability per sample) and compared with p = 0 by the likelihood
ratio (:data:`OUTLIER_LR`).

**Quantization.** Every output of a quantizer of step q is a multiple of q; the bench ADC
already quantizes at its LSB. ``quantization`` is named when the output's value lattice is
at least :data:`LATTICE_RATIO` LSBs wide and most first differences sit on it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares, minimize
from scipy.special import log_ndtr, ndtr

from gyrolab.numerics.allan import allan_deviation
from gyrolab.sim.discrepancy.data import BenchData

RRW_CHI2 = 40.0
OUTLIER_LR = 40.0
SPIKE_K_HARD = 8.0
LATTICE_RATIO = 3.0
LATTICE_FRACTION = 0.5
LATTICE_NOISE_RATIO = 0.1
"""A lattice finer than this fraction of the sample noise is taken as the ADC's."""


@dataclass
class AllanCurve:
    tau: np.ndarray
    adev: np.ndarray
    edf: np.ndarray


def edf_estimate(n: int, m: np.ndarray) -> np.ndarray:
    """A conservative equivalent number of degrees of freedom of each overlapping-ADEV
    point: about ``n/m`` independent clusters, halved for the overlap's correlation. (The
    weights of the fit only; Greenhall's EDF, ``gyrolab.numerics.confidence``, would need
    a noise identification per τ of every residual the workflow tries.)"""
    return np.maximum(1.0, 0.5 * (n / np.asarray(m, dtype=float) - 1.0))


def measured_allan(d: BenchData, resid_bins: np.ndarray) -> AllanCurve:
    """ADEV of the despiked output (τ ≤ bin) joined to that of the residual bins (τ > bin),
    the latter at octave τ with at least 8 clusters (m ≤ n/8)."""
    hr = d.hr
    m_hr = np.rint(hr.tau / hr.dt)
    m_oct = 2 ** np.arange(int(np.log2(max(1, resid_bins.size // 8))) + 1)
    res = allan_deviation(
        resid_bins, 1.0 / d.bin_s, taus=m_oct * d.bin_s, confidence=None, allow_constant=True
    )
    tau_b, ad_b = res.taus, res.dev
    keep = tau_b > d.bin_s * 1.01
    m_b = np.rint(tau_b[keep] / d.bin_s)
    tau = np.concatenate([hr.tau, tau_b[keep]])
    ad = np.concatenate([hr.adev, ad_b[keep]])
    edf = np.concatenate([edf_estimate(hr.n, m_hr), edf_estimate(resid_bins.size, m_b)])
    ok = edf >= 4.0
    return AllanCurve(tau[ok], ad[ok], edf[ok])


def model_avar(
    tau: np.ndarray, n: float, b: float, k: float = 0.0, q: float = 0.0, dt: float = 0.01
) -> np.ndarray:
    """Model Allan variance (module docstring); units °/s."""
    qq = q * dt / math.sqrt(12.0)
    return 3.0 * qq * qq / tau**2 + n * n / tau + b * b + k * k * tau / 3.0


@dataclass
class NoiseFit:
    """Fitted noise terms (°/s units: N in °/s/√Hz, B in °/s, K in °/s/√s, q in °/s)."""

    n_white: float
    b_floor: float
    k_rrw: float
    q: float
    chi2: float
    curve: AllanCurve
    dt: float

    def model_adev(self, tau: np.ndarray | None = None) -> np.ndarray:
        t = self.curve.tau if tau is None else tau
        avar = model_avar(t, self.n_white, self.b_floor, self.k_rrw, self.q, self.dt)
        # floor: a model without any noise term compares finitely (and very badly)
        return np.sqrt(np.maximum(avar, 1e-24))

    def sim_params(self) -> dict[str, dict[str, float]]:
        """Simulator parameters (effects.py units: N °/√h, B °/h, K °/h/√h)."""
        return {
            "arw": {"N": self.n_white * 60.0},
            "bias_instability": {"B": self.b_floor * 3600.0},
            "rate_random_walk": {"K": self.k_rrw * 3600.0 * 60.0},
        }


def fit_allan(
    curve: AllanCurve, dt: float, terms: set[str], q: float = 0.0, white0: float = 0.0
) -> NoiseFit:
    """Weighted log-domain fit of the noise terms in ``terms`` (arw, bias_instability,
    rate_random_walk) with the quantization step ``q`` held fixed."""
    tau, s2, w = curve.tau, curve.adev**2, np.sqrt(curve.edf / 2.0)
    names = [t for t in ("arw", "bias_instability", "rate_random_walk") if t in terms]
    n0 = white0 * math.sqrt(dt) if white0 > 0 else float(curve.adev[0] * math.sqrt(tau[0]))
    b0 = float(np.min(curve.adev)) * 0.7
    k0 = float(curve.adev[-1] / math.sqrt(tau[-1] / 3.0)) * 0.3
    start = {"arw": n0, "bias_instability": b0, "rate_random_walk": k0}

    def unpack(x: np.ndarray) -> tuple[float, float, float]:
        v = dict(zip(names, np.exp(np.clip(x, -80.0, 20.0)), strict=True))
        return v.get("arw", 0.0), v.get("bias_instability", 0.0), v.get("rate_random_walk", 0.0)

    def res(x: np.ndarray) -> np.ndarray:
        n, b, k = unpack(x)
        m = model_avar(tau, n, b, k, q, dt) + 1e-300
        return w * (np.log(s2) - np.log(m))

    if names:
        x0 = np.log([max(start[nm], 1e-15) for nm in names])
        best = None
        # a few starts: a term may be negligible, which a log-parameter reaches only far out
        for shift in (0.0, -3.0):
            for j in range(len(names)):
                x = x0.copy()
                x[j] += shift
                r = least_squares(res, x, method="lm", max_nfev=400)
                if best is None or r.cost < best.cost:
                    best = r
        assert best is not None
        n, b, k = unpack(best.x)
        chi2 = 2.0 * float(best.cost)
    else:
        n = b = k = 0.0
        chi2 = float(np.sum(res(np.empty(0)) ** 2))
    return NoiseFit(n, b, k, q, chi2, curve, dt)


# ------------------------------------------------------------------------- outliers


@dataclass
class OutlierFit:
    """Spike-tail fit: null (σ only) against spikes (σ, p, A)."""

    lr: float
    sigma: float
    p: float
    amplitude: float
    n: int

    def sim_params(self, dt: float) -> dict[str, float]:
        return {"rate_per_h": self.p * 3600.0 / dt, "amplitude": self.amplitude}


def _tail_loglik(v: np.ndarray, n: int, c: float, s: float, p: float, a: float) -> float:
    z = v / s

    def g_pdf(aa: float) -> np.ndarray:
        return (np.exp(-0.5 * ((v - aa) / s) ** 2) + np.exp(-0.5 * ((v + aa) / s) ** 2)) / (
            s * math.sqrt(2 * math.pi)
        )

    def g_tail(aa: float) -> float:
        return float(ndtr((aa - c) / s) + ndtr((-aa - c) / s))

    log_gauss = math.log(2.0 * n) - 0.5 * z * z - math.log(s * math.sqrt(2 * math.pi))
    if p > 0:
        lam = np.exp(log_gauss) + n * p * (g_pdf(a) + 2.0 * g_pdf(0.5 * a))
        loglam = np.log(lam + 1e-300)
        integral = 2.0 * n * math.exp(log_ndtr(-c / s)) + n * p * (g_tail(a) + 2 * g_tail(a / 2))
    else:
        loglam = log_gauss
        integral = 2.0 * n * math.exp(log_ndtr(-c / s))
    return float(np.sum(loglam) - integral)


def fit_outliers(d: BenchData, lattice_q: float = 0.0) -> OutlierFit:
    """Likelihood-ratio test of spikes in the tail of the second differences.

    On a coarsely quantized output (``lattice_q`` > 0) ``e`` carries a bounded quantization
    term (|·| ≤ 2q) that the Gaussian tail model does not describe; there only values
    beyond ``SPIKE_K σ_e + 2q`` count, each taken as a spike (none are expected otherwise).
    """
    hr = d.hr
    v = hr.e_tail
    n = max(1, hr.n - 2)
    s0 = hr.e_sigma
    if lattice_q > 0:
        big = v[v > SPIKE_K_HARD * s0 + 2.0 * lattice_q]
        # centre values only: a spike's neighbours sit near A/2
        centre = big[big > 0.7 * np.percentile(big, 90)] if big.size else big
        a = float(np.median(centre)) if centre.size else 0.0
        cnt = int(centre.size)
        lr = 2.0 * cnt * 5.0 if cnt >= 3 else 0.0
        return OutlierFit(lr, s0, cnt / n, a, n)
    if s0 <= 0 or v.size < 5:
        return OutlierFit(0.0, s0, 0.0, 0.0, n)
    c = float(v.min()) if v.size else 3.0 * s0
    c = min(c, 3.0 * s0)
    r0 = minimize(
        lambda x: -_tail_loglik(v, n, c, math.exp(x[0]), 0.0, 0.0),
        [math.log(s0)],
        method="Nelder-Mead",
        options={"xatol": 1e-6, "fatol": 1e-4},
    )
    best = None
    vmax = float(v.max())
    for a0 in np.geomspace(4.0 * s0, max(5.0 * s0, vmax), 6):
        p0 = max(1e-9, 10.0 / n)
        r = minimize(
            lambda x: (
                -_tail_loglik(
                    v, n, c, math.exp(x[0]), 1.0 / (1.0 + math.exp(-x[1])), math.exp(x[2])
                )
            ),
            [math.log(s0), math.log(p0 / (1 - p0)), math.log(a0)],
            method="Nelder-Mead",
            options={"xatol": 1e-5, "fatol": 1e-4, "maxiter": 2000},
        )
        if best is None or r.fun < best.fun:
            best = r
    assert best is not None
    lr = max(0.0, 2.0 * (float(r0.fun) - float(best.fun)))
    s, p, a = (
        math.exp(best.x[0]),
        1.0 / (1.0 + math.exp(-best.x[1])),
        math.exp(best.x[2]),
    )
    return OutlierFit(lr, s, p, a, n)


def spike_counts(d: BenchData, k: float = 5.0) -> tuple[int, float]:
    """Observed number of |e| > k σ_e, and the Gaussian expectation."""
    hr = d.hr
    n = max(1, hr.n - 2)
    obs = int(np.sum(hr.e_tail > k * hr.e_sigma))
    return obs, float(2.0 * n * ndtr(-k))


def expected_spike_excess(d: BenchData, rate_per_h: float, amp: float, k: float = 5.0) -> float:
    """Expected extra |e| > k σ_e from the model's spikes (centre + two neighbours)."""
    hr = d.hr
    s = hr.e_sigma
    p = rate_per_h / 3600.0 * hr.dt
    n = max(1, hr.n - 2)

    def tail(a: float) -> float:
        return float(ndtr((abs(a) - k * s) / s) + ndtr((-abs(a) - k * s) / s))

    return n * p * (tail(amp) + 2.0 * tail(0.5 * amp))


# ---------------------------------------------------------------------- quantization


def lattice_phase_hist(d: BenchData, q: float, bins: int = 21) -> np.ndarray:
    """Histogram (fractions) of the phase of first differences on a lattice of step q."""
    r = d.hr.diffs / q
    ph = r - np.rint(r)
    h, _ = np.histogram(ph, bins=bins, range=(-0.5, 0.5))
    return h / max(1, h.sum())


def model_phase_hist(q_data: float, q_model: float, bins: int = 21) -> np.ndarray:
    """What the model predicts for :func:`lattice_phase_hist` at step ``q_data``: all on
    the lattice when its own lattice step is the same, else spread evenly."""
    h = np.full(bins, 1.0 / bins)
    if q_model > 0 and abs(q_data / q_model - 1.0) < 0.1:
        h = np.zeros(bins)
        h[bins // 2] = 1.0
    return h


# ------------------------------------------------------ the bins' learned noise model

GM_CHI2 = 10.0
"""χ² drop above which a Gauss–Markov part joins the learned noise model."""


def gm_avar(tau: np.ndarray, sigma: float, tc: float) -> np.ndarray:
    """Allan variance of a first-order Gauss–Markov rate process (variance σ², correlation
    time T_c), IEEE 952 Annex C::

        σ²_A(τ) = (σ² T_c/τ) [2 − (T_c/τ)(3 − 4 e^{−τ/T_c} + e^{−2τ/T_c})]

    (K²τ/3 with K² = 2σ²/T_c for τ ≪ T_c, white N² = 2σ²T_c for τ ≫ T_c)."""
    x = np.asarray(tau, dtype=float) / tc
    small = x < 1e-3
    xs = np.where(small, 1.0, x)
    full = (sigma**2 / xs) * (2.0 - (3.0 - 4.0 * np.exp(-xs) + np.exp(-2.0 * xs)) / xs)
    return np.where(small, (2.0 / 3.0) * sigma**2 * x, full)


@dataclass
class CovNoise:
    """Noise model of the low-frequency bins learned from this run's residual: white N,
    flicker B, random walk K (°/s units as :class:`NoiseFit`) and a Gauss–Markov part
    (σ °/s, T_c s) for correlated structure that none of the three power laws has."""

    n_white: float
    b_floor: float
    k_rrw: float
    gm_sigma: float
    gm_tau_s: float
    chi2: float
    n_points: int

    def avar(self, tau: np.ndarray) -> np.ndarray:
        v = model_avar(tau, self.n_white, self.b_floor, self.k_rrw)
        if self.gm_sigma > 0:
            v = v + gm_avar(tau, self.gm_sigma, self.gm_tau_s)
        return v


def fit_cov_noise(curve: AllanCurve, bin_s: float, rrw: bool, gm: bool | None = None) -> CovNoise:
    """Fit the bins' noise model to the measured Allan curve in the band the bins live in
    (τ ≥ bin/2): what happens faster than a bin (resonances, a lattice, spikes) does not
    reach the bins' covariance and must not inflate it. Weighted least squares on
    ``ln σ²`` (weights edf/2, as :func:`fit_allan`). ``gm=None``: the Gauss–Markov part is
    kept when it lowers χ² by more than :data:`GM_CHI2`."""
    keep = curve.tau >= 0.5 * bin_s
    tau, s2 = curve.tau[keep], curve.adev[keep] ** 2
    w = np.sqrt(curve.edf[keep] / 2.0)
    if tau.size < 3:
        tau, s2, w = curve.tau, curve.adev**2, np.sqrt(curve.edf / 2.0)

    def run(with_gm: bool) -> CovNoise:
        names = ["n", "b"] + (["k"] if rrw else []) + (["gs", "gt"] if with_gm else [])
        n0 = float(np.sqrt(s2[0] * tau[0]))
        start = {
            "n": n0,
            "b": float(np.sqrt(np.min(s2))) * 0.7,
            "k": float(np.sqrt(s2[-1] / (tau[-1] / 3.0))) * 0.3,
            "gs": float(np.sqrt(np.min(s2))),
            "gt": float(np.sqrt(tau[0] * tau[-1])),
        }

        def unpack(x: np.ndarray) -> dict[str, float]:
            v = dict(zip(names, np.exp(np.clip(x, -80.0, 25.0)), strict=True))
            if "gt" in v:
                # a hump must show inside the measured range (peak at τ ≈ 1.9 T_c)
                v["gt"] = float(np.clip(v["gt"], tau[0] / 4, tau[-1] / 2))
            return v

        def res(x: np.ndarray) -> np.ndarray:
            v = unpack(x)
            m = model_avar(tau, v["n"], v["b"], v.get("k", 0.0))
            if with_gm:
                m = m + gm_avar(tau, v["gs"], v["gt"])
            return w * (np.log(s2) - np.log(m + 1e-300))

        x0 = np.log([max(start[k], 1e-15) for k in names])
        best = None
        gts = [None] if not with_gm else [tau[0] * 2, np.sqrt(tau[0] * tau[-1]), tau[-1] / 2]
        for gt in gts:
            for shift in (0.0, -3.0):
                x = x0.copy()
                if gt is not None:
                    x[names.index("gt")] = math.log(gt)
                x[1] += shift
                r = least_squares(res, x, method="lm", max_nfev=400)
                if best is None or r.cost < best.cost:
                    best = r
        assert best is not None
        v = unpack(best.x)
        return CovNoise(
            v["n"],
            v["b"],
            v.get("k", 0.0),
            v.get("gs", 0.0),
            v.get("gt", 1.0),
            2.0 * float(best.cost),
            int(tau.size),
        )

    plain = run(False)
    if gm is False or tau.size < 6:
        return plain
    with_gm = run(True)
    if gm or plain.chi2 - with_gm.chi2 > GM_CHI2:
        return with_gm
    return plain
