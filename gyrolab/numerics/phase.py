"""The phase (angle) of rate data, the common input of every Allan-type deviation, and
the tau grids.

The phase of rate data ``y`` (sample interval ``tau0``) is ``x_k = tau0 * sum_{i<k} y_i``,
``N = n + 1`` points (NIST SP 1065 §5.2). It is built once, in place, by a compensated
(Neumaier) cumulative sum of ``y - mean(y)``: second and third differences are blind to a
constant rate, and removing it keeps the phase small, so that 40 M samples keep float64
accuracy. Angle (phase) input has the line through its end points removed instead (the
differences are unchanged). One phase array (8 bytes per sample) is the only large
allocation of a deviation without gaps.

**Gaps.** A missing sample is NaN (:func:`gap_filled` places a recording's samples by their
index). :func:`phase_of` never interpolates: a missing rate sample adds nothing to the phase
(the mean of the samples present is removed first), and ``cb[k]``, the number of missing
units before phase point ``k``, lets a deviation use a term only when its span
``[p_0, p_K]`` is whole (``cb[p_K] == cb[p_0]``).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from gyrolab.errors import InputError

__all__ = [
    "count_missing",
    "gap_filled",
    "phase_detrended",
    "phase_from_rate",
    "phase_of",
    "tau_grid",
]


@numba.njit(cache=True)
def count_missing(y: np.ndarray) -> int:
    """The number of NaN (missing) samples, or -1 if any sample is infinite (an error, not
    a gap); without an n-byte temporary."""
    n = 0
    for i in range(y.size):
        if math.isinf(y[i]):
            return -1
        if math.isnan(y[i]):
            n += 1
    return n


def gap_filled(index: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Samples placed at their sample index, NaN where the index jumps (a recording gap).

    ``index`` is the sample index of each value (``Series.index``, increasing).
    """
    index = np.asarray(index, dtype=np.int64)
    if index.size == 0:
        return np.empty(0)
    out = np.full(int(index[-1] - index[0]) + 1, np.nan)
    out[index - index[0]] = values
    return out


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


def phase_of(
    data: np.ndarray, data_type: str, tau0: float, missing: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """The phase of rate (``"rate"``/``"freq"``) or angle (``"angle"``/``"phase"``) data
    in rate-unit x s, and ``cb``, the cumulative count of missing units before each phase
    point (a one-element zero array when ``missing`` is 0: no count array, 8 B/sample).

    ``data`` is float64 and contiguous; ``missing`` its NaN count (:func:`count_missing`).
    """
    bad = np.isnan(data) if missing else None
    filled = data
    if bad is not None:
        filled = np.where(bad, 0.0, data)
    if data_type in ("rate", "freq"):
        if bad is not None and missing < data.size:
            filled = filled - filled.sum() / (data.size - missing)
            filled[bad] = 0.0
        phase = np.empty(data.size + 1)
        phase_from_rate(filled, tau0, phase)
        bad_units = bad
    elif data_type in ("angle", "phase"):
        phase = np.empty(data.size)
        phase_detrended(filled, phase)
        bad_units = None if bad is None else bad[:-1] | bad[1:]
    else:
        raise InputError(None, f"unknown data_type {data_type!r} (rate or angle)")
    if bad_units is None:
        return phase, np.zeros(1, dtype=np.int64)
    cb = np.zeros(phase.size, dtype=np.int64)
    np.cumsum(bad_units, out=cb[1:])
    return phase, cb
