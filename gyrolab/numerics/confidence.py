"""Confidence intervals of Allan-type deviations: Greenhall & Riley EDF, lag-1 noise
identification, chi-squared bounds.

The equivalent degrees of freedom follow Greenhall & Riley, "Uncertainty of stability
variances based on finite differences" (PTTI 2003) — the algorithm of the NIST "Handbook of
Frequency Stability Analysis" (SP 1065, §5.3). The power-law noise type of each tau is
identified by the lag-1 autocorrelation method of Riley & Greenhall, "Power law noise
identification using the lag 1 autocorrelation" (EFTF 2004). The bounds of a deviation
``s`` with ``edf`` degrees of freedom at two-sided level ``c``, ``p = (1 - c) / 2``
(SP 1065 eq. 45)::

    s_lo = s sqrt(edf / chi2.ppf(1 - p, edf))      s_hi = s sqrt(edf / chi2.ppf(p, edf))

:func:`confidence_bounds` is the one loop over the taus that every deviation uses: noise
type from the tau-averaged rate, the deviation's own EDF, the bounds.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from scipy import stats

__all__ = [
    "NOISE_ID_MAX_POINTS",
    "ONE_SIGMA",
    "confidence_bounds",
    "edf_greenhall",
    "noise_id_lag1",
    "tau_averaged_rate",
]

#: Confidence level of the default bounds: one standard deviation (erf(1/sqrt(2))).
ONE_SIGMA = 0.6826894921370859
#: Longest block-averaged series used for lag-1 noise identification (statistical precision of
#: the lag-1 autocorrelation is then ~3e-3, far finer than the 0.25 decision steps).
NOISE_ID_MAX_POINTS = 1 << 17


def _sw(t: float, alpha: int) -> float:
    # eq. 7: generalised autocovariance of the phase for power-law noise S_y ~ f^alpha.
    # (Overall signs per alpha are irrelevant: only ratios of squares are used.)
    a = abs(t)
    if alpha == 2:
        return -a
    if alpha == 1:
        return t * t * math.log(a) if a > 0 else 0.0
    if alpha == 0:
        return a**3
    if alpha == -1:
        return -(t**4) * math.log(a) if a > 0 else 0.0
    if alpha == -2:
        return -(a**5)
    if alpha == -3:
        return t**6 * math.log(a) if a > 0 else 0.0
    if alpha == -4:
        return a**7
    raise ValueError(f"noise exponent alpha={alpha} outside -4..2")


def _sx(t: float, f: float, alpha: int) -> float:
    # eq. 8: effect of the F-point averaging filter (F = inf: continuous limit)
    if math.isinf(f):
        return _sw(t, alpha + 2)
    return f * f * (2.0 * _sw(t, alpha) - _sw(t - 1.0 / f, alpha) - _sw(t + 1.0 / f, alpha))


_BINOM = {1: (2.0, -1.0), 2: (6.0, -4.0, 1.0), 3: (20.0, -15.0, 6.0, -1.0)}


def _sz(t: float, f: float, alpha: int, d: int) -> float:
    # eq. 9: d-th difference (d = 2 for the Allan variance)
    c = _BINOM[d]
    s = c[0] * _sx(t, f, alpha)
    for k in range(1, d + 1):
        s += c[k] * (_sx(t - k, f, alpha) + _sx(t + k, f, alpha))
    return s


def _basic_sum(j: int, mm: float, s: float, f: float, alpha: int, d: int) -> float:
    # eq. 10
    total = _sz(0.0, f, alpha, d) ** 2
    total += (1.0 - j / mm) * _sz(j / s, f, alpha, d) ** 2
    for jj in range(1, j):
        total += 2.0 * (1.0 - jj / mm) * _sz(jj / s, f, alpha, d) ** 2
    return total


# Greenhall & Riley 2003 table 2 (a0, a1) for unmodified variances, rows alpha = 2..-4,
# columns d = 1, 2, 3; None where alpha + 2d <= 1 (variance does not converge).
_TABLE2: dict[int, tuple[tuple[float, float] | None, ...]] = {
    2: ((3 / 2, 1 / 2), (35 / 18, 1.0), (231 / 100, 3 / 2)),
    1: ((78.6, 25.2), (790.0, 410.0), (9950.0, 6520.0)),
    0: ((2 / 3, 1 / 6), (2 / 3, 1 / 3), (7 / 9, 1 / 2)),
    -1: (None, (0.852, 0.375), (0.997, 0.617)),
    -2: (None, (1.079, 0.368), (1.033, 0.607)),
    -3: (None, None, (1.053, 0.553)),
    -4: (None, None, (1.302, 0.535)),
}
# table 3 (b0, b1) for alpha = 1, d = 1..3
_TABLE3 = ((6.0, 4.0), (15.23, 12.0), (47.8, 40.0))
_JMAX = 100


def edf_greenhall(
    alpha: int,
    m: int,
    n_phase: int,
    overlapping: bool = True,
    d: int = 2,
    modified: bool = False,
) -> float:
    """Equivalent degrees of freedom of an (overlapping) Allan-type variance estimate.

    Greenhall & Riley (PTTI 2003) algorithm: unmodified variances (F = m) or, with
    ``modified``, modified ones (F = 1: MVAR/TVAR; their table 1), stride S = m
    (overlapping) or 1, ``d = 2`` for the Allan variance, 3 for the Hadamard variance.
    ``alpha`` is the power-law exponent of the rate PSD (2 white phase ... -2 random-walk
    rate); ``n_phase`` is the number of phase points. Requires alpha + 2 d > 1.
    """
    alpha = int(alpha)
    if alpha + 2 * d <= 1:
        raise ValueError(f"alpha={alpha} too low for d={d}: variance does not converge")
    if modified:
        return _edf_greenhall_modified(alpha, m, n_phase, overlapping, d)
    f = float(m)
    s = float(m) if overlapping else 1.0
    length = m / f + m * d
    mm = 1.0 + math.floor(s * (n_phase - length) / m)
    if mm < 1:
        return float("nan")
    j = int(min(mm, (d + 1) * s))
    r = mm / s
    if alpha <= 0:
        if j <= _JMAX:
            fp = float(m) if m * (d + 1) <= _JMAX else math.inf
            inv = _basic_sum(j, mm, s, fp, alpha, d) / (_sz(0.0, fp, alpha, d) ** 2 * mm)
        elif r > d + 1:
            a0, a1 = _TABLE2[alpha][d - 1]  # type: ignore[misc]
            inv = (a0 - a1 / r) / r
        else:
            mp = _JMAX / r
            inv = _basic_sum(_JMAX, _JMAX, mp, math.inf, alpha, d) / (
                _sz(0.0, math.inf, alpha, d) ** 2 * _JMAX
            )
    elif alpha == 1:
        if j <= _JMAX:
            inv = _basic_sum(j, mm, s, f, 1, d) / (_sz(0.0, f, 1, d) ** 2 * mm)
        elif r > d + 1:
            a0, a1 = _TABLE2[1][d - 1]  # type: ignore[misc]
            b0, b1 = _TABLE3[d - 1]
            inv = (a0 - a1 / r) / ((b0 + b1 * math.log(m)) ** 2 * r)
        else:
            mp = _JMAX / r
            b0, b1 = _TABLE3[d - 1]
            inv = _basic_sum(_JMAX, _JMAX, mp, mp, 1, d) / ((b0 + b1 * math.log(m)) ** 2 * _JMAX)
    else:  # alpha == 2 (white phase noise)
        if math.ceil(r) > d:
            a0 = math.comb(4 * d, 2 * d) / math.comb(2 * d, d) ** 2
            a1 = d / 2.0
            inv = (a0 - a1 / r) / mm
        else:
            # very few terms: evaluate the exact basic sum (eq. 13) instead of the closed form
            inv = _basic_sum(j, mm, s, f, 2, d) / (_sz(0.0, f, 2, d) ** 2 * mm)
    return 1.0 / inv


# Greenhall & Riley 2003 table 1 (a0, a1) for modified variances (F = 1), alpha = 2..-4.
_TABLE1: dict[int, tuple[tuple[float, float] | None, ...]] = {
    2: ((2 / 3, 1 / 3), (7 / 9, 1 / 2), (22 / 25, 2 / 3)),
    1: ((0.840, 0.345), (0.997, 0.616), (1.141, 0.843)),
    0: ((1.079, 0.368), (1.033, 0.607), (1.184, 0.848)),
    -1: (None, (1.048, 0.534), (1.180, 0.816)),
    -2: (None, (1.302, 0.535), (1.175, 0.777)),
    -3: (None, None, (1.194, 0.703)),
    -4: (None, None, (1.489, 0.702)),
}


def _edf_greenhall_modified(alpha: int, m: int, n_phase: int, overlapping: bool, d: int) -> float:
    # Greenhall & Riley 2003, case 1 (F = 1): the same basic sum with a one-point filter
    s = float(m) if overlapping else 1.0
    mm = 1.0 + math.floor(s * (n_phase - (m + m * d)) / m)  # filter length L = m/F + m d
    if mm < 1:
        return float("nan")
    j = int(min(mm, (d + 1) * s))
    r = mm / s
    if j <= _JMAX:
        inv = _basic_sum(j, mm, s, 1.0, alpha, d) / (_sz(0.0, 1.0, alpha, d) ** 2 * mm)
    elif r > d + 1:
        a0, a1 = _TABLE1[alpha][d - 1]  # type: ignore[misc]
        inv = (a0 - a1 / r) / r
    else:
        inv = _basic_sum(_JMAX, _JMAX, _JMAX / r, 1.0, alpha, d) / (
            _sz(0.0, 1.0, alpha, d) ** 2 * _JMAX
        )
    return 1.0 / inv


def _lag1_acf(z: np.ndarray) -> float:
    # z is already mean-free (detrended or differenced-then-centred by the caller)
    den = float(np.dot(z, z))
    if den == 0.0:
        return float("nan")
    return float(np.dot(z[:-1], z[1:])) / den


def _detrend_inplace(z: np.ndarray) -> None:
    # least-squares line removed with closed-form sums: no Vandermonde matrix, one index array
    n = z.size
    t = np.arange(n, dtype=float)
    t -= (n - 1) / 2.0
    z -= z.mean()
    z -= (float(np.dot(t, z)) / float(np.dot(t, t))) * t


def noise_id_lag1(ybar: np.ndarray, dmax: int = 2) -> tuple[int, float]:
    """Power-law exponent alpha of rate data from the lag-1 autocorrelation.

    Riley & Greenhall (EFTF 2004): remove a linear trend from the (block-averaged) rate
    series, difference it d times until ``delta = r1 / (1 + r1) < 0.25`` (or d = dmax);
    then ``alpha = -2 (delta + d)``, rounded to the nearest integer and clipped to -2..2
    (the range where the Allan variance converges). Needs at least 30 points.
    Returns (alpha_int, alpha_float).
    """
    z = np.array(ybar, dtype=float)  # private copy, detrended in place
    if z.size < 30:
        raise ValueError("noise identification needs at least 30 points")
    _detrend_inplace(z)
    d = 0
    while True:
        if d:
            z -= z.mean()
        r1 = _lag1_acf(z)
        if not np.isfinite(r1):
            return 0, float("nan")
        delta = r1 / (1.0 + r1)
        if delta < 0.25 or d >= dmax:
            a = -2.0 * (delta + d)
            a_int = int(-round(2.0 * delta) - 2 * d)
            return int(min(2, max(-2, a_int))), a
        z = np.diff(z)
        d += 1


def tau_averaged_rate(phase: np.ndarray, m: int, cb: np.ndarray | None = None) -> np.ndarray:
    """The rate averaged over ``tau = m`` samples, from strided views of the phase (no
    n-sized temporaries), in phase units per tau; at most :data:`NOISE_ID_MAX_POINTS`.

    ``cb`` (gaps): the cumulative count of missing units before each phase point; an
    average whose span touches a gap is left out."""
    nb = min((phase.size - 1) // m, (4 if cb is not None else 1) * NOISE_ID_MAX_POINTS)
    ybar = np.diff(phase[: nb * m + 1 : m])
    if cb is not None:
        cbs = cb[: nb * m + 1 : m]
        ybar = ybar[cbs[1:] == cbs[:-1]][:NOISE_ID_MAX_POINTS]
    return ybar


def confidence_bounds(
    phase: np.ndarray,
    ms: np.ndarray,
    dev: np.ndarray,
    edf_of: Callable[[int, int], float],
    confidence: float,
    alpha: int | None = None,
    cb: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """EDF, noise exponent and two-sided ``confidence`` bounds of deviation ``dev`` at each
    averaging factor ``ms``; returns ``(edf, alpha, dev_lo, dev_hi)``.

    The exponent of each tau comes from :func:`noise_id_lag1` on :func:`tau_averaged_rate`
    (30 or more averages; fewer: the previous tau's exponent, 0 at the first), unless
    ``alpha`` forces it. ``edf_of(alpha, m)`` is the deviation's own EDF (e.g.
    :func:`edf_greenhall` with its ``d``, ``modified`` and number of phase points). Bounds
    per module docstring; NaN where the EDF or the deviation is not finite."""
    n = ms.size
    edf = np.full(n, np.nan)
    alphas = np.full(n, np.nan)
    lo = np.full(n, np.nan)
    hi = np.full(n, np.nan)
    last = 0 if alpha is None else int(alpha)
    p = (1.0 - confidence) / 2.0
    for k, m in enumerate(ms):
        m = int(m)
        if alpha is None:
            ybar = tau_averaged_rate(phase, m, cb)
            if ybar.size >= 30:
                last, _ = noise_id_lag1(ybar)
        alphas[k] = last
        e = edf_of(last, m)
        edf[k] = e
        if np.isfinite(e) and e > 0 and np.isfinite(dev[k]):
            lo[k] = dev[k] * math.sqrt(e / stats.chi2.ppf(1.0 - p, e))
            hi[k] = dev[k] * math.sqrt(e / stats.chi2.ppf(p, e))
    return edf, alphas, lo, hi
