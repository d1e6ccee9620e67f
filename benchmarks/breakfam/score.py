"""The break family's scorer, written without gyrolab's metrics or averaging code.

All on the 10 Hz output ``y`` (°/s) of one method on one run:

* 3.6 s means: consecutive, non-overlapping 36-sample means (a trailing part dropped);
* **bias stability** (°/h): 3600 × their sample standard deviation;
* **100 s p-p** (°/s): peak-to-peak of the means of 28 consecutive 3.6 s means (100.8 s);
* **residual mean bias** (°/h): 3600 × the mean of ``y`` over the run — what a constant
  turn-on offset, aging or a wrong level of the drift model leaves;
* **band coverage**: the share of 100 s means inside a method's stated band.
"""

from __future__ import annotations

import numpy as np

BLOCK = 36  # samples of 3.6 s at 10 Hz
WINDOW = 28  # 3.6 s blocks in a 100 s window


def means(y: np.ndarray, n: int) -> np.ndarray:
    """Means of consecutive, non-overlapping ``n``-sample blocks (trailing part dropped)."""
    k = y.size // n
    return y[: k * n].reshape(k, n).mean(axis=1)


def score(y: np.ndarray) -> dict[str, float]:
    """Bias stability, 100 s p-p and residual mean bias of a 10 Hz output (docstring)."""
    b = means(np.asarray(y, dtype=float), BLOCK)
    w = means(b, WINDOW)
    return {
        "bias_stability_deg_per_h": float(np.std(b, ddof=1) * 3600.0),
        "pp_100s_deg_per_s": float(np.max(w) - np.min(w)),
        "mean_bias_deg_per_h": float(np.mean(b) * 3600.0),
    }


def window_means(y: np.ndarray) -> np.ndarray:
    """The 100 s means of a 10 Hz output (°/s)."""
    return means(means(np.asarray(y, dtype=float), BLOCK), WINDOW)


def coverage(y: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
    """Share of the 100 s means of ``y`` inside ``[lo, hi]`` (per window, °/s)."""
    w = window_means(y)
    k = min(w.size, lo.size, hi.size)
    return float(np.mean((w[:k] >= lo[:k]) & (w[:k] <= hi[:k])))
