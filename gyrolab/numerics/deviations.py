"""The time-and-frequency family beside the Allan deviation: MDEV, TDEV, HDEV, TOTDEV, and
:func:`deviation`, one entry to all five (its OADEV is
:func:`~gyrolab.numerics.allan.allan_deviation`).

All estimators work on the phase (angle) ``x_k = tau0 * sum_{i<k} y_i`` of rate data ``y``
(built once by :mod:`gyrolab.numerics.phase`'s compensated cumulative sum), ``N`` phase
points, ``tau = m * tau0`` (NIST SP 1065, W. J. Riley, "Handbook of Frequency Stability
Analysis", 2008; equation numbers below are SP 1065's)::

    OADEV  s2 = 1/(2 tau^2 (N-2m)) sum_{i} (x_{i+2m} - 2x_{i+m} + x_i)^2               (14)
    MDEV   s2 = 1/(2 m^2 tau^2 (N-3m+1)) sum_j [sum_{i=j}^{j+m-1}
                                              (x_{i+2m} - 2x_{i+m} + x_i)]^2           (15)
    TDEV   s  = tau / sqrt(3) * MDEV                                                  (17)
    HDEV   s2 = 1/(6 tau^2 (N-3m)) sum_i (x_{i+3m} - 3x_{i+2m} + 3x_{i+m} - x_i)^2    (18)
    TOTDEV s2 = 1/(2 tau^2 (N-2)) sum_{i=2}^{N-1} (x*_{i-m} - 2x*_i + x*_{i+m})^2     (25)

HDEV is the overlapping Hadamard deviation; TOTDEV's ``x*`` is the record extended by odd
reflection at both ends (``x*_{1-j} = 2x_1 - x_{1+j}``, ``x*_{N+j} = 2x_N - x_{N-j}``).
Units, for rate in deg/s: every deviation in deg/s except TDEV, in deg (an angle).

**Gaps.** Missing samples are NaN (a recording's index jumps,
:func:`~gyrolab.numerics.phase.gap_filled`). They are never interpolated: a term (one
squared difference, or MDEV's inner sum) is used only when every rate sample it integrates
is present, i.e. the term's span of phase points
``[p_0, p_K]`` has no missing sample (for angle input: no NaN point in the span); the
variance is the mean over the terms kept, ``n`` counts them. This is the "skip the
differences that touch a gap" rule of Stable32's gap handling and of allantools' gap-
resistant ADEV, applied to the whole span (an MDEV term uses every point of its span). For
TOTDEV every gap-free segment is reflected at its own ends and the segments' sums are
pooled (sum over segments / sum of their ``N_s - 2``). A record without gaps gives the
textbook estimators exactly (tests: allantools to 1e-10; SP 1065 tables 30 and 31).

**Confidence intervals.** EDF by Greenhall & Riley (PTTI 2003): unmodified, d = 2 (OADEV)
or d = 3 (HDEV), modified (F = 1, d = 2) for MDEV and TDEV, all overlapping; TOTDEV by
SP 1065 table 7, ``edf = b T/tau - c`` for alpha = 0, -1, -2 (white, flicker, random-walk
rate), and the OADEV EDF for alpha = 1, 2 (phase noise, where TOTDEV ~ OADEV); bounds
``s sqrt(edf / chi2_{1-p}(edf))``, ``s sqrt(edf / chi2_p(edf))`` (SP 1065 eq. 45). The noise
type alpha at each tau comes from the lag-1 autocorrelation of the tau-averaged rate
(:func:`~gyrolab.numerics.confidence.noise_id_lag1`), averages that touch a gap left out;
with gaps, ``N`` in the EDF is the number of samples present plus one (an approximation).
"""

from __future__ import annotations

import math
from typing import Literal

import numba
import numpy as np

from gyrolab.errors import InputError
from gyrolab.numerics.allan import DeviationResult, allan_deviation, checked_series
from gyrolab.numerics.confidence import ONE_SIGMA, confidence_bounds, edf_greenhall
from gyrolab.numerics.phase import phase_of, tau_grid

__all__ = ["KINDS", "deviation"]

Kind = Literal["oadev", "mdev", "tdev", "hdev", "totdev"]
KINDS: tuple[str, ...] = ("oadev", "mdev", "tdev", "hdev", "totdev")
# SP 1065 table 7: TOTDEV edf = b T/tau - c, for alpha = 0, -1, -2
_TOT_EDF = {0: (1.50, 0.0), -1: (1.17, 0.22), -2: (0.93, 0.36)}


# --------------------------------------------------------------------------------------------
# numba kernels: sums of squared terms over the terms whose span has no missing sample.
# ``cb[k]`` = number of missing units before phase point k; span [a, b] is whole iff
# cb[b] == cb[a]. Without gaps (``gaps`` False) cb is not read.
# --------------------------------------------------------------------------------------------


@numba.njit(cache=True)
def _sum_d3(x: np.ndarray, cb: np.ndarray, m: int, gaps: bool) -> tuple[float, int]:
    s = 0.0
    c = 0
    for i in range(x.size - 3 * m):
        if not gaps or cb[i + 3 * m] == cb[i]:
            d = x[i + 3 * m] - 3.0 * x[i + 2 * m] + 3.0 * x[i + m] - x[i]
            s += d * d
            c += 1
    return s, c


@numba.njit(cache=True)
def _sum_mod(x: np.ndarray, cb: np.ndarray, m: int, gaps: bool) -> tuple[float, int]:
    # inner_j = sum_{i=j}^{j+m-1} d2_i, updated by one term in, one out (gaps hold finite
    # filler values, so the running sum stays exact; only whole spans are accumulated)
    n_terms = x.size - 3 * m + 1
    if n_terms <= 0:
        return 0.0, 0
    inner = 0.0
    for i in range(m):
        inner += x[i + 2 * m] - 2.0 * x[i + m] + x[i]
    s = 0.0
    c = 0
    for j in range(n_terms):
        if not gaps or cb[j + 3 * m - 1] == cb[j]:
            s += inner * inner
            c += 1
        if j + 1 < n_terms:
            i_in = j + m
            inner += (x[i_in + 2 * m] - 2.0 * x[i_in + m] + x[i_in]) - (
                x[j + 2 * m] - 2.0 * x[j + m] + x[j]
            )
    return s, c


@numba.njit(cache=True)
def _reflect(x: np.ndarray, a: int, b: int, k: int) -> float:
    # x* of the segment x[a:b] (length L) at segment index k, odd reflection at both ends
    last = b - a - 1
    if k < 0:
        return 2.0 * x[a] - x[a - k]
    if k > last:
        return 2.0 * x[b - 1] - x[a + 2 * last - k]
    return x[a + k]


@numba.njit(cache=True)
def _sum_tot(x: np.ndarray, seg_a: np.ndarray, seg_b: np.ndarray, m: int) -> tuple[float, int]:
    s = 0.0
    c = 0
    for g in range(seg_a.size):
        a = seg_a[g]
        b = seg_b[g]
        length = b - a
        if length < 3 or m > length - 1:
            continue
        for i in range(1, length - 1):
            d = _reflect(x, a, b, i - m) - 2.0 * x[a + i] + _reflect(x, a, b, i + m)
            s += d * d
        c += length - 2
    return s, c


# --------------------------------------------------------------------------------------------
# results and the public function
# --------------------------------------------------------------------------------------------


def _segments(cb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    # maximal runs of phase points joined by whole units: [a, b)
    broken = np.flatnonzero(np.diff(cb) != 0)  # unit k missing: points k and k+1 apart
    starts = np.concatenate(([0], broken + 1))
    ends = np.concatenate((broken + 1, [cb.size]))
    keep = ends - starts >= 1
    return starts[keep].astype(np.int64), ends[keep].astype(np.int64)


def _max_m(kind: str, n_phase: int) -> int:
    if kind in ("mdev", "tdev"):
        return n_phase // 3
    if kind == "hdev":
        return (n_phase - 1) // 3
    return (n_phase - 1) // 2  # totdev: Stable32's stop ratio 2


def _edf(kind: str, alpha: int, m: int, n_phase: int) -> float:
    if kind in ("mdev", "tdev"):
        return edf_greenhall(alpha, m, n_phase, overlapping=True, d=2, modified=True)
    if kind == "hdev":
        return edf_greenhall(alpha, m, n_phase, overlapping=True, d=3)
    if kind == "totdev" and alpha in _TOT_EDF:
        b, c = _TOT_EDF[alpha]
        return b * (n_phase - 1) / m - c
    return edf_greenhall(alpha, m, n_phase, overlapping=True, d=2)


def deviation(
    data: np.ndarray,
    rate: float,
    kind: Kind = "mdev",
    taus: str | np.ndarray | list[float] = "octave",
    data_type: Literal["rate", "angle", "phase", "freq"] = "rate",
    confidence: float | None = ONE_SIGMA,
    alpha: int | None = None,
) -> DeviationResult | list[DeviationResult]:
    """One of OADEV, MDEV, TDEV, HDEV, TOTDEV of rate (or angle) data, gaps as NaN.

    Parameters
    ----------
    data : 1-D array, or 2-D ``(samples, axes)``: then one result per axis (column) is
        returned, in a list. NaN marks a missing sample (see the module docstring).
    rate : sample rate in Hz (tau0 = 1 / rate).
    kind : ``"oadev"``, ``"mdev"``, ``"tdev"``, ``"hdev"`` (overlapping Hadamard) or
        ``"totdev"``.
    taus : ``"octave"``, ``"decade"``, ``"all"`` or taus in s (rounded to whole samples);
        m is capped at N/3 (MDEV, TDEV), (N-1)/3 (HDEV), (N-1)/2 (OADEV, TOTDEV).
    data_type : ``"rate"`` (alias ``"freq"``) or ``"angle"`` (alias ``"phase"``).
    confidence : two-sided level of ``dev_lo``/``dev_hi`` (default one sigma); ``None``
        skips the EDF.
    alpha : force the power-law noise exponent instead of identifying it per tau.
    """
    if kind not in KINDS:
        raise InputError(None, f"unknown deviation {kind!r} (one of {', '.join(KINDS)})")
    arr = np.asarray(data, dtype=np.float64)
    if arr.ndim == 2:
        return [
            deviation(arr[:, j], rate, kind, taus, data_type, confidence, alpha)  # type: ignore[misc]
            for j in range(arr.shape[1])
        ]
    if arr.ndim != 1:
        raise InputError(None, f"deviation needs a 1-D or 2-D array, got shape {arr.shape}")
    if kind == "oadev":
        return allan_deviation(arr, rate, taus, data_type, confidence=confidence, alpha=alpha)
    arr, missing = checked_series(arr, rate, "a deviation")
    tau0 = 1.0 / float(rate)
    phase, cb = phase_of(arr, data_type, tau0, missing)  # rate-unit x s
    n_phase = phase.size
    ms = tau_grid(n_phase, float(rate), taus)
    ms = ms[ms <= _max_m(kind, n_phase)]
    if ms.size == 0:
        raise InputError(
            None, f"series too short for the requested taus ({arr.size} samples at {rate} Hz)"
        )
    gaps = missing > 0
    if kind == "totdev":
        seg_a, seg_b = (
            _segments(cb) if gaps else (np.array([0], np.int64), np.array([n_phase], np.int64))
        )
    var = np.full(ms.size, np.nan)
    nterms = np.zeros(ms.size, dtype=np.int64)
    for k, m in enumerate(ms):
        m = int(m)
        t = m * tau0
        if kind in ("mdev", "tdev"):
            s, c = _sum_mod(phase, cb, m, gaps)
            v = s / (2.0 * m * m * t * t * c) if c else math.nan
        elif kind == "hdev":
            s, c = _sum_d3(phase, cb, m, gaps)
            v = s / (6.0 * t * t * c) if c else math.nan
        else:
            s, c = _sum_tot(phase, seg_a, seg_b, m)
            v = s / (2.0 * t * t * c) if c else math.nan
        var[k] = v
        nterms[k] = c
    dev = np.sqrt(var)
    taus_s = ms * tau0
    if kind == "tdev":
        dev = taus_s / math.sqrt(3.0) * dev
    if not np.any(dev > 0):
        raise InputError(None, "constant series: the deviation is zero at every tau")

    edf, alphas, lo, hi = (np.full(ms.size, np.nan) for _ in range(4))
    if confidence is not None:
        n_eff = n_phase - missing
        edf, alphas, lo, hi = confidence_bounds(
            phase,
            ms,
            dev,
            lambda a, m: _edf(kind, a, m, n_eff),
            confidence,
            alpha,
            cb if gaps else None,
        )
    return DeviationResult(
        kind=kind,
        taus=taus_s,
        dev=dev,
        n=nterms,
        m=ms,
        dev_lo=lo,
        dev_hi=hi,
        edf=edf,
        alpha=alphas,
        rate=float(rate),
        confidence=ONE_SIGMA if confidence is None else float(confidence),
        missing=missing,
        data_type="rate" if data_type in ("rate", "freq") else "angle",
        extra={"record_s": (n_phase - 1) * tau0},
    )
