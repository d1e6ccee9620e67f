"""Overlapping Allan deviation, confidence intervals and IEEE 952 noise terms.

The Allan variance of rate data ``y`` (sample interval ``tau0 = 1/rate``) at
``tau = m * tau0`` is computed from the phase (angle) ``x_k = tau0 * sum_{i<k} y_i``::

    avar(tau) = 1 / (2 tau^2 (N - 2m)) * sum_{i=0}^{N-2m-1} (x_{i+2m} - 2 x_{i+m} + x_i)^2

with ``N`` phase points (IEEE Std 952-1997 Annex C; NIST SP 1065 eq. 14). The non-overlapping
estimator takes every ``m``-th term only (SP 1065 eq. 12). The phase is built once, in place,
by a compensated (Neumaier) cumulative sum of ``y - mean(y)``: second differences are blind to
a constant rate, and removing it keeps the phase small so that 40 M samples keep float64
accuracy. One phase array (8 bytes per sample) is the only large allocation.

Confidence intervals use the equivalent degrees of freedom of Greenhall & Riley,
"Uncertainty of stability variances based on finite differences" (PTTI 2003) — the algorithm
of the NIST "Handbook of Frequency Stability Analysis" (SP 1065, §5.3) — with the power-law
noise type of each tau identified by the lag-1 autocorrelation method of Riley & Greenhall,
"Power law noise identification using the lag 1 autocorrelation" (EFTF 2004), and chi-squared
bounds ``edf * avar / chi2.ppf(...)`` (SP 1065 eq. 45).

Noise terms follow IEEE Std 952-1997 Annex C (rate units ``u``, e.g. deg/s; tau in s)::

    avar(tau) = 3 Q^2 / tau^2 + N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3 + R^2 tau^2 / 2

    Q  quantization noise       [u s]        slope -1   read at tau = sqrt(3) s
    N  angle random walk        [u sqrt(s)]  slope -1/2 read at tau = 1 s
    B  bias instability         [u]          slope 0    sigma_min / 0.664
    K  rate random walk         [u / sqrt(s)] slope +1/2 read at tau = 3 s
    R  rate ramp                [u / s]      slope +1   read at tau = sqrt(2) s

For u = deg/s: ARW in deg/sqrt(h) = 60 N (sqrt(h) = 60 sqrt(s)); B in deg/h = 3600 B;
K in deg/h/sqrt(h) = 216 000 K; R in deg/h^2 = 3600^2 R; Q in arcsec = 3600 Q.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numba
import numpy as np
from scipy import optimize, stats

from gyrolab.errors import InputError

__all__ = [
    "AllanResult",
    "NoiseTerms",
    "allan_deviation",
    "edf_greenhall",
    "noise_id_lag1",
    "noise_terms",
    "tau_grid",
]

#: Confidence level of the default bounds: one standard deviation (erf(1/sqrt(2))).
ONE_SIGMA = 0.6826894921370859
#: sqrt(2 ln 2 / pi): sigma of flicker rate noise B on the flat part of the curve.
FLICKER_FLOOR = math.sqrt(2.0 * math.log(2.0) / math.pi)  # 0.6643
#: Longest block-averaged series used for lag-1 noise identification (statistical precision of
#: the lag-1 autocorrelation is then ~3e-3, far finer than the 0.25 decision steps).
NOISE_ID_MAX_POINTS = 1 << 17


# --------------------------------------------------------------------------------------------
# numba kernels
# --------------------------------------------------------------------------------------------


@numba.njit(cache=True)
def _all_finite(y: np.ndarray) -> bool:
    # np.all(np.isfinite(y)) without its n-byte temporary
    for i in range(y.size):
        if not math.isfinite(y[i]):
            return False
    return True


@numba.njit(cache=True)
def _neumaier_mean(y: np.ndarray) -> float:
    s = 0.0
    c = 0.0
    for i in range(y.size):
        v = y[i]
        t = s + v
        if abs(s) >= abs(v):
            c += (s - t) + v
        else:
            c += (v - t) + s
        s = t
    return (s + c) / y.size


@numba.njit(cache=True)
def _phase_from_rate(y: np.ndarray, tau0: float, out: np.ndarray) -> None:
    """out[0] = 0, out[k] = tau0 * sum_{i<k} (y_i - mean), Neumaier-compensated."""
    mean = _neumaier_mean(y)
    s = 0.0
    c = 0.0
    out[0] = 0.0
    for i in range(y.size):
        v = (y[i] - mean) * tau0
        t = s + v
        if abs(s) >= abs(v):
            c += (s - t) + v
        else:
            c += (v - t) + s
        s = t
        out[i + 1] = s + c


@numba.njit(cache=True)
def _phase_detrended(x: np.ndarray, out: np.ndarray) -> None:
    """out = x minus the line through its end points (second differences are unchanged)."""
    n = x.size
    x0 = x[0]
    slope = (x[n - 1] - x0) / (n - 1) if n > 1 else 0.0
    for i in range(n):
        out[i] = (x[i] - x0) - slope * i


@numba.njit(cache=True)
def _sum_sq_second_diff(x: np.ndarray, m: int, stride: int) -> tuple[float, int]:
    """sum over i = 0, stride, 2 stride, ... < N - 2m of (x[i+2m] - 2 x[i+m] + x[i])^2."""
    n = x.size - 2 * m
    if n <= 0:
        return 0.0, 0
    # four independent accumulators: breaks the add dependency chain (speed) and acts as a
    # short pairwise sum (accuracy) without fastmath reordering
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    s3 = 0.0
    count = (n - 1) // stride + 1
    i = 0
    k = 0
    last = count - count % 4
    while k < last:
        d0 = x[i + 2 * m] - 2.0 * x[i + m] + x[i]
        i += stride
        d1 = x[i + 2 * m] - 2.0 * x[i + m] + x[i]
        i += stride
        d2 = x[i + 2 * m] - 2.0 * x[i + m] + x[i]
        i += stride
        d3 = x[i + 2 * m] - 2.0 * x[i + m] + x[i]
        i += stride
        s0 += d0 * d0
        s1 += d1 * d1
        s2 += d2 * d2
        s3 += d3 * d3
        k += 4
    while k < count:
        d0 = x[i + 2 * m] - 2.0 * x[i + m] + x[i]
        s0 += d0 * d0
        i += stride
        k += 1
    return (s0 + s1) + (s2 + s3), count


# --------------------------------------------------------------------------------------------
# tau grids
# --------------------------------------------------------------------------------------------


def _max_af(n_phase: int) -> int:
    # at least one second difference: x[i + 2m] must exist
    return max((n_phase - 1) // 2, 0)


def tau_grid(
    n_phase: int,
    rate: float,
    taus: str | np.ndarray | list[float] = "octave",
) -> np.ndarray:
    """Averaging factors ``m`` (tau = m / rate) for ``n_phase`` phase points.

    ``"octave"``: 1, 2, 4, 8, ...; ``"decade"``: 1, 2, 4, 10, 20, 40, ... (Stable32 style);
    ``"all"``: every m; an array: those taus in seconds, rounded to whole samples, duplicates
    and out-of-range values dropped. The largest m leaves at least one second difference
    (m <= (n_phase - 1) // 2).
    """
    mmax = _max_af(n_phase)
    if mmax < 1:
        return np.zeros(0, dtype=np.int64)
    if isinstance(taus, str):
        if taus == "octave":
            m = 2 ** np.arange(int(math.log2(mmax)) + 1, dtype=np.int64)
        elif taus == "decade":
            dec = 10 ** np.arange(int(math.log10(mmax)) + 1, dtype=np.int64)
            m = (dec[:, None] * np.array([1, 2, 4], dtype=np.int64)).ravel()
        elif taus == "all":
            m = np.arange(1, mmax + 1, dtype=np.int64)
        else:
            raise InputError(None, f"unknown tau grid {taus!r} (octave, decade, all or array)")
    else:
        t = np.asarray(taus, dtype=float).ravel()
        if not np.all(np.isfinite(t)):
            raise InputError(None, "tau list contains NaN or infinite values")
        m = np.round(t * rate).astype(np.int64)
    m = np.unique(m[(m >= 1) & (m <= mmax)])
    return m


# --------------------------------------------------------------------------------------------
# Equivalent degrees of freedom (Greenhall & Riley 2003) and noise identification
# --------------------------------------------------------------------------------------------


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


# --------------------------------------------------------------------------------------------
# Allan deviation
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class AllanResult:
    """Allan deviation curve. Units: taus in s, adev in the rate unit of the data."""

    taus: np.ndarray  #: averaging times (s)
    adev: np.ndarray  #: Allan deviation (rate units)
    n: np.ndarray  #: number of second differences averaged at each tau
    m: np.ndarray  #: averaging factor, tau = m / rate
    adev_lo: np.ndarray  #: lower confidence bound
    adev_hi: np.ndarray  #: upper confidence bound
    edf: np.ndarray  #: equivalent degrees of freedom (Greenhall & Riley)
    alpha: np.ndarray  #: power-law noise exponent used for the EDF (rate PSD ~ f^alpha)
    rate: float  #: sample rate (Hz)
    overlapping: bool = True
    confidence: float = ONE_SIGMA
    data_type: str = "rate"
    extra: dict = field(default_factory=dict)

    @property
    def avar(self) -> np.ndarray:
        return self.adev**2

    @property
    def duration_s(self) -> float:
        """Length of the record (s) the curve was computed on."""
        return float(self.extra.get("record_s", float("nan")))

    def to_dict(self) -> dict:
        """JSON-ready copy (lists of floats; NaN stays NaN)."""
        d: dict = {
            k: [float(v) for v in getattr(self, k)]
            for k in ("taus", "adev", "adev_lo", "adev_hi", "edf", "alpha")
        }
        d.update(
            n=[int(v) for v in self.n],
            m=[int(v) for v in self.m],
            rate=self.rate,
            overlapping=self.overlapping,
            confidence=self.confidence,
            data_type=self.data_type,
            duration_s=self.duration_s,
        )
        return d


def _check_input(data: np.ndarray, rate: float) -> None:
    if not (np.isfinite(rate) and rate > 0):
        raise InputError(None, f"sample rate must be positive and finite, got {rate!r}")
    if data.ndim != 1:
        raise InputError(None, f"Allan deviation needs a 1-D series, got shape {data.shape}")
    if data.size < 3:
        raise InputError(None, f"series too short for an Allan deviation ({data.size} samples)")
    if not _all_finite(data):
        raise InputError(None, "series contains NaN or infinite values")


def allan_deviation(
    data: np.ndarray,
    rate: float,
    taus: str | np.ndarray | list[float] = "octave",
    data_type: Literal["rate", "angle", "phase", "freq"] = "rate",
    overlapping: bool = True,
    confidence: float | None = ONE_SIGMA,
    alpha: int | None = None,
) -> AllanResult:
    """Allan deviation of rate data (e.g. deg/s) or angle data (e.g. deg).

    Parameters
    ----------
    data : 1-D array. ``data_type="rate"`` (alias ``"freq"``): rate samples; ``"angle"``
        (alias ``"phase"``): integrated angle samples, in rate-unit * s.
    rate : sample rate in Hz (tau0 = 1 / rate).
    taus : ``"octave"``, ``"decade"``, ``"all"`` or taus in seconds (see :func:`tau_grid`).
    overlapping : overlapping estimator (all N - 2m differences) or non-overlapping (stride m).
    confidence : two-sided confidence level of ``adev_lo``/``adev_hi``; ``None`` skips noise
        identification and EDF (bounds and edf are NaN).
    alpha : force the power-law noise exponent for the EDF instead of identifying it per tau.

    Returns an :class:`AllanResult`. Raises :class:`~gyrolab.errors.InputError` on NaN/inf,
    a series too short for any tau, or a constant series.
    """
    arr = np.asarray(data)
    if arr.dtype != np.float64:
        arr = arr.astype(np.float64)
    arr = np.ascontiguousarray(arr)
    _check_input(arr, float(rate))
    tau0 = 1.0 / float(rate)
    if data_type in ("rate", "freq"):
        phase = np.empty(arr.size + 1, dtype=np.float64)
        _phase_from_rate(arr, tau0, phase)
    elif data_type in ("angle", "phase"):
        phase = np.empty(arr.size, dtype=np.float64)
        _phase_detrended(arr, phase)
    else:
        raise InputError(None, f"unknown data_type {data_type!r} (rate or angle)")
    n_phase = phase.size
    ms = tau_grid(n_phase, float(rate), taus)
    if ms.size == 0:
        raise InputError(
            None, f"series too short for the requested taus ({arr.size} samples at {rate} Hz)"
        )

    adev = np.empty(ms.size)
    nterms = np.empty(ms.size, dtype=np.int64)
    for k, m in enumerate(ms):
        s, c = _sum_sq_second_diff(phase, int(m), int(m) if not overlapping else 1)
        t = m * tau0
        adev[k] = math.sqrt(s / (2.0 * t * t * c))
        nterms[k] = c
    if not np.any(adev > 0):
        raise InputError(None, "constant series: the Allan deviation is zero at every tau")

    edf = np.full(ms.size, np.nan)
    alphas = np.full(ms.size, np.nan)
    lo = np.full(ms.size, np.nan)
    hi = np.full(ms.size, np.nan)
    if confidence is not None:
        last_alpha = 0 if alpha is None else int(alpha)
        for k, m in enumerate(ms):
            if alpha is None:
                # block-averaged rate at this tau, taken from the phase without a copy of it
                nb = min((n_phase - 1) // int(m), NOISE_ID_MAX_POINTS)
                if nb >= 30:
                    xs = phase[: nb * int(m) + 1 : int(m)]
                    ybar = np.diff(xs)
                    last_alpha, _ = noise_id_lag1(ybar)
                    del ybar
                # fewer than 30 averages: keep the exponent of the previous tau
            a = last_alpha
            alphas[k] = a
            e = edf_greenhall(a, int(m), n_phase, overlapping=overlapping)
            edf[k] = e
            if np.isfinite(e) and e > 0:
                p_lo = (1.0 - confidence) / 2.0
                chi_lo = stats.chi2.ppf(p_lo, e)
                chi_hi = stats.chi2.ppf(1.0 - p_lo, e)
                lo[k] = adev[k] * math.sqrt(e / chi_hi)
                hi[k] = adev[k] * math.sqrt(e / chi_lo)
    return AllanResult(
        taus=ms * tau0,
        adev=adev,
        n=nterms,
        m=ms,
        adev_lo=lo,
        adev_hi=hi,
        edf=edf,
        alpha=alphas,
        rate=float(rate),
        overlapping=overlapping,
        confidence=ONE_SIGMA if confidence is None else float(confidence),
        data_type="rate" if data_type in ("rate", "freq") else "angle",
        extra={"record_s": (n_phase - 1) * tau0},
    )


# --------------------------------------------------------------------------------------------
# IEEE 952 noise terms
# --------------------------------------------------------------------------------------------

# name: (log-log slope of the deviation, tau (s) at which the line reads the coefficient)
_SLOPE_RULES = {
    "Q": (-1.0, math.sqrt(3.0)),
    "N": (-0.5, 1.0),
    "K": (0.5, 3.0),
    "R": (1.0, math.sqrt(2.0)),
}
# the slopes a region of each term must be told apart from (its physical neighbours)
_NEIGHBOURS = {"Q": (-0.5,), "N": (-1.0, 0.0), "B": (-0.5, 0.5), "K": (0.0, 1.0), "R": (0.5,)}
# avar coefficient c_p of tau^p -> term: Q = sqrt(c/3), N = sqrt(c), B = sqrt(c/FLOOR^2) ...
_FIT_POWERS = {"Q": -2, "N": -1, "B": 0, "K": 1, "R": 2}
_FIT_SCALE = {"Q": 3.0, "N": 1.0, "B": FLICKER_FLOOR**2, "K": 1.0 / 3.0, "R": 0.5}
#: Confidence of the slope tests (two-sided 95 %): a region's local slopes must be
#: consistent with the term's slope, and its fitted slope inconsistent with the
#: neighbouring terms' slopes, at this level.
SLOPE_TEST_LEVEL = 0.95
#: How far (in log-log slope) a local slope may sit from a term's own where that term
#: dominates: the other terms then contribute a few per cent of the variance (a white-noise
#: curve with a flicker floor 10x below it bends by less than 0.1 over an octave).
DOMINANCE_TOL = 0.1


@dataclass(frozen=True)
class NoiseTerms:
    """IEEE 952 noise coefficients in the data's rate unit ``u`` (tau in seconds).

    Q [u s], N [u sqrt(s)], B [u], K [u/sqrt(s)], R [u/s]. A term the curve does not
    identify is NaN here, ``None`` in :meth:`to_dict` / :meth:`deg_h`, and ``reasons``
    says why; ``tau_ranges`` gives the (first, last) tau (s) each identified term was read
    on; ``upper_bounds`` holds sigma_min/0.664 when there is no floor (an upper bound on B).
    """

    Q: float
    N: float
    B: float
    K: float
    R: float
    method: str
    tau_b: float = float("nan")  #: tau (s) of the minimum of the curve (B read there)
    slopes: dict = field(default_factory=dict)  #: local slope actually used per term
    reasons: dict = field(default_factory=dict)  #: term -> why it is not identifiable
    tau_ranges: dict = field(default_factory=dict)  #: term -> (tau_lo, tau_hi) in s
    upper_bounds: dict = field(default_factory=dict)  #: term -> upper bound (rate units)

    def value(self, name: str) -> float | None:
        """The term, or ``None`` when not identifiable."""
        v = float(getattr(self, name))
        return v if math.isfinite(v) else None

    def to_dict(self) -> dict:
        """JSON-ready: the raw terms (``None`` if not identifiable), the customary units,
        method, tau_b, slopes, reasons, tau ranges and upper bounds."""
        return {
            **{k: self.value(k) for k in "QNBKR"},
            **self.deg_h(),
            "method": self.method,
            "tau_b": self.tau_b,
            "slopes": dict(self.slopes),
            "reasons": dict(self.reasons),
            "tau_ranges": {k: list(v) for k, v in self.tau_ranges.items()},
            "upper_bounds": dict(self.upper_bounds),
        }

    def deg_h(self) -> dict[str, float | None]:
        """The terms for data in deg/s, in the customary gyro units (``None``: not
        identifiable)."""
        scale = {
            "quantization_arcsec": ("Q", 3600.0),
            "arw_deg_per_sqrt_h": ("N", 60.0),
            "bias_instability_deg_per_h": ("B", 3600.0),
            "rrw_deg_per_h_per_sqrt_h": ("K", 216000.0),
            "rate_ramp_deg_per_h2": ("R", 3600.0**2),
        }
        out: dict[str, float | None] = {}
        for key, (name, f) in scale.items():
            v = self.value(name)
            out[key] = None if v is None else f * v
        return out


def _log_uncertainty(result: AllanResult, ok: np.ndarray) -> np.ndarray:
    """One-sigma uncertainty of log10(adev) per point from the confidence bounds (NaN
    where the result has none): half the log width of the interval over its z."""
    lo = np.asarray(result.adev_lo, dtype=float)[ok]
    hi = np.asarray(result.adev_hi, dtype=float)[ok]
    z = stats.norm.ppf(0.5 + float(result.confidence) / 2.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = (np.log10(hi) - np.log10(lo)) / (2.0 * z)
    return np.where(np.isfinite(u) & (u > 0), u, np.nan)


def _region_slope(lt: np.ndarray, la: np.ndarray, u: np.ndarray) -> tuple[float, float]:
    """Weighted least-squares slope of log10 adev against log10 tau and its standard error
    (points taken as independent: conservative, adjacent overlapping estimates are
    positively correlated)."""
    w = 1.0 / u**2
    xm = float(np.sum(w * lt) / np.sum(w))
    sxx = float(np.sum(w * (lt - xm) ** 2))
    slope = float(np.sum(w * (lt - xm) * la) / sxx)
    return slope, 1.0 / math.sqrt(sxx)


def _best_region(
    lt: np.ndarray,
    la: np.ndarray,
    u: np.ndarray | None,
    slope: float,
    neighbours: tuple[float, ...],
    slope_tol: float,
    start: int | None = None,
    end: int | None = None,
    contains: int | None = None,
    min_points: int = 2,
) -> tuple[int, int] | None:
    """The longest run of consecutive points ``[i, j]`` (``min_points`` or more) on which
    the data identify ``slope``.

    Every local (pair) slope must be within ``slope_tol`` of it; with confidence bounds
    also within :data:`DOMINANCE_TOL` of it up to its own uncertainty (z at
    :data:`SLOPE_TEST_LEVEL`), and the run's fitted slope must exclude every neighbouring
    term's slope at that level. Optional constraints: the run starts at ``start``, ends
    at ``end``, contains ``contains``."""
    n = lt.size
    local = np.diff(la) / np.diff(lt)
    z = stats.norm.ppf(0.5 + SLOPE_TEST_LEVEL / 2.0)
    if u is not None:
        u_local = np.sqrt(u[:-1] ** 2 + u[1:] ** 2) / np.diff(lt)
        pair_ok = np.abs(local - slope) <= np.minimum(slope_tol, DOMINANCE_TOL + z * u_local)
    else:
        pair_ok = np.abs(local - slope) <= slope_tol
    best: tuple[int, int] | None = None
    for i in range(n - 1):
        if start is not None and i != start:
            continue
        for j in range(i + 1, n):
            if not pair_ok[j - 1]:
                break  # the run cannot extend past a pair of the wrong slope
            if end is not None and j != end:
                continue
            if contains is not None and not i <= contains <= j:
                continue
            if j - i + 1 < min_points:
                continue
            if u is not None:
                s_hat, s_err = _region_slope(lt[i : j + 1], la[i : j + 1], u[i : j + 1])
                if any(abs(s_hat - nb) <= z * s_err for nb in neighbours):
                    continue
            if best is None or j - i > best[1] - best[0]:
                best = (i, j)
    return best


def _nnls_terms(taus: np.ndarray, adev: np.ndarray, edf: np.ndarray, names: str) -> dict:
    """Coefficients c_p of avar = sum c_p tau^p (non-negative least squares), each point
    weighted by its relative uncertainty sqrt(edf / 2) / avar (unit weights where the EDF
    is unknown)."""
    powers = np.array([_FIT_POWERS[t] for t in names], dtype=float)
    avar = adev**2
    w = np.where(np.isfinite(edf) & (edf > 0), np.sqrt(np.maximum(edf, 1e-12) / 2.0), 1.0)
    w = w / avar
    a = (taus[:, None] ** powers[None, :]) * w[:, None]
    b = avar * w
    # scale columns so NNLS is well conditioned across decades of tau
    col = np.linalg.norm(a, axis=0)
    col[col == 0] = 1.0
    c, _ = optimize.nnls(a / col, b, maxiter=50 * len(names))
    return dict(zip(names, c / col, strict=True))


def _fmt_tau(t: float) -> str:
    return f"{t:.3g} s"


def noise_terms(
    result: AllanResult,
    method: Literal["slope", "fit"] = "slope",
    slope_tol: float | None = 0.25,
    terms: tuple[str, ...] = ("Q", "N", "B", "K", "R"),
    b_max_tau_fraction: float = 0.1,
) -> NoiseTerms:
    """IEEE 952 noise terms from an Allan deviation curve, only where the curve identifies
    them.

    Every term is read from taus with at least 1/``b_max_tau_fraction`` (default 10)
    independent averages: tau <= T/10, T the record length (the last points rest on a
    handful of averages and scatter).

    ``method="slope"`` (IEEE 952 C.2 slope rules, made testable): a term with slope s is
    read on the longest run of two or more consecutive taus whose local slopes are within
    ``slope_tol`` of s and — when the result has confidence bounds — on which the line of
    slope s is consistent with the points while the lines of the neighbouring terms'
    slopes (s ± 1/2) are rejected (chi-squared of the log deviations, 95 %). The line's
    value at the term's tau gives it (N at 1 s, K at 3 s, R at sqrt(2) s, Q at sqrt(3) s).
    Q (white angle noise falls fastest) must start at the shortest tau, R (rises fastest)
    must end at the longest usable one. B = sigma_min / 0.664 only at a true floor: a run
    through the minimum identified as slope 0 by the same test; otherwise B is not
    identifiable and sigma_min / 0.664 is reported as an upper bound. Terms that fail are
    NaN with a reason in ``NoiseTerms.reasons``.

    ``slope_tol=None`` is the single-point rule (always read, no confidence test): each
    term from the adjacent pair whose slope is closest to its own, B at the minimum
    (what the ``arw_deg_per_sqrt_h``/``bias_instability_deg_per_h`` metrics use).

    ``method="fit"``: non-negative least squares of avar(tau) = sum c_p tau^p over the terms
    asked for, on the usable taus, each point weighted by its relative uncertainty
    sqrt(edf / 2) / avar (unit weights where the EDF is unknown); Q, N, B, K, R follow from
    c_p (module docstring). A term whose fitted share of avar is below one half at every
    usable tau is not identifiable (it is never the term the data show).
    """
    taus = np.asarray(result.taus, dtype=float)
    adev = np.asarray(result.adev, dtype=float)
    ok = adev > 0
    u_all = _log_uncertainty(result, ok)
    taus, adev = taus[ok], adev[ok]
    edf = np.asarray(result.edf, dtype=float)[ok]
    if taus.size == 0:
        raise InputError(None, "Allan deviation curve is empty or zero")
    record_s = result.duration_s if np.isfinite(result.duration_s) else np.inf
    usable = taus <= b_max_tau_fraction * record_s
    t_max = b_max_tau_fraction * record_s
    if not usable.any():
        usable[:] = True
    taus, adev, edf, u_all = taus[usable], adev[usable], edf[usable], u_all[usable]
    imin = int(np.argmin(adev))
    tau_b = float(taus[imin])
    out = dict.fromkeys("QNBKR", float("nan"))
    slopes: dict[str, float] = {}
    reasons: dict[str, str] = {}
    ranges: dict[str, tuple[float, float]] = {}
    bounds: dict[str, float] = {}
    few = f"tau <= T/{1 / b_max_tau_fraction:.0f} = {_fmt_tau(t_max)}"
    if method == "slope":
        lt, la = np.log10(taus), np.log10(adev)
        local = np.diff(la) / np.diff(lt) if taus.size >= 2 else np.zeros(0)
        have_ci = bool(np.all(np.isfinite(u_all))) and slope_tol is not None
        u = u_all if have_ci else None
        if slope_tol is None:
            # single-point rule: always read
            if "B" in terms:
                out["B"] = float(adev[imin] / FLICKER_FLOOR)
                slopes["B"] = 0.0
                ranges["B"] = (tau_b, tau_b)
            for name, (slope, tau_read) in _SLOPE_RULES.items():
                if name not in terms or local.size == 0:
                    continue
                i = int(np.argmin(np.abs(local - slope)))
                slopes[name] = float(local[i])
                lt_mid = 0.5 * (lt[i] + lt[i + 1])
                la_mid = 0.5 * (la[i] + la[i + 1])
                out[name] = float(10.0 ** (la_mid + slope * (math.log10(tau_read) - lt_mid)))
                ranges[name] = (float(taus[i]), float(taus[i + 1]))
        else:
            tol = float(slope_tol)
            how = "whose confidence intervals separate it from the neighbouring slopes"
            how = how if have_ci else ""
            for name in ("Q", "N", "B", "K", "R"):
                if name not in terms:
                    continue
                slope, tau_read = (0.0, float("nan")) if name == "B" else _SLOPE_RULES[name]
                kw: dict = {}
                if name == "Q":
                    kw["start"] = 0
                elif name == "R":
                    kw["end"] = taus.size - 1
                elif name == "B":
                    # a floor spans at least two octaves: over one, any V-shaped minimum
                    # between a falling and a rising term looks flat
                    kw.update(contains=imin, min_points=3)
                reg = (
                    _best_region(lt, la, u, slope, _NEIGHBOURS[name], tol, **kw)
                    if taus.size >= 2
                    else None
                )
                if reg is None:
                    if name == "B":
                        bounds["B"] = float(adev[imin] / FLICKER_FLOOR)
                        reasons["B"] = (
                            f"no floor within the record: the minimum at {_fmt_tau(tau_b)} "
                            f"(of {few}) is not on a flat stretch {how}".rstrip()
                            + f"; sigma_min/0.664 = {bounds['B']:.4g} is an upper bound"
                        )
                    else:
                        where = {"Q": " starting at the shortest tau", "R": " ending at T/10"}
                        reasons[name] = (
                            f"no run of taus with slope {slope:+g}{where.get(name, '')} in "
                            f"{few} {how}".rstrip()
                        )
                    continue
                i, j = reg
                ranges[name] = (float(taus[i]), float(taus[j]))
                slopes[name] = float((la[j] - la[i]) / (lt[j] - lt[i]))
                if name == "B":
                    out["B"] = float(adev[imin] / FLICKER_FLOOR)
                    continue
                w = None if u is None else 1.0 / u[i : j + 1] ** 2
                c = float(np.average(la[i : j + 1] - slope * lt[i : j + 1], weights=w))
                out[name] = float(10.0 ** (c + slope * math.log10(tau_read)))
            if have_ci:
                # the values of the identified terms from a joint fit of all five on the
                # usable taus: a single-slope line through a region also carries the
                # neighbouring terms' share of it (K read next to a white-noise region
                # comes out ~40 % high); B stays the IEEE sigma_min / 0.664
                joint = _nnls_terms(taus, adev, edf, "QNBKR")
                for name in ("Q", "N", "K", "R"):
                    if np.isfinite(out[name]) and joint[name] > 0:
                        out[name] = float(math.sqrt(joint[name] / _FIT_SCALE[name]))
    elif method == "fit":
        names = [t for t in "QNBKR" if t in terms]
        powers = np.array([_FIT_POWERS[t] for t in names], dtype=float)
        fitted = _nnls_terms(taus, adev, edf, "".join(names))
        c = np.array([fitted[t] for t in names])
        model = taus[:, None] ** powers[None, :] * c[None, :]
        share = model / np.maximum(model.sum(axis=1, keepdims=True), np.finfo(float).tiny)
        for k, (t, cp) in enumerate(zip(names, c, strict=True)):
            slopes[t] = _FIT_POWERS[t] / 2.0
            if not cp > 0:
                reasons[t] = f"fitted to zero on {few}"
                continue
            dom = share[:, k] >= 0.5
            if not dom.any():
                reasons[t] = f"never half of the fitted Allan variance at {few}"
                continue
            out[t] = float(math.sqrt(cp / _FIT_SCALE[t]))
            ranges[t] = (float(taus[dom][0]), float(taus[dom][-1]))
    else:
        raise InputError(None, f"unknown noise-term method {method!r} (slope or fit)")
    return NoiseTerms(
        **out,
        method=method,
        tau_b=tau_b,
        slopes=slopes,
        reasons=reasons,
        tau_ranges=ranges,
        upper_bounds=bounds,
    )
