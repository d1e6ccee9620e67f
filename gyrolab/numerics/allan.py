"""Overlapping (and non-overlapping) Allan deviation of rate or angle data.

The Allan variance of rate data ``y`` (sample interval ``tau0 = 1/rate``) at
``tau = m * tau0`` is computed from the phase (angle) ``x_k = tau0 * sum_{i<k} y_i``
(:mod:`gyrolab.numerics.phase`)::

    avar(tau) = 1 / (2 tau^2 (N - 2m)) * sum_{i=0}^{N-2m-1} (x_{i+2m} - 2 x_{i+m} + x_i)^2

with ``N`` phase points (IEEE Std 952-1997 Annex C; NIST SP 1065 eq. 14). The non-overlapping
estimator takes every ``m``-th term only (SP 1065 eq. 12). Confidence intervals:
:mod:`gyrolab.numerics.confidence` (Greenhall & Riley EDF, lag-1 noise identification,
chi-squared bounds); ``confidence=None`` skips them (the fast path: the deviation alone).
IEEE 952 noise terms from the curve: :mod:`gyrolab.numerics.noise_terms`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numba
import numpy as np

from gyrolab.errors import InputError
from gyrolab.numerics.confidence import ONE_SIGMA, confidence_bounds, edf_greenhall
from gyrolab.numerics.phase import all_finite, phase_detrended, phase_from_rate, tau_grid

__all__ = ["AllanResult", "allan_deviation"]


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
    if not all_finite(data):
        raise InputError(None, "series contains NaN or infinite values")


def allan_deviation(
    data: np.ndarray,
    rate: float,
    taus: str | np.ndarray | list[float] = "octave",
    data_type: Literal["rate", "angle", "phase", "freq"] = "rate",
    overlapping: bool = True,
    confidence: float | None = ONE_SIGMA,
    alpha: int | None = None,
    allow_constant: bool = False,
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
    allow_constant : a constant series gives a zero curve instead of an InputError (a
        noiseless simulated channel is a valid input to the discrepancy workflow).

    Returns an :class:`AllanResult`. Raises :class:`~gyrolab.errors.InputError` on NaN/inf,
    a series too short for any tau, or (unless ``allow_constant``) a constant series.
    """
    arr = np.asarray(data)
    if arr.dtype != np.float64:
        arr = arr.astype(np.float64)
    arr = np.ascontiguousarray(arr)
    _check_input(arr, float(rate))
    tau0 = 1.0 / float(rate)
    if data_type in ("rate", "freq"):
        phase = np.empty(arr.size + 1, dtype=np.float64)
        phase_from_rate(arr, tau0, phase)
    elif data_type in ("angle", "phase"):
        phase = np.empty(arr.size, dtype=np.float64)
        phase_detrended(arr, phase)
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
    if not allow_constant and not np.any(adev > 0):
        raise InputError(None, "constant series: the Allan deviation is zero at every tau")

    edf, alphas, lo, hi = (np.full(ms.size, np.nan) for _ in range(4))
    if confidence is not None:
        edf, alphas, lo, hi = confidence_bounds(
            phase,
            ms,
            adev,
            lambda a, m: edf_greenhall(a, m, n_phase, overlapping=overlapping),
            confidence,
            alpha,
        )
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
