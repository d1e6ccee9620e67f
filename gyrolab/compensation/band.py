"""A causal drift model's prediction band and the graded expected error outside its
calibrated range (issue 23), both measured inside the calibration run.

**What the band states.** The compensated output ``y = raw − d`` of a held-out run,
averaged over 100 s windows, lies within ``±h`` with probability ``level`` (0.9): ``h``
bounds the model's residual drift *and* the noise left in a 100 s mean, the two things a
user sees on a static test. It is centred on zero (the model's own level).

**How it is measured.** The blocked cross-validation that chose the model
(:mod:`gyrolab.compensation.causal`) leaves, for every 3.6 s block, a prediction made
without that block's stretch of the run. The held-out residuals ``r = y − ŷ`` are
averaged over 100 s windows inside each held-out stretch. Every window also gets its
distance outside the range its *training* folds covered: ``δ_T`` (°C beyond the training
folds' PT100 range) and ``δ_R`` (°C/min beyond their dT/dt range, the backward
difference over ``rate_window_s`` of :func:`~gyrolab.compensation.guards.temperature_rate`).
Held-out folds at the ends of a staircase, or the only heating stretch of a cooling run,
are extrapolations of the model fitted without them, so the CV measures what
extrapolation costs this model on this unit:

    h_cv = quantile_level |r_w|          over windows with δ_T = δ_R = 0
    h₀ = κ √(h_cv² + (z σ_off)²)         z = √2 erf⁻¹(level) (1.645 at 90 %)
    h(δ_T, δ_R) = h₀ + k (a_T δ_T + a_R δ_R)

``σ_off`` is the Allan deviation of the CV residual at T/8 (8 averages): a new run starts
from another point of the noise's slow wander (flicker, rate random walk), an offset the
CV windows — all measured against one run — do not contain (on the break family, the
oracle's own 100 s means, pure noise, fell outside ``±h_cv`` on up to a third of a run).
``κ`` (:data:`TRANSFER`, 1.7) is the trajectory transfer: a model's error on a trajectory
it was not calibrated on exceeds what the CV inside its one calibration trajectory shows
(on the break family's development units, by 1.70× at the 90 % level).

``(a_T, a_R) ≥ 0`` by non-negative least squares of ``|r_w| − h₀`` on ``(δ_T, δ_R)`` over
the windows outside, and ``k`` the ``level`` quantile of the factor each of those windows
needs to be covered (0 for those already inside ``h₀``): the law is scaled so that it
covers ``level`` of the measured extrapolations. A direction in which fewer than three CV
windows went beyond the margins (0.5 °C, 0.1 °C/min) is not measured — a cooling
staircase never heats faster than its one power-on heat — and its slope is then the
prior :data:`DEFAULT_PER_C` · h₀ or :data:`DEFAULT_PER_C_PER_MIN` · h₀ (the band doubles
5 °C or 1 °C/min beyond the range; ``law_measured_c``, ``law_measured_c_per_min`` false);
a measured slope is never flatter than that prior — a CV whose excursions were a few °C
cannot show what 25 °C beyond costs. Nowhere is ``h`` wider than the calibration run's
raw 100 s peak-to-peak (``max_half_width``): a linear law measured on small excursions is
not carried past what no compensation at all leaves.

**Graded expected error.** On a run, ``ρ(t) = h(t)/h₀ ≥ 1`` is the factor by which the
expected error at t exceeds the in-range one. The grade is that of its 90th percentile
over the run: ``none`` (≤ 1.1: within 10 % of the calibrated accuracy), ``mild`` (≤ 2)
or ``severe`` (> 2) — in place of a bare fraction of points outside.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy.optimize import nnls
from scipy.special import erfinv

from gyrolab.compensation.causal_features import hold, power_on_edges
from gyrolab.compensation.guards import temperature_rate

LEVEL = 0.9
WINDOW_BLOCKS = 28  # 3.6 s blocks in a 100 s window (100.8 s), as the 100 s p-p metric
RATE_WINDOW_S = 300.0
#: the prior law (per unit of h₀): the slope where the calibration's CV never
#: extrapolated in a direction, and the floor of a measured one. A stated prior, not a
#: measurement: the band doubles 5 °C or 1 °C/min beyond the calibrated range
DEFAULT_PER_C = 0.2
DEFAULT_PER_C_PER_MIN = 1.0
GRADES = ((1.1, "none"), (2.0, "mild"), (float("inf"), "severe"))
#: trajectory transfer: the factor by which a model's error on another trajectory exceeds
#: what the CV inside its calibration run shows, at the band's level. Measured on the
#: development units 12–19 of the break family (never scored; docs/results.md): with the
#: factor 1 the 90 % quantile of |100 s mean| / half-width over their 40 held-out runs
#: (13 765 windows) was 1.70; rounded up.
TRANSFER = 1.7
MARGIN_C = 0.5  # as the range guard (gyrolab.compensation.guards.TEMP_MARGIN_C)
MARGIN_C_PER_MIN = 0.1


@dataclass(frozen=True)
class PredictionBand:
    """``h(δ_T, δ_R) = half_width + per_c δ_T + per_c_per_min δ_R`` (°/s, 100 s means)."""

    level: float
    half_width: float  # °/s inside the calibrated range
    per_c: float  # °/s per °C beyond the calibrated temperature range
    per_c_per_min: float  # °/s per °C/min beyond the calibrated dT/dt range
    temp_min_c: float
    temp_max_c: float
    rate_min_c_per_min: float
    rate_max_c_per_min: float
    rate_window_s: float = RATE_WINDOW_S
    law_measured: bool = True  # both slopes measured (else a default stands for one)
    law_measured_c: bool = True
    law_measured_c_per_min: bool = True
    n_windows_inside: int = 0
    n_windows_outside: int = 0
    max_half_width: float = float("inf")  # °/s: the raw output's own 100 s p-p (calibration)

    def distances(
        self, t: np.ndarray, pt_t: np.ndarray, pt_c: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(δ_T, δ_R)`` at times ``t``: °C and °C/min beyond the calibrated ranges (causal:
        the last PT100 reading and the backward-difference rate)."""
        T = hold(np.asarray(t, dtype=float), pt_t, pt_c)
        R = temperature_rate(np.asarray(t, dtype=float), pt_t, pt_c, self.rate_window_s)
        dT = np.maximum(0.0, np.maximum(T - self.temp_max_c, self.temp_min_c - T))
        dR = np.maximum(0.0, np.maximum(R - self.rate_max_c_per_min, self.rate_min_c_per_min - R))
        return dT, dR

    def half_width_at(self, t: np.ndarray, pt_t: np.ndarray, pt_c: np.ndarray) -> np.ndarray:
        """Band half-width (°/s) at times ``t`` for the 100 s mean around t."""
        dT, dR = self.distances(t, pt_t, pt_c)
        h = self.half_width + self.per_c * dT + self.per_c_per_min * dR
        # a linear law measured on small excursions is not carried past what no
        # compensation at all leaves: the calibration's raw 100 s peak-to-peak
        return np.minimum(h, max(self.max_half_width, self.half_width))

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PredictionBand:
        # JSON has no inf: an uncapped band was written as null (gyrolab.outputs.json_safe)
        return cls(**{k: d[k] for k in cls.__dataclass_fields__ if d.get(k) is not None})


def _windows(
    mask: np.ndarray, n: int = WINDOW_BLOCKS, starts: tuple[int, ...] = ()
) -> list[np.ndarray]:
    """Index arrays of consecutive ``n``-block windows inside every run of True, none
    across a block index of ``starts`` (a later power-on's first block)."""
    out: list[np.ndarray] = []
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return out
    cut = np.diff(idx) > 1
    if starts:
        cut |= np.isin(idx[1:], starts)
    breaks = np.flatnonzero(cut) + 1
    for seg in np.split(idx, breaks):
        for s in range(0, seg.size - n + 1, n):
            out.append(seg[s : s + n])
    return out


def _rate_by_run(
    t: np.ndarray, pt_t: np.ndarray, pt_c: np.ndarray, power_ons: tuple[float, ...]
) -> tuple[np.ndarray, tuple[int, ...]]:
    """dT/dt (°C/min, :func:`~gyrolab.compensation.guards.temperature_rate`) at the block
    centres ``t``, each run of a calibration of several power-ons on its own — across a
    power-on the backward difference would compare two runs — and the block index where
    each later run starts."""
    if not power_ons:
        return temperature_rate(t, pt_t, pt_c, RATE_WINDOW_S), ()
    cuts_b, cuts_p = power_on_edges(t, power_ons), power_on_edges(pt_t, power_ons)
    spans = zip(
        zip(cuts_b[:-1], cuts_b[1:], strict=True),
        zip(cuts_p[:-1], cuts_p[1:], strict=True),
        strict=True,
    )
    parts = [
        temperature_rate(t[a:b], pt_t[c:d], pt_c[c:d], RATE_WINDOW_S) for (a, b), (c, d) in spans
    ]
    return np.concatenate(parts), tuple(cuts_b[1:-1])


def fit_band(
    t: np.ndarray,
    y: np.ndarray,
    pred: np.ndarray,
    folds: list[np.ndarray],
    pt_t: np.ndarray,
    pt_c: np.ndarray,
    level: float = LEVEL,
    power_ons: tuple[float, ...] = (),
) -> PredictionBand:
    """The band of a model from its cross-validated predictions (module docstring).

    ``t``, ``y``: the calibration run's block centres (s) and 3.6 s means (°/s); ``pred``:
    each block's prediction by the model fitted without its fold; ``folds``: the boolean
    held-out masks of the CV; ``power_ons``: the calibration's later power-ons (s), where
    a new run starts: dT/dt is taken within each run and no window spans two."""
    T = hold(t, pt_t, pt_c)
    R, starts = _rate_by_run(t, pt_t, pt_c, power_ons)
    r = y - pred
    res, dts, drs = [], [], []
    for held in folds:
        tr = ~held
        if not tr.any():
            continue
        tlo, thi = float(T[tr].min()), float(T[tr].max())
        rlo, rhi = float(R[tr].min()), float(R[tr].max())
        dT = np.maximum(0.0, np.maximum(T - thi, tlo - T))
        dR = np.maximum(0.0, np.maximum(R - rhi, rlo - R))
        for w in _windows(held, starts=starts):
            res.append(abs(float(r[w].mean())))
            dts.append(float(dT[w].mean()))
            drs.append(float(dR[w].mean()))
    a_r, a_t, a_rr = np.array(res), np.array(dts), np.array(drs)
    # excursions within the margins (the PT100's own accuracy; a rate resolution of
    # 0.1 °C/min) count as inside: a slope measured on tiny distances is noise over zero
    inside = (a_t < MARGIN_C) & (a_rr < MARGIN_C_PER_MIN)
    base = a_r[inside] if inside.sum() >= 20 else a_r
    h_cv = float(np.quantile(base, level)) if base.size else float(np.std(r))
    # a new run starts from another point of the noise's slow wander (flicker, random
    # walk): its offset from the calibration's level is not in the CV windows, which are
    # all measured against one run. Its size: the Allan deviation of the CV residual at
    # the longest averaging time with 8 averages (≈ T/8), at the band's level.
    sig_off = _long_allan(r)
    z = float(np.sqrt(2.0) * erfinv(level))
    h0 = TRANSFER * float(np.hypot(h_cv, z * sig_off))
    out = ~inside
    # each direction's slope is measured only where ≥ 3 CV windows went beyond it;
    # otherwise its default (module docstring) stands
    seen = np.array([(a_t >= MARGIN_C).sum() >= 3, (a_rr >= MARGIN_C_PER_MIN).sum() >= 3])
    slopes = np.array([DEFAULT_PER_C * h0, DEFAULT_PER_C_PER_MIN * h0])
    if seen.any():
        A = np.column_stack([a_t[out], a_rr[out]])[:, seen]
        e = np.maximum(a_r[out] - h0, 0.0)
        scale = np.maximum(A.max(axis=0), 1e-12)
        coef, _ = nnls(A / scale, e)
        a = coef / scale
        lin = A @ a
        k = 0.0
        if np.any(lin > 0):
            need = np.where(e > 0, e / np.where(lin > 0, lin, np.inf), 0.0)
            k = float(np.quantile(need, level))
        # never flatter than the prior: a CV whose excursions were a few °C cannot show
        # what 25 °C beyond costs (a polynomial's error grows faster than linearly)
        slopes[seen] = np.maximum(k * a, slopes[seen])
    per_c, per_r = float(slopes[0]), float(slopes[1])
    measured = bool(seen.all())
    return PredictionBand(
        level=level,
        half_width=h0,
        per_c=per_c,
        per_c_per_min=per_r,
        temp_min_c=float(T.min()),
        temp_max_c=float(T.max()),
        rate_min_c_per_min=float(R.min()),
        rate_max_c_per_min=float(R.max()),
        law_measured=measured,
        law_measured_c=bool(seen[0]),
        law_measured_c_per_min=bool(seen[1]),
        n_windows_inside=int(inside.sum()),
        n_windows_outside=int(out.sum()),
        max_half_width=float(
            np.ptp(
                y[: (y.size // WINDOW_BLOCKS) * WINDOW_BLOCKS]
                .reshape(-1, WINDOW_BLOCKS)
                .mean(axis=1)
            )
        )
        if y.size >= WINDOW_BLOCKS
        else float("inf"),
    )


def _long_allan(r: np.ndarray, n_avg: int = 8) -> float:
    """Allan deviation of ``r`` at averaging length ``r.size // n_avg`` (non-overlapping)."""
    m = r.size // n_avg
    if m < 1:
        return 0.0
    means = r[: m * n_avg].reshape(n_avg, m).mean(axis=1)
    return float(np.sqrt(0.5 * np.mean(np.diff(means) ** 2)))


def grade(ratio_p90: float) -> str:
    """none / mild / severe for the 90th percentile of ``h(t)/h₀`` over a run."""
    for limit, name in GRADES:
        if ratio_p90 <= limit:
            return name
    return "severe"  # pragma: no cover - the last limit is infinite


def band_metrics(
    band: PredictionBand,
    t: np.ndarray,
    y: np.ndarray,
    pt_t: np.ndarray,
    pt_c: np.ndarray,
) -> dict[str, Any]:
    """metrics.json ``causal_band`` for one run: the band on the run's 100 s windows of the
    causal output ``y`` (3.6 s means at block centres ``t``), its coverage, and the graded
    expected error."""
    h = band.half_width_at(t, pt_t, pt_c)
    n = (min(y.size, h.size) // WINDOW_BLOCKS) * WINDOW_BLOCKS
    hw = h[:n].reshape(-1, WINDOW_BLOCKS).mean(axis=1)
    yw = y[:n].reshape(-1, WINDOW_BLOCKS).mean(axis=1)
    ratio = h / band.half_width if band.half_width > 0 else np.ones_like(h)
    p90 = float(np.quantile(ratio, 0.9)) if ratio.size else 1.0
    return {
        "level": band.level,
        "half_width_inside_deg_per_s": band.half_width,
        "per_c_deg_per_s": band.per_c,
        "per_c_per_min_deg_per_s": band.per_c_per_min,
        "law_measured": band.law_measured,
        "mean_half_width_deg_per_s": float(hw.mean()) if hw.size else band.half_width,
        "max_half_width_deg_per_s": float(hw.max()) if hw.size else band.half_width,
        "coverage_100s": float(np.mean(np.abs(yw) <= hw)) if hw.size else None,
        "n_windows": int(hw.size),
        "expected_error": {
            "grade": grade(p90),
            "ratio_p90": p90,
            "ratio_mean": float(ratio.mean()) if ratio.size else 1.0,
            "ratio_max": float(ratio.max()) if ratio.size else 1.0,
        },
    }
