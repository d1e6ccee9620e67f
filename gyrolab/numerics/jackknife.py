"""The delete-a-group jackknife's covariance of an estimate: one formula for every caller
(the structured model's hysteresis test, the fleet prior's own-estimate covariance), so a
threshold on it (|t| ≥ 2) never flips between two summation orders of the same sum."""

from __future__ import annotations

import numpy as np


def jackknife_covariance(estimates: np.ndarray) -> np.ndarray:
    """The jackknife covariance of an estimate from its ``m`` delete-one-group estimates
    (``estimates``: ``(m, p)``, row ``k`` the estimate with group ``k`` left out):

        C = (m − 1)/m Σ_k (θ̂₋ₖ − θ̄)(θ̂₋ₖ − θ̄)ᵀ,   θ̄ = (1/m) Σ_k θ̂₋ₖ

    in the units of the estimate squared, ``(p, p)``; its diagonal is the squared
    jackknife standard errors (zero for ``m`` = 1). With the groups contiguous blocks of
    a series, the delete-a-block jackknife, it carries the series' correlation within a
    block (Efron & Stein, *Ann. Statist.* 9 (1981) 586; Künsch, *Ann. Statist.* 17
    (1989) 1217)."""
    th = np.asarray(estimates, dtype=float)
    if th.ndim != 2 or th.shape[0] < 1:
        raise ValueError("jackknife_covariance: (m, p) estimates, m >= 1")
    m = th.shape[0]
    d = th - th.mean(axis=0)
    return (m - 1) / m * (d.T @ d)
