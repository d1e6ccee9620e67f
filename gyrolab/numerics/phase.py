"""The phase (angle) of rate data, the common input of every Allan-type deviation, and
the tau grids.

The phase of rate data ``y`` (sample interval ``tau0``) is ``x_k = tau0 * sum_{i<k} y_i``,
``N = n + 1`` points (NIST SP 1065 §5.2). It is built once, in place, by a compensated
(Neumaier) cumulative sum of ``y - mean(y)``: second and third differences are blind to a
constant rate, and removing it keeps the phase small, so that 40 M samples keep float64
accuracy. Angle (phase) input has the line through its end points removed instead (the
differences are unchanged). One phase array (8 bytes per sample) is the only large
allocation of a deviation.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from gyrolab.errors import InputError

__all__ = ["all_finite", "phase_detrended", "phase_from_rate", "tau_grid"]


@numba.njit(cache=True)
def all_finite(y: np.ndarray) -> bool:
    # np.all(np.isfinite(y)) without its n-byte temporary
    for i in range(y.size):
        if not math.isfinite(y[i]):
            return False
    return True


@numba.njit(cache=True, inline="always")
def _neumaier_add(s: float, c: float, v: float) -> tuple[float, float]:
    """One term of a Neumaier-compensated sum: the new (sum, compensation) after adding v."""
    t = s + v
    if abs(s) >= abs(v):
        c += (s - t) + v
    else:
        c += (v - t) + s
    return t, c


@numba.njit(cache=True)
def _neumaier_mean(y: np.ndarray) -> float:
    s = 0.0
    c = 0.0
    for i in range(y.size):
        s, c = _neumaier_add(s, c, y[i])
    return (s + c) / y.size


@numba.njit(cache=True)
def phase_from_rate(y: np.ndarray, tau0: float, out: np.ndarray) -> None:
    """out[0] = 0, out[k] = tau0 * sum_{i<k} (y_i - mean), Neumaier-compensated."""
    mean = _neumaier_mean(y)
    s = 0.0
    c = 0.0
    out[0] = 0.0
    for i in range(y.size):
        s, c = _neumaier_add(s, c, (y[i] - mean) * tau0)
        out[i + 1] = s + c


@numba.njit(cache=True)
def phase_detrended(x: np.ndarray, out: np.ndarray) -> None:
    """out = x minus the line through its end points (second differences are unchanged)."""
    n = x.size
    x0 = x[0]
    slope = (x[n - 1] - x0) / (n - 1) if n > 1 else 0.0
    for i in range(n):
        out[i] = (x[i] - x0) - slope * i


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
