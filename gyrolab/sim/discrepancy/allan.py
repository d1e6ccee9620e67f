"""Small Allan-deviation helpers for the discrepancy workflow (kept here: ``sim`` must not
import ``compensation``).

Overlapping Allan variance of a rate series ``x_k`` (sample interval ``dt``) at
``τ = m·dt`` from the cumulative angle ``θ_k = dt · Σ_{j<k} x_j`` (IEEE 952-1997 eq. C.27)::

    σ²(τ) = Σ_{k=0}^{N−2m} (θ_{k+2m} − 2 θ_{k+m} + θ_k)² / (2 τ² (N − 2m + 1))

One pass of ``cumsum`` then O(N) per τ, on an octave grid of ``m``.

The model curves used to compare a recording with the simulator's noise terms
(IEEE 952 Annex C)::

    σ²(τ) = N²/τ  (white rate, N in °/s/√Hz)
          + B²    (flicker rate with Allan floor B, the simulator's convention)
          + K² τ / 3  (rate random walk, K in °/s/√s)
"""

from __future__ import annotations

import numpy as np


def octave_m(n: int, max_fraction: float = 0.125) -> np.ndarray:
    """Cluster sizes ``m = 1, 2, 4, …`` with ``m ≤ max_fraction · n`` (≥ 8 clusters)."""
    top = max(1, int(n * max_fraction))
    return 2 ** np.arange(int(np.floor(np.log2(top))) + 1)


def oadev(x: np.ndarray, dt: float, m: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Overlapping Allan deviation of rate samples ``x`` (any unit) at ``τ = m·dt`` (s).

    Returns ``(tau_s, adev)``; ``m`` defaults to the octave grid of :func:`octave_m`.
    """
    x = np.asarray(x, dtype=float)
    n = x.size
    if m is None:
        m = octave_m(n)
    m = np.asarray(m, dtype=np.int64)
    m = m[(m >= 1) & (2 * m < n)]
    # The mean does not change σ² but subtracting it keeps the cumulative sum small.
    theta = np.concatenate([[0.0], np.cumsum(x - x.mean())]) * dt
    out = np.empty(m.size)
    for i, mm in enumerate(m):
        d = theta[2 * mm :] - 2.0 * theta[mm:-mm] + theta[: -2 * mm]
        tau = mm * dt
        out[i] = np.sqrt(np.mean(d * d) / (2.0 * tau * tau))
    return m * dt, out


def edf_estimate(n: int, m: np.ndarray) -> np.ndarray:
    """A conservative equivalent number of degrees of freedom of each overlapping-ADEV
    point: about ``n/m`` independent clusters, halved for the overlap's correlation."""
    return np.maximum(1.0, 0.5 * (n / np.asarray(m, dtype=float) - 1.0))


def model_avar(tau: np.ndarray, n_white: float, b_floor: float, k_rrw: float) -> np.ndarray:
    """Allan variance of white + flicker + random-walk rate noise (see module docstring)."""
    tau = np.asarray(tau, dtype=float)
    return n_white**2 / tau + b_floor**2 + k_rrw**2 * tau / 3.0
