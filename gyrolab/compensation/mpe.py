"""Multiscale permutation entropy (MPE) and the noise / mixed / drift classification of modes.

Permutation entropy (Bandt & Pompe, PRL 88, 174102, 2002) of order ``m`` and delay ``d``:
each window ``(x_i, x_{i+d}, ..., x_{i+(m-1)d})`` is mapped to its ordinal pattern (the
permutation that sorts it; ties are broken by position, like a stable argsort), and

    H = -sum_pi p(pi) log2 p(pi) / log2(m!)        in [0, 1]

with ``p`` the relative frequency of each of the ``m!`` patterns over the
``L - (m-1) d`` windows. Patterns are counted by their Lehmer code in a numba kernel (no
embedding matrix, no sort), which gives the same counts as ``antropy.perm_entropy``.

Multiscale: the series is coarse-grained at scale ``s`` by non-overlapping means
(paper eq. 21, Wei et al. 2021)::

    Z_j^s = (1/s) sum_{i=(j-1)s+1}^{js} x_i,    1 <= j <= L/s

and H is computed on each ``Z^s`` for s = 1..12 (the paper's scale factor 12). The mean over
scales, per mode, ranks the modes from regular (drift) to disordered (noise) (paper §3.4,
Fig. 12).

Classification rule (configurable, :func:`classify_modes`): a mode is **noise** when its
mean MPE >= ``noise_min`` (default 0.85), **drift** when <= ``drift_max`` (default 0.5),
otherwise **mixed**. With order 4, white noise has mean MPE ~ 1.0 at every scale and the
slow, smooth drift modes of a temperature run are far below 0.5; narrow-band modes in
between are "mixed" (see docs/allan.md for the calibration of the defaults).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numba
import numpy as np

from gyrolab.errors import InputError

__all__ = [
    "DEFAULT_DRIFT_MAX",
    "DEFAULT_NOISE_MIN",
    "classify_modes",
    "coarse_grain",
    "mean_mpe",
    "multiscale_perm_entropy",
    "perm_entropy",
]

DEFAULT_NOISE_MIN = 0.85
DEFAULT_DRIFT_MAX = 0.5
MAX_ORDER = 10  # 10! = 3.6 M pattern counters; beyond that the histogram is meaningless


@numba.njit(cache=True)
def _pattern_counts(x: np.ndarray, order: int, delay: int, counts: np.ndarray) -> int:
    """Histogram of ordinal patterns (Lehmer code) of all delay-embedded windows."""
    n = x.size - (order - 1) * delay
    for i in range(n):
        code = 0
        for j in range(order):
            xj = x[i + j * delay]
            c = 0
            for k in range(j + 1, order):
                # strict "<": equal values keep their positional order (stable argsort)
                if x[i + k * delay] < xj:
                    c += 1
            code = code * (order - j) + c
        counts[code] += 1
    return n


def _as_series(x: np.ndarray | Sequence[float], what: str = "series") -> np.ndarray:
    a = np.ascontiguousarray(np.asarray(x, dtype=np.float64))
    if a.ndim != 1:
        raise InputError(None, f"{what} must be 1-D, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputError(None, f"{what} contains NaN or infinite values")
    return a


def _check_order_delay(order: int, delay: int) -> None:
    if not 2 <= order <= MAX_ORDER:
        raise InputError(None, f"permutation-entropy order must be 2..{MAX_ORDER}, got {order}")
    if delay < 1:
        raise InputError(None, f"permutation-entropy delay must be >= 1, got {delay}")


def perm_entropy(
    x: np.ndarray | Sequence[float], order: int = 4, delay: int = 1, normalize: bool = True
) -> float:
    """Permutation entropy of a 1-D series, in bits, or normalised by log2(order!) to [0, 1].

    Same definition and tie rule as ``antropy.perm_entropy``.
    """
    _check_order_delay(order, delay)
    a = _as_series(x)
    if a.size - (order - 1) * delay < 1:
        raise InputError(
            None, f"series of {a.size} samples too short for order {order}, delay {delay}"
        )
    counts = np.zeros(math.factorial(order), dtype=np.int64)
    n = _pattern_counts(a, order, delay, counts)
    p = counts[counts > 0] / n
    h = float(-(p * np.log2(p)).sum())
    if normalize:
        h = min(max(h / math.log2(math.factorial(order)), 0.0), 1.0)
    return h


def coarse_grain(x: np.ndarray | Sequence[float], scale: int) -> np.ndarray:
    """Paper eq. 21: means of consecutive non-overlapping blocks of ``scale`` samples
    (a trailing partial block is dropped)."""
    a = np.asarray(x, dtype=np.float64)
    if scale < 1:
        raise InputError(None, f"coarse-graining scale must be >= 1, got {scale}")
    n = a.size // scale
    return a[: n * scale].reshape(n, scale).mean(axis=1)


def _scale_list(scales: int | Iterable[int]) -> list[int]:
    if isinstance(scales, (int, np.integer)):
        return list(range(1, int(scales) + 1))
    return [int(s) for s in scales]


def multiscale_perm_entropy(
    x: np.ndarray | Sequence[float],
    scales: int | Iterable[int] = 12,
    order: int = 4,
    delay: int = 1,
) -> np.ndarray:
    """Normalised permutation entropy of ``x`` coarse-grained at each scale (eq. 21).

    ``scales``: an int S means 1..S (paper: 12), or an explicit list. Returns one value per
    scale. The coarsest series must still hold ``order`` windows' worth of samples.
    """
    _check_order_delay(order, delay)
    a = _as_series(x)
    sl = _scale_list(scales)
    need = (order - 1) * delay + 1
    if not sl or min(sl) < 1:
        raise InputError(None, f"scales must be >= 1, got {sl}")
    if a.size // max(sl) < need:
        raise InputError(
            None,
            f"series of {a.size} samples too short for scale {max(sl)} with order {order}",
        )
    nf = math.factorial(order)
    logn = math.log2(nf)
    out = np.empty(len(sl))
    counts = np.zeros(nf, dtype=np.int64)
    for k, s in enumerate(sl):
        z = np.ascontiguousarray(coarse_grain(a, s)) if s > 1 else a
        counts[:] = 0
        n = _pattern_counts(z, order, delay, counts)
        p = counts[counts > 0] / n
        out[k] = min(max(float(-(p * np.log2(p)).sum()) / logn, 0.0), 1.0)
    return out


def mean_mpe(
    modes: np.ndarray | Sequence[np.ndarray],
    scales: int | Iterable[int] = 12,
    order: int = 4,
    delay: int = 1,
) -> np.ndarray:
    """Mean over scales of the MPE of each mode; ``modes`` is (K, L) or a list of K series."""
    rows = [np.asarray(m) for m in modes] if not isinstance(modes, np.ndarray) else list(modes)
    if not rows:
        raise InputError(None, "no modes given")
    return np.array([multiscale_perm_entropy(r, scales, order, delay).mean() for r in rows])


def classify_modes(
    mean_values: np.ndarray | Sequence[float],
    noise_min: float = DEFAULT_NOISE_MIN,
    drift_max: float = DEFAULT_DRIFT_MAX,
) -> dict[str, list[int]]:
    """Split modes into ``noise`` / ``mixed`` / ``drift`` by their mean MPE.

    noise: mean MPE >= ``noise_min``; drift: mean MPE <= ``drift_max``; mixed: in between.
    Returns mode indices (ascending) per class, the ``imf_classes`` of metrics.json.
    """
    v = np.asarray(mean_values, dtype=float)
    if not drift_max < noise_min:
        raise InputError(None, f"need drift_max < noise_min, got {drift_max} >= {noise_min}")
    if not np.all(np.isfinite(v)):
        raise InputError(None, "mean MPE values contain NaN")
    idx = np.arange(v.size)
    return {
        "noise": [int(i) for i in idx[v >= noise_min]],
        "mixed": [int(i) for i in idx[(v > drift_max) & (v < noise_min)]],
        "drift": [int(i) for i in idx[v <= drift_max]],
    }
