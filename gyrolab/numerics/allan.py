"""The Allan deviation (overlapping and non-overlapping) of rate or angle data, and
:class:`DeviationResult`, the one result type of it and of its family
(:mod:`gyrolab.numerics.deviations`: MDEV, TDEV, HDEV, TOTDEV).

The Allan variance of rate data ``y`` (sample interval ``tau0 = 1/rate``) at
``tau = m * tau0`` is computed from the phase (angle) ``x_k = tau0 * sum_{i<k} y_i``
(:mod:`gyrolab.numerics.phase`)::

    avar(tau) = 1 / (2 tau^2 (N - 2m)) * sum_{i=0}^{N-2m-1} (x_{i+2m} - 2 x_{i+m} + x_i)^2

with ``N`` phase points (IEEE Std 952-1997 Annex C; NIST SP 1065 eq. 14). The non-overlapping
estimator takes every ``m``-th term only (SP 1065 eq. 12). Missing samples are NaN: a term
is used only when every sample it integrates is present (Stable32's and allantools' gap
rule, :mod:`gyrolab.numerics.phase`), and the variance is the mean over the terms kept.
Confidence intervals: :mod:`gyrolab.numerics.confidence` (Greenhall & Riley EDF, lag-1 noise
identification, chi-squared bounds); ``confidence=None`` skips them (the fast path: the
deviation alone). IEEE 952 noise terms from the curve: :mod:`gyrolab.numerics.noise_terms`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numba
import numpy as np

from gyrolab.errors import InputError
from gyrolab.numerics.confidence import ONE_SIGMA, confidence_bounds, edf_greenhall
from gyrolab.numerics.phase import count_missing, phase_of, tau_grid

__all__ = ["DeviationResult", "allan_deviation", "checked_series"]


@numba.njit(cache=True)
def _sum_run(x: np.ndarray, i0: int, count: int, m: int, stride: int) -> float:
    """sum over ``count`` terms i = i0, i0 + stride, ... of (x[i+2m] - 2 x[i+m] + x[i])^2."""
    # four independent accumulators: breaks the add dependency chain (speed) and acts as a
    # short pairwise sum (accuracy) without fastmath reordering; offset slices and a counted
    # loop let LLVM drop the index arithmetic
    a = x[i0:]
    b = x[i0 + m :]
    c = x[i0 + 2 * m :]
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    s3 = 0.0
    q = count // 4
    for k in range(q):
        j0 = 4 * k * stride
        j1 = j0 + stride
        j2 = j1 + stride
        j3 = j2 + stride
        d0 = c[j0] - 2.0 * b[j0] + a[j0]
        d1 = c[j1] - 2.0 * b[j1] + a[j1]
        d2 = c[j2] - 2.0 * b[j2] + a[j2]
        d3 = c[j3] - 2.0 * b[j3] + a[j3]
        s0 += d0 * d0
        s1 += d1 * d1
        s2 += d2 * d2
        s3 += d3 * d3
    for k in range(4 * q, count):
        j = k * stride
        d = c[j] - 2.0 * b[j] + a[j]
        s0 += d * d
    return (s0 + s1) + (s2 + s3)


@numba.njit(cache=True)
def _sum_sq_second_diff(
    x: np.ndarray, gap_at: np.ndarray, m: int, stride: int
) -> tuple[float, int]:
    """The squared second differences at i = 0, stride, 2 stride, ... < N - 2m whose span
    [i, i + 2m] is whole: their sum and number. ``gap_at``: the missing units, increasing
    (unit g lies between phase points g and g + 1, so it breaks the terms
    i = g - 2m + 1 ... g). The whole runs between them are summed alike: a record without
    gaps is one run."""
    n = x.size - 2 * m
    if n <= 0:
        return 0.0, 0
    count = (n - 1) // stride + 1
    s = 0.0
    c = 0
    k = 0  # next term: i = k * stride
    j = 0  # next missing unit that may break a term at or after i
    while k < count:
        while j < gap_at.size and gap_at[j] < k * stride:
            j += 1
        if j == gap_at.size:
            end = count
        else:  # the terms before the first one unit gap_at[j] breaks
            end = min(count, (gap_at[j] - 2 * m) // stride + 1)
        if end > k:
            s += _sum_run(x, k * stride, end - k, m, stride)
            c += end - k
        if j == gap_at.size:
            break
        k = max(k, gap_at[j] // stride + 1)  # the first term after the broken ones
        j += 1
    return s, c


@dataclass(frozen=True)
class DeviationResult:
    """One deviation curve: ``taus`` in s; ``dev`` in the data's rate unit (TDEV: rate x s)."""

    kind: str  #: oadev | adev (non-overlapping) | mdev | tdev | hdev | totdev
    taus: np.ndarray  #: averaging times (s)
    dev: np.ndarray  #: the deviation at each tau
    n: np.ndarray  #: number of terms averaged (terms touching a gap are not counted)
    m: np.ndarray  #: averaging factor, tau = m / rate
    dev_lo: np.ndarray  #: lower confidence bound
    dev_hi: np.ndarray  #: upper confidence bound
    edf: np.ndarray  #: equivalent degrees of freedom
    alpha: np.ndarray  #: power-law noise exponent used for the EDF (rate PSD ~ f^alpha)
    rate: float  #: sample rate (Hz)
    confidence: float = ONE_SIGMA
    missing: int = 0  #: samples missing (NaN) in the input
    data_type: str = "rate"  #: what the input was: rate or angle
    extra: dict = field(default_factory=dict)

    @property
    def overlapping(self) -> bool:
        return self.kind != "adev"

    @property
    def duration_s(self) -> float:
        """Length of the record (s) the curve was computed on."""
        return float(self.extra.get("record_s", float("nan")))

    def to_dict(self) -> dict:
        """JSON-ready copy (lists of floats; NaN stays NaN)."""
        d: dict = {
            k: [float(v) for v in getattr(self, k)]
            for k in ("taus", "dev", "dev_lo", "dev_hi", "edf", "alpha")
        }
        d.update(
            kind=self.kind,
            n=[int(v) for v in self.n],
            m=[int(v) for v in self.m],
            rate=self.rate,
            confidence=self.confidence,
            missing=self.missing,
            data_type=self.data_type,
            duration_s=self.duration_s,
        )
        return d


def checked_series(data: np.ndarray, rate: float, what: str) -> tuple[np.ndarray, int]:
    """``data`` as a contiguous float64 1-D series checked for a deviation (positive finite
    rate, no infinite sample, at least 3 samples present), and its number of NaN (missing)
    samples. Raises :class:`~gyrolab.errors.InputError`."""
    arr = np.asarray(data)
    if arr.dtype != np.float64:
        arr = arr.astype(np.float64)
    arr = np.ascontiguousarray(arr)
    if not (np.isfinite(rate) and rate > 0):
        raise InputError(None, f"sample rate must be positive and finite, got {rate!r}")
    if arr.ndim != 1:
        raise InputError(None, f"{what} needs a 1-D series, got shape {arr.shape}")
    missing = count_missing(arr)
    if missing < 0:
        raise InputError(None, "series contains infinite values (NaN marks a gap; inf is an error)")
    if arr.size - missing < 3:
        raise InputError(None, f"series too short for {what} ({arr.size} samples)")
    return arr, missing


def allan_deviation(
    data: np.ndarray,
    rate: float,
    taus: str | np.ndarray | list[float] = "octave",
    data_type: Literal["rate", "angle", "phase", "freq"] = "rate",
    overlapping: bool = True,
    confidence: float | None = ONE_SIGMA,
    alpha: int | None = None,
    allow_constant: bool = False,
) -> DeviationResult:
    """Allan deviation of rate data (e.g. deg/s) or angle data (e.g. deg); NaN = missing.

    Parameters
    ----------
    data : 1-D array. ``data_type="rate"`` (alias ``"freq"``): rate samples; ``"angle"``
        (alias ``"phase"``): integrated angle samples, in rate-unit * s. NaN marks a missing
        sample (see the module docstring); infinity is an error.
    rate : sample rate in Hz (tau0 = 1 / rate).
    taus : ``"octave"``, ``"decade"``, ``"all"`` or taus in seconds (see
        :func:`~gyrolab.numerics.phase.tau_grid`).
    overlapping : overlapping estimator (all N - 2m differences, ``kind="oadev"``) or
        non-overlapping (stride m, ``kind="adev"``).
    confidence : two-sided confidence level of ``dev_lo``/``dev_hi``; ``None`` skips noise
        identification and EDF (bounds and edf are NaN).
    alpha : force the power-law noise exponent for the EDF instead of identifying it per tau.
    allow_constant : a constant series gives a zero curve instead of an InputError (a
        noiseless simulated channel is a valid input to the discrepancy workflow).

    Returns a :class:`DeviationResult`. Raises :class:`~gyrolab.errors.InputError` on inf,
    a series too short for any tau, or (unless ``allow_constant``) a constant series.
    """
    arr, missing = checked_series(data, rate, "an Allan deviation")
    tau0 = 1.0 / float(rate)
    phase, cb = phase_of(arr, data_type, tau0, missing)
    n_phase = phase.size
    ms = tau_grid(n_phase, float(rate), taus)
    if ms.size == 0:
        raise InputError(
            None, f"series too short for the requested taus ({arr.size} samples at {rate} Hz)"
        )
    gaps = missing > 0
    gap_at = np.flatnonzero(np.diff(cb)) if gaps else np.zeros(0, dtype=np.int64)
    adev = np.empty(ms.size)
    nterms = np.empty(ms.size, dtype=np.int64)
    for k, m in enumerate(ms):
        s, c = _sum_sq_second_diff(phase, gap_at, int(m), int(m) if not overlapping else 1)
        t = m * tau0
        adev[k] = math.sqrt(s / (2.0 * t * t * c)) if c else math.nan
        nterms[k] = c
    if not allow_constant and not np.any(adev > 0):
        raise InputError(None, "constant series: the Allan deviation is zero at every tau")

    edf, alphas, lo, hi = (np.full(ms.size, np.nan) for _ in range(4))
    if confidence is not None:
        n_eff = n_phase - missing
        edf, alphas, lo, hi = confidence_bounds(
            phase,
            ms,
            adev,
            lambda a, m: edf_greenhall(a, m, n_eff, overlapping=overlapping),
            confidence,
            alpha,
            cb if gaps else None,
        )
    return DeviationResult(
        kind="oadev" if overlapping else "adev",
        taus=ms * tau0,
        dev=adev,
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
