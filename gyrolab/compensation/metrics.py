"""The metric set (docs/cli.md keys) of one gyro output signal (deg/s), as written to metrics.json.

=============================  ==========================================================
key                            definition
=============================  ==========================================================
``arw_deg_per_sqrt_h``         angle random walk: the -1/2 line of the overlapping Allan
                               deviation read at tau = 1 s (IEEE 952 C.2, the pair of
                               octave taus whose local slope is closest to -1/2), x 60
``bias_instability_deg_per_h`` IEEE 952 Allan floor: min sigma(tau) / 0.664 over
                               tau <= T/10, x 3600
``bias_stability_deg_per_h``   the paper's "bias stability" (Chinese gyro standards,
                               e.g. GJB 2426A): sample standard deviation (n - 1) of the
                               output averaged over non-overlapping windows of
                               ``stability_window_s`` (default 3.6 s = 1000 points/h, the
                               paper's recording rate), x 3600
``drift_pp_deg_per_s``         peak-to-peak of the output averaged over non-overlapping
                               windows of ``drift_window_s`` (default 3.6 s = 1000 points/h,
                               how the paper states its 0.0287 deg/s output variation)
``rms_deg_per_s``              root mean square of the output at the full rate (about zero:
                               the residual of a static test, bias included)
=============================  ==========================================================

Windows are rounded to whole samples (at least one); a trailing partial window is dropped
(:func:`gyrolab.numerics.averaging.block_means`).
A 0.0287 deg/s staircase drift gives ~32 deg/h bias stability but well under 1 deg/h bias
instability: the two names are different quantities (docs/allan.md).
"""

from __future__ import annotations

import numpy as np

from gyrolab.errors import InputError
from gyrolab.numerics.allan import DeviationResult, allan_deviation
from gyrolab.numerics.averaging import PAPER_BLOCK_S, block_means
from gyrolab.numerics.noise_terms import noise_terms

__all__ = ["METRIC_KEYS", "signal_metrics"]

METRIC_KEYS = (
    "arw_deg_per_sqrt_h",
    "bias_instability_deg_per_h",
    "bias_stability_deg_per_h",
    "drift_pp_deg_per_s",
    "rms_deg_per_s",
)


def _num(v: float | None) -> float:
    return float("nan") if v is None else float(v)


def signal_metrics(
    rate_dps: np.ndarray,
    rate_hz: float,
    stability_window_s: float = PAPER_BLOCK_S,
    drift_window_s: float = PAPER_BLOCK_S,
    allan: DeviationResult | None = None,
) -> dict[str, float]:
    """The five metrics (docs/cli.md) of a gyro output in deg/s sampled at ``rate_hz``.

    ``allan``: a precomputed overlapping octave :func:`allan_deviation` of the same signal
    (saves recomputing it); otherwise it is computed here without confidence intervals.
    Raises :class:`~gyrolab.errors.InputError` on NaN/inf, constant or too-short input.
    """
    x = np.asarray(rate_dps, dtype=np.float64)
    if x.ndim != 1:
        raise InputError(None, f"metrics need a 1-D rate series, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise InputError(None, "rate series contains NaN or infinite values")
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise InputError(None, f"sample rate must be positive, got {rate_hz!r}")
    if allan is None:
        allan = allan_deviation(x, rate_hz, taus="octave", confidence=None)
    terms = noise_terms(allan, method="slope", slope_tol=None, terms=("N", "B")).deg_h()
    stab = block_means(x, rate_hz, stability_window_s)
    drift = stab if drift_window_s == stability_window_s else None
    if drift is None:
        drift = block_means(x, rate_hz, drift_window_s)
    return {
        "arw_deg_per_sqrt_h": _num(terms["arw_deg_per_sqrt_h"]),
        "bias_instability_deg_per_h": _num(terms["bias_instability_deg_per_h"]),
        "bias_stability_deg_per_h": float(np.std(stab, ddof=1) * 3600.0),
        "drift_pp_deg_per_s": float(np.ptp(drift)),
        "rms_deg_per_s": float(np.sqrt(np.mean(x * x))),
    }
