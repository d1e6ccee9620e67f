"""The structured causal drift model: linear in its parameters on the causal features.

The model (:mod:`gyrolab.compensation.causal_features` gives the features ``F, R, S, E``
of every PT100 reading)::

    d = Σ_{i≤P} c_i L_i(u(F)) + k R + h S + A E [+ kp max(R, 0) + k2 R|R| + hT S v],
    u(F) = (2F − (lo + hi)) / (hi − lo),   v = u clipped to [−1, 1]

a Legendre series in the *lagged* (die) temperature ``F`` plus rate, hysteresis and
warm-up terms — and, for gyros outside the original class (issue 23), a heating-only rate
term, R|R| and a hysteresis amplitude that changes across the range. The rate terms are
searched with the lag and kept by backward elimination on the blocked CV (ridge-stabilised
fold fits, :func:`cv_linear`), ``S·v`` only when also significant with the effective
sample size (:func:`_select_terms`); outside the calibration range of ``F`` the series
continues linearly from its edge, and R|R| beyond the calibrated rates likewise. The
nonlinear parameters (τ, w, τ_w; the extended search also s₀ and δ) and the order P are
chosen on grids by blocked cross-validation inside the calibration run
(:func:`select_structured`), the linear ones by least squares (:func:`fit_structured`); a
term is kept only if it lowers the cross-validated error by ≥ 1 %
(:data:`~gyrolab.compensation.drift_model.TIE`). The
``poly`` and ``structured`` families of :mod:`gyrolab.compensation.causal_models` are
this model (poly: τ = 0, no term).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.polynomial import legendre

from gyrolab.compensation.causal_features import CausalParams, hold, reading_features
from gyrolab.compensation.drift_model import TIE, CausalCalibration
from gyrolab.numerics.jackknife import jackknife_covariance

TERMS = ("rate", "hyst", "warmup")  # optional terms of the structured model (original)
#: terms added for gyros outside the original class (issue 23), each a function of the
#: same four features (no new state): heating/cooling asymmetry of the rate sensitivity
#: max(R, 0), its growth with the rate R|R| (in (°C/min)² · 60⁻² units, °C²/s²), and a
#: hysteresis whose amplitude changes with temperature S·v (v = u clipped to [−1, 1])
EXTRA_TERMS = ("rate_pos", "rate_sq", "hyst_T")
ALL_TERMS = TERMS + EXTRA_TERMS
#: |coefficient / standard error| (with the effective sample size) a term needs to be kept
T_KEEP = 3.0
#: |coefficient / jackknife standard error| (:func:`jackknife_t`) the hysteresis term
#: needs to stay in the extended family (:func:`_select_terms_backward`)
T_JACK = 2.0
#: the terms on while (τ, τ_w, w, order) are searched, and from which backward
#: elimination starts (:func:`_select_terms`): the rate sensitivity's sign asymmetry and
#: its growth are searched with the lag, not after it — a lag chosen without them
#: absorbs them (the break family, docs/results.md)
GRID_TERMS = TERMS + ("rate_pos", "rate_sq")
#: ridge of the blocked CV's fold fits, in units of the whole run's column norms
#: (:func:`cv_linear`)
CV_RIDGE = 1e-3
TAU_GRID_S = (0.0, 60.0, 150.0, 300.0, 450.0, 600.0, 900.0, 1200.0, 1800.0)
WIDTH_GRID_C = (0.25, 0.5, 1.0, 2.0, 4.0)
WARMUP_GRID_S = (200.0, 300.0, 450.0, 600.0, 900.0, 1200.0, 1800.0)
ORDERS = range(1, 7)
#: how the structured families choose the lag (``PipelineConfig.causal_lag_criterion``):
#: by the blocked CV with the other parameters (``cv``), or then again by profile least
#: squares for the order, terms and other parameters the CV chose (``profile``,
#: :func:`_profile_lag`), with the warm-up's time constant chosen jointly with it where
#: that term is kept (``profile_warmup``, opt-in: docs/results.md)
LAG_CRITERIA = ("cv", "profile", "profile_warmup")
#: the pipeline's default (``PipelineConfig.causal_lag_criterion``): the families are
#: compared at the CV's lag and the winner's τ re-chosen by profile least squares
#: (docs/results.md, issue 23: the break staircase's median 1.162 → 1.112× the oracle,
#: gyrolab's validation family median 1.089 → 1.088×, worst 1.26 → 1.29×)
DEFAULT_LAG_CRITERION = "profile"
#: the hysteresis branch at power-on (:class:`CausalParams` ``start_branch``) searched
#: with the lag by the extended family (``structured_rate``) only: 0 (the play starts
#: where the PT100 reads) or +1 (on its heating branch: the die's self-heating at
#: power-on). Chosen only if ≥ 1 % (TIE) better in CV. Not in the original family: there
#: it let ``structured`` (symmetric rate term) win the selection over ``structured_rate``
#: on units whose rate sensitivity differs heating and cooling (docs/results.md).
START_BRANCHES = (0.0, 1.0)
#: the play's self-heating shift δ (°C, :class:`CausalParams` ``self_heating_c``),
#: searched by the extended family after the width (:func:`_self_heating`): the die's
#: settled rise above its case that the play follows, ``H = F + δ (1 − E)``
SELF_HEATING_GRID_C = (0.25, 0.5, 1.0, 2.0)
#: the play width's temperature coefficient κ (1/°C, :class:`CausalParams`
#: ``width_temp_per_c``: ``w (1 + κ (H − 25 °C))``), searched by the extended family
#: after the order and width (:func:`_width_temperature`): ±25 % and ±50 % over 50 °C
WIDTH_TEMP_GRID_PER_C = (-0.01, -0.005, 0.005, 0.01)
#: the die's own self-heating rise δ_d (°C, :class:`CausalParams` ``die_heating_c``:
#: ``D = F + δ_d (1 − exp(−t/τ))`` for every term), chosen last by the extended family
#: by profile least squares with τ_w (:func:`_die_heating`)
DIE_HEATING_GRID_C = (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)


@dataclass
class StructuredModel:
    """``d = Σ c_i L_i(u(F)) + k R + h S + A E`` on feature rows ``(F, R, S, E)``."""

    coef: np.ndarray  # Legendre c_0..c_P, °/s
    lo: float  # calibration range of F, °C
    hi: float
    k: float = 0.0  # °/s per °C/s
    h: float = 0.0  # °/s (half the heating-cooling difference)
    A: float = 0.0  # °/s at power-on
    terms: tuple[str, ...] = ()
    kp: float = 0.0  # °/s per °C/s of heating only: max(R, 0)
    k2: float = 0.0  # °/s per (°C/s)²: R|R|
    hT: float = 0.0  # °/s: S·v, the hysteresis amplitude's change across the range
    r_lo: float = -np.inf  # calibrated range of R, °C/s: R|R| continues linearly beyond
    r_hi: float = np.inf

    @property
    def order(self) -> int:
        return int(self.coef.size - 1)

    def poly(self, F: np.ndarray) -> np.ndarray:
        """Σ c_i L_i(u), continued linearly beyond u = ±1 (°/s)."""
        u = (2.0 * np.asarray(F, dtype=float) - (self.lo + self.hi)) / (self.hi - self.lo)
        uc = np.clip(u, -1.0, 1.0)
        y = legendre.legval(uc, self.coef)
        if np.any(u != uc):
            d1 = legendre.legval(uc, legendre.legder(self.coef)) if self.order else 0.0 * u
            y = y + d1 * (u - uc)
        return y

    def predict(self, X: np.ndarray) -> np.ndarray:
        X = np.atleast_2d(np.asarray(X, dtype=float))
        y = self.poly(X[:, 0]) + self.k * X[:, 1] + self.h * X[:, 2] + self.A * X[:, 3]
        if self.kp or self.k2 or self.hT:
            v = np.clip((2.0 * X[:, 0] - (self.lo + self.hi)) / (self.hi - self.lo), -1.0, 1.0)
            R = X[:, 1]
            y = y + self.kp * np.maximum(R, 0.0) + self.hT * X[:, 2] * v
            y = y + self.k2 * rate_square(R, self.r_lo, self.r_hi)
        return y

    def spec(self, inputs: list[str], window_s: float | None) -> dict[str, Any]:
        """The exported form (``structured``, :mod:`gyrolab.compensation.regressors`; its
        inputs are F, R, S, E)."""
        return {
            "kind": "structured",
            "coef": np.asarray(self.coef, dtype=float).tolist(),
            "lo": float(self.lo),
            "hi": float(self.hi),
            "k": float(self.k),
            "h": float(self.h),
            "A": float(self.A),
            "kp": float(self.kp),
            "k2": float(self.k2),
            "hT": float(self.hT),
            **self.rate_range(),
        }

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": "structured",
            "coef": [float(c) for c in self.coef],
            "lo": self.lo,
            "hi": self.hi,
            "k": self.k,
            "h": self.h,
            "A": self.A,
            "terms": list(self.terms),
            "kp": self.kp,
            "k2": self.k2,
            "hT": self.hT,
            **self.rate_range(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> StructuredModel:
        return cls(
            coef=np.asarray(d["coef"], dtype=float),
            lo=float(d["lo"]),
            hi=float(d["hi"]),
            k=float(d["k"]),
            h=float(d["h"]),
            A=float(d["A"]),
            terms=tuple(d.get("terms", ())),
            kp=float(d.get("kp", 0.0)),  # absent in models written before issue 23
            k2=float(d.get("k2", 0.0)),
            hT=float(d.get("hT", 0.0)),
            # absent before R|R| was bounded: unbounded, as those models were fitted
            r_lo=float(d.get("r_lo", -np.inf)),
            r_hi=float(d.get("r_hi", np.inf)),
        )

    def rate_range(self) -> dict[str, float]:
        """``{"r_lo", "r_hi"}`` where finite (JSON has no infinity)."""
        pairs = (("r_lo", self.r_lo), ("r_hi", self.r_hi))
        return {k: float(v) for k, v in pairs if np.isfinite(v)}


def rate_square(R: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """``R|R|`` inside the calibrated rate range ``[lo, hi]`` (°C/s), continued linearly
    (its tangent, slope ``2|R|``) beyond it — as the temperature series is: a quadratic
    fitted on the rates a calibration run showed is not carried to rates it never saw
    (a fast ramp heats two to three times faster than a cooling staircase)."""
    R = np.asarray(R, dtype=float)
    Rc = np.clip(R, lo, hi)
    return Rc * np.abs(Rc) + 2.0 * np.abs(Rc) * (R - Rc)


def _term_column(X: np.ndarray, name: str, u: np.ndarray) -> np.ndarray:
    """The regressor of one optional term on feature rows ``X`` (``u`` = scaled F, clipped)."""
    R = X[:, 1]
    cols = {
        "rate": lambda: R,
        "hyst": lambda: X[:, 2],
        "warmup": lambda: X[:, 3],
        "rate_pos": lambda: np.maximum(R, 0.0),
        "rate_sq": lambda: R * np.abs(R),
        "hyst_T": lambda: X[:, 2] * u,
    }
    return cols[name]()


def design(X: np.ndarray, order: int, terms: tuple[str, ...], lo: float, hi: float):
    """The structured model's design matrix on feature rows ``X``: ``L_0..L_P`` of
    ``u(F)`` clipped to [−1, 1], then one column per term of ``terms``."""
    u = np.clip((2.0 * X[:, 0] - (lo + hi)) / (hi - lo), -1.0, 1.0)
    cols = [legendre.legvander(u, order)]
    for t in terms:
        cols.append(_term_column(X, t, u)[:, None])
    return np.hstack(cols)


def _solve(
    G: np.ndarray, b: np.ndarray, d: np.ndarray | None = None, ridge: float = 0.0
) -> np.ndarray:
    """Least squares from the normal equations ``G c = b`` (``G = AᵀA``, ``b = Aᵀy``), with
    the columns scaled by ``d`` (default: to unit diagonal; the Legendre columns on
    [−1, 1] are well conditioned; the scaling brings the rate column, ~1e-3 °C/s, to the
    same size) and ``ridge`` added to the scaled diagonal. A column that is zero
    throughout (no hysteresis reversal seen) gets coefficient 0. Normal equations instead
    of ``lstsq`` on the tall matrix: the CV search solves a few hundred of these, and a
    p × p solve costs nothing next to forming ``AᵀA`` once."""
    if d is None:
        d = np.sqrt(np.diag(G))
    ok = d > 0
    c = np.zeros(G.shape[0])
    Gs = G[np.ix_(ok, ok)] / np.outer(d[ok], d[ok]) + ridge * np.eye(int(ok.sum()))
    c[ok] = np.linalg.lstsq(Gs, b[ok] / d[ok], rcond=1e-12)[0] / d[ok]
    return c


def lstsq(A: np.ndarray, y: np.ndarray) -> np.ndarray:
    return _solve(A.T @ A, A.T @ y)


def fit_structured(
    X: np.ndarray, y: np.ndarray, order: int, terms: tuple[str, ...]
) -> StructuredModel:
    """Least squares of the structured model on feature rows ``X`` and target ``y``."""
    lo, hi = float(X[:, 0].min()), float(X[:, 0].max())
    if not hi > lo:
        raise ValueError("temperature does not vary: a temperature model cannot be fitted")
    c = lstsq(design(X, order, terms, lo, hi), y)
    return model_from_coef(c, X, order, terms)


def model_from_coef(
    c: np.ndarray, X: np.ndarray, order: int, terms: tuple[str, ...]
) -> StructuredModel:
    """The model of coefficients ``c`` (Legendre ``c_0..c_P``, then one per term of
    ``terms``; any further ones are not the model's) fitted on feature rows ``X``."""
    lo, hi = float(X[:, 0].min()), float(X[:, 0].max())
    extra = dict(zip(terms, c[order + 1 : order + 1 + len(terms)], strict=True))
    return StructuredModel(
        coef=c[: order + 1],
        lo=lo,
        hi=hi,
        k=float(extra.get("rate", 0.0)),
        h=float(extra.get("hyst", 0.0)),
        A=float(extra.get("warmup", 0.0)),
        terms=terms,
        kp=float(extra.get("rate_pos", 0.0)),
        k2=float(extra.get("rate_sq", 0.0)),
        hT=float(extra.get("hyst_T", 0.0)),
        r_lo=float(X[:, 1].min()) if "rate_sq" in terms else -np.inf,
        r_hi=float(X[:, 1].max()) if "rate_sq" in terms else np.inf,
    )


def cv_linear(
    X: np.ndarray,
    y: np.ndarray,
    order: int,
    terms: tuple[str, ...],
    folds: list[np.ndarray],
    pred: np.ndarray | None = None,
    ridge: float = 0.0,
) -> float:
    """Blocked-CV RMSE (°/s) of the structured model of ``order`` and ``terms`` on feature
    rows ``X`` and target ``y`` (``folds``: boolean held-out masks); ``pred`` (if given)
    receives every block's held-out prediction (for the prediction band,
    :mod:`.band`).

    With ``ridge`` > 0 (the extended family: :data:`CV_RIDGE`) each fold's fit is a
    ridge regression on the columns scaled by the *whole run's* norms: a term whose
    regressor is almost zero on a fold's training blocks — the warm-up when the first
    hour is held out, a heating-only rate term when the run's one heating step is — then
    gets a coefficient near 0, and the held-out stretch is predicted as by the model
    without that term, not by a coefficient fitted to the noise of the few training
    blocks where the regressor is not zero (which made the CV reject terms that hold on
    other trajectories)."""
    lo, hi = float(X[:, 0].min()), float(X[:, 0].max())
    return cv_design(design(X, order, terms, lo, hi), y, folds, pred, ridge)


def cv_design(
    A: np.ndarray,
    y: np.ndarray,
    folds: list[np.ndarray],
    pred: np.ndarray | None = None,
    ridge: float = 0.0,
) -> float:
    """Blocked-CV RMSE (°/s) of least squares on the design matrix ``A`` (one row per
    block; :func:`cv_linear` with its own design, e.g. the Prandtl–Ishlinskii columns
    of :mod:`.pi_models`); ``pred`` and ``ridge`` as there."""
    G, b = A.T @ A, A.T @ y
    d = np.sqrt(np.diag(G)) if ridge else None
    sq, n = 0.0, 0
    for held in folds:
        Ah, yh = A[held], y[held]
        c = _solve(G - Ah.T @ Ah, b - Ah.T @ yh, d, ridge)
        p = Ah @ c
        if pred is not None:
            pred[held] = p
        r = p - yh
        sq += float(r @ r)
        n += int(held.sum())
    return float(np.sqrt(sq / n))


def block_features(cal: CausalCalibration, params: CausalParams) -> np.ndarray:
    """The features of every block centre of ``cal``: those of the last reading at or
    before it (zero-order hold), the state at rest again at each of its later
    ``power_ons``."""
    feats = reading_features(cal.pt_t, cal.pt_c, params, power_ons=tuple(cal.power_ons))
    return hold(cal.t, cal.pt_t, feats)


def effective_samples(r: np.ndarray) -> float:
    """Effective number of independent samples of a residual series: ``n / (1 + 2 Σ ρ_k)``,
    the autocorrelations ``ρ_k`` summed up to the first lag where they reach zero (the
    integrated autocorrelation time; Sokal's estimator without his window)."""
    r = np.asarray(r, dtype=float) - float(np.mean(r))
    n = r.size
    v = float(np.dot(r, r))
    if n < 4 or v == 0.0:
        return float(n)
    f = np.fft.rfft(np.concatenate([r, np.zeros(n)]))
    ac = np.fft.irfft(np.abs(f) ** 2)[:n] / v
    neg = np.flatnonzero(ac[1 : n // 4] <= 0.0)
    stop = 1 + (int(neg[0]) if neg.size else n // 4 - 1)
    return float(n / (1.0 + 2.0 * float(np.sum(ac[1:stop]))))


def _t_stats(
    X: np.ndarray, y: np.ndarray, order: int, terms: tuple[str, ...]
) -> tuple[np.ndarray, float]:
    """``|c/se|`` of each optional term's coefficient, the least-squares covariance
    ``σ² (AᵀA)⁻¹`` inflated by ``n / n_eff`` (:func:`effective_samples` of the residual),
    and ``n_eff``."""
    lo, hi = float(X[:, 0].min()), float(X[:, 0].max())
    A = design(X, order, terms, lo, hi)
    c = lstsq(A, y)
    r = y - A @ c
    n_eff = effective_samples(r)
    s2 = float(r @ r) / max(r.size - A.shape[1], 1) * (r.size / max(n_eff, 1.0))
    se = np.sqrt(np.maximum(np.diag(s2 * np.linalg.pinv(A.T @ A))[order + 1 :], 0.0))
    return np.abs(c[order + 1 :]) / np.where(se > 0, se, np.inf), n_eff


def _select_terms(
    X: np.ndarray, y: np.ndarray, order: int, folds: list[np.ndarray]
) -> tuple[tuple[str, ...], float, dict[str, Any]]:
    """Two stages. (1) The original terms (:data:`TERMS`): each is dropped if removing it
    costs < 1 % CV RMSE. (2) Each of :data:`EXTRA_TERMS` is added, best first, only if it
    passes both tests: its coefficient is significant with the *effective* number of
    samples (``|c/se| ≥`` :data:`T_KEEP`, :func:`_t_stats`: 3.6 s residuals of a
    flicker-dominated gyro are far from independent, n_eff ≈ 300–600 of 13 000 blocks on
    the break family) and it lowers the CV RMSE by ≥ 1 %. A term a unit lacks fails the
    first test; one that fits a coincidence of the calibration run fails the second.
    Measured against letting the t test alone choose every term (docs/results.md): that
    dropped real rate terms on some units and let the polynomial family win on others."""
    terms = TERMS
    err = cv_linear(X, y, order, terms, folds)
    dropped: dict[str, float] = {}
    for t in TERMS:
        fewer = tuple(x for x in terms if x != t)
        e = cv_linear(X, y, order, fewer, folds)
        dropped[t] = e
        if e <= err * (1.0 + TIE):
            terms, err = fewer, min(err, e)
    added: list[dict[str, Any]] = []
    todo = list(EXTRA_TERMS)
    while todo:
        best = None
        for t in todo:
            more = terms + (t,)
            e = cv_linear(X, y, order, more, folds)
            tstat, n_eff = _t_stats(X, y, order, more)
            ok = tstat[-1] >= T_KEEP and e < err * (1.0 - TIE)
            if ok and (best is None or e < best[0]):
                best = (e, t, float(tstat[-1]), n_eff)
        if best is None:
            break
        err, t = best[0], best[1]
        terms = terms + (t,)
        todo.remove(t)
        added.append({"added": t, "t": best[2], "n_eff": best[3], "cv_rmse": err})
    log = {"cv_rmse_without_term": dropped, "terms": list(terms), "added": added}
    return terms, err, log


def _without(terms: tuple[str, ...], t: str) -> tuple[str, ...]:
    return tuple(x for x in terms if x != t)


def _select_terms_backward(
    X: np.ndarray, y: np.ndarray, order: int, folds: list[np.ndarray]
) -> tuple[tuple[str, ...], float, dict[str, Any]]:
    """The extended family's term selection (ridge-stabilised CV, :data:`CV_RIDGE`), in
    four stages. (1) Backward elimination from :data:`GRID_TERMS` (the terms the grid
    search had on), the warm-up excepted: the term whose removal costs least CV RMSE is
    dropped while that cost is < 1 % (:data:`~gyrolab.compensation.drift_model.TIE`), so
    a term stays only if the held-out stretches need it. (2) The hysteresis term, if
    kept, is dropped when its coefficient is below :data:`T_JACK` jackknife standard
    errors (:func:`jackknife_t`): the CV kept it on a break-family unit without
    hysteresis (|t| 0.8; 2.7–37 on the nine with it), and the same test on the rate
    terms removed heating-only terms the fast ramps need (docs/results.md). (3) The
    warm-up stays only if its coefficient is significant with the *effective* number of
    samples (``|c/se| ≥`` :data:`T_KEEP`, :func:`_t_stats`): its column lives in the
    first CV segment, and when that segment is held out the ridge fit gives it ≈ 0, so
    the CV has no power on it (on the break staircase plus a ramp cycle, dropping it
    changed the held-out RMSE of its own segment by < 1e-9 relative on 5 of 12 units)
    and the 1 % tie dropped it by chance — unit 2's self-heating warm-up there, whose
    100 s p-p gap then reached 12 points (docs/results.md, "The ramp cycle's side
    effects"). (4) ``hyst_T`` is added only if it passes both tests: its coefficient is
    significant with the effective number of samples (:func:`_t_stats`: 3.6 s residuals
    of a flicker-dominated gyro are far from independent) and it lowers the CV RMSE by
    ≥ 1 %. Measured on the break family (docs/results.md) against adding the rate
    asymmetry and R|R| one at a time after the original terms (:func:`_select_terms`):
    they were then rejected on units that have them (the lag, searched without them,
    had absorbed part of them)."""
    terms = GRID_TERMS
    err = cv_linear(X, y, order, terms, folds, ridge=CV_RIDGE)
    dropped: list[dict[str, Any]] = []
    while cand := [t for t in terms if t != "warmup"]:
        e, t = min(
            (cv_linear(X, y, order, _without(terms, t), folds, ridge=CV_RIDGE), t) for t in cand
        )
        if e > err * (1.0 + TIE):
            break
        terms = _without(terms, t)
        err = min(err, e)
        dropped.append({"dropped": t, "cv_rmse": e})
    jack: dict[str, float] = {}
    if "hyst" in terms:  # (2) the hysteresis the CV kept must stand its jackknife test
        jack = jackknife_t(X, y, order, terms, folds)
        if jack["hyst"] < T_JACK:
            terms = _without(terms, "hyst")
            err = cv_linear(X, y, order, terms, folds, ridge=CV_RIDGE)
            dropped.append({"dropped": "hyst", "jackknife_t": jack["hyst"], "cv_rmse": err})
    warm_t: float | None = None
    if "warmup" in terms:  # (3) the CV cannot test it: its effective-sample t decides
        warm_t = float(_t_stats(X, y, order, _without(terms, "warmup") + ("warmup",))[0][-1])
        if warm_t < T_KEEP:
            terms = _without(terms, "warmup")
            err = cv_linear(X, y, order, terms, folds, ridge=CV_RIDGE)
            dropped.append({"dropped": "warmup", "t": warm_t, "cv_rmse": err})
    added: list[dict[str, Any]] = []
    for t in (x for x in ALL_TERMS if x not in GRID_TERMS):
        more = terms + (t,)
        e = cv_linear(X, y, order, more, folds, ridge=CV_RIDGE)
        tstat, n_eff = _t_stats(X, y, order, more)
        if tstat[-1] >= T_KEEP and e < err * (1.0 - TIE):
            err, terms = e, more
            added.append({"added": t, "t": float(tstat[-1]), "n_eff": n_eff, "cv_rmse": e})
    log = {
        "dropped": dropped,
        "terms": list(terms),
        "added": added,
        "jackknife_t": jack,
        "warmup_t": warm_t,
    }
    return terms, err, log


def segments(folds: list[np.ndarray]) -> list[np.ndarray]:
    """The blocked CV's segments: the contiguous stretches of the folds' held-out masks,
    as boolean masks."""
    out = []
    for held in folds:
        idx = np.flatnonzero(held)
        for run in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1):
            m = np.zeros(held.size, dtype=bool)
            m[run] = True
            out.append(m)
    return out


def jackknife_t(
    X: np.ndarray, y: np.ndarray, order: int, terms: tuple[str, ...], folds: list[np.ndarray]
) -> dict[str, float]:
    """``|c / se|`` of each term's least-squares coefficient, ``se`` its delete-one-segment
    jackknife standard error over the K CV segments (:func:`segments`; Efron & Stein,
    *Ann. Statist.* 9 (1981) 586): ``se² = (K−1)/K Σ_k (c_k − c̄)²``, the diagonal of
    :func:`gyrolab.numerics.jackknife.jackknife_covariance`. Leaving out a whole
    1.3 h segment carries the residuals' correlation (flicker noise, a wrong lag) that a
    per-sample standard error misses."""
    segs = segments(folds)
    A = design(X, order, terms, float(X[:, 0].min()), float(X[:, 0].max()))
    c = lstsq(A, y)
    cs = np.array([lstsq(A[~m], y[~m]) for m in segs])
    se = np.sqrt(np.diag(jackknife_covariance(cs)))
    t = np.abs(c) / np.where(se > 0, se, np.inf)
    return {n: float(t[order + 1 + i]) for i, n in enumerate(terms)}


def _refine_tau(f: Callable[[float], float], tau: float, err: float) -> tuple[float, float]:
    """Refine the lag ``tau`` (a point of :data:`TAU_GRID_S` with criterion ``err``)
    between its grid neighbours: golden section on ``f(τ)``, 8 steps. Returns the best τ
    seen and its criterion."""
    g = list(TAU_GRID_S)
    i = g.index(tau)
    a, b = g[max(i - 1, 0)], g[min(i + 1, len(g) - 1)]
    phi = 0.5 * (np.sqrt(5.0) - 1.0)
    c, d = b - phi * (b - a), a + phi * (b - a)
    fc, fd = f(c), f(d)
    for _ in range(8):
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - phi * (b - a)
            fc = f(c)
        else:
            a, c, fc = c, d, fd
            d = a + phi * (b - a)
            fd = f(d)
    for t, e in ((c, fc), (d, fd)):
        if e < err:
            err, tau = e, float(t)
    return tau, err


def profile_rms(X: np.ndarray, y: np.ndarray, order: int, terms: tuple[str, ...]) -> float:
    """The profile least-squares criterion: the in-sample RMS residual (°/s) of the whole
    run's least-squares fit of the structured model of ``order`` and ``terms`` on feature
    rows ``X`` (what :func:`_profile_lag` and :func:`_die_heating` minimise)."""
    A = design(X, order, terms, float(X[:, 0].min()), float(X[:, 0].max()))
    r = y - A @ lstsq(A, y)
    return float(np.sqrt(float(r @ r) / r.size))


def _profile_lag(
    feature: Callable[[CausalParams], np.ndarray],
    y: np.ndarray,
    p: CausalParams,
    order: int,
    terms: tuple[str, ...],
    warmup: bool = False,
) -> tuple[CausalParams, dict[str, Any]]:
    """The lag by profile least squares: the in-sample RMS residual of the whole run's
    fit of the model the CV chose (``p``'s other parameters, ``order``, the ``terms`` it
    kept) minimised over τ on :data:`TAU_GRID_S`, refined between grid neighbours; with
    ``warmup`` and the warm-up term kept, over (τ_w, τ) on :data:`WARMUP_GRID_S` × the τ
    grid, since both shape the first hours of a run (with τ_w held at the CV's, the lag
    moved away from the die's on gyrolab's validation units 6 and 10, but the fleet
    prior's quick calibrations got worse with it: docs/results.md). τ is one
    nonlinear parameter of a model linear in the rest, so its least-squares estimate
    (Ljung, *System Identification*, 2nd ed., §7.3, the prediction-error method; Golub &
    Pereyra, SIAM J. Numer. Anal. 10, 1973, variable projection) does not overfit; it
    varies far less than the blocked CV's, whose fold fits of the rate and warm-up
    columns under flicker noise leave it flat or jagged in τ (the break family,
    docs/results.md). The blocked CV keeps the discrete choices (order, terms, family:
    the families are compared at the CV's parameters, ``tau_plain_cv_s`` and
    ``warmup_plain_cv_s`` of the log). Returns the parameters with that τ (and τ_w) and
    a log (the criterion on the τ grid at the chosen τ_w, °/s)."""

    def crit(q: CausalParams) -> float:
        return profile_rms(feature(q), y, order, terms)

    tws = WARMUP_GRID_S if warmup and "warmup" in terms else (p.warmup_tau_s,)
    grid = {
        (tw, tau): crit(replace(p, warmup_tau_s=tw, tau_s=tau)) for tw in tws for tau in TAU_GRID_S
    }
    tw, tau0 = min(grid, key=lambda k: grid[k])
    q = replace(p, warmup_tau_s=tw)
    tau, _ = _refine_tau(lambda t: crit(replace(q, tau_s=float(t))), tau0, grid[(tw, tau0)])
    log = {
        "tau_plain_cv_s": p.tau_s,
        "warmup_plain_cv_s": p.warmup_tau_s,
        "tau_s": tau,
        "warmup_tau_s": tw,
        "criterion_by_tau": {str(t): grid[(tw, t)] for t in TAU_GRID_S},
    }
    return replace(q, tau_s=tau), log


def _grid(name: str, values: tuple[float, ...]) -> list[dict[str, float]]:
    """One feature parameter's grid as changes for :func:`_descend`."""
    return [{name: v} for v in values]


def _descend(
    cv: Callable[[CausalParams, int], float],
    order: int,
    err: float,
    p: CausalParams,
    changes: list[dict[str, float]],
) -> tuple[float, CausalParams]:
    """Each change in turn applied to the parameters chosen so far, kept where it lowers
    the CV RMSE: a coordinate pass over grids. Returns the CV RMSE and the parameters."""
    for change in changes:
        q = replace(p, **change)
        e = cv(q, order)
        if e < err:
            err, p = e, q
    return err, p


def _new_parameter(
    cv: Callable[[CausalParams, int], float],
    p: CausalParams,
    order: int,
    err: float,
    name: str,
    values: tuple[float, ...],
    **fixed: float,
) -> tuple[float, CausalParams, dict[str, float]]:
    """Each value of the feature parameter ``name`` (with ``fixed`` set beside it)
    against the choice so far by the blocked CV, the best kept only if ≥ 1 % (TIE)
    better: a new parameter must win by TIE, as s₀ must. Returns the CV RMSE, the
    parameters and the CV RMSE of each value tried."""
    tried: dict[str, float] = {}
    best = (np.inf, p)
    for v in values:
        q = replace(p, **{name: v}, **fixed)
        e = cv(q, order)
        tried[str(v)] = e
        if e < best[0]:
            best = (e, q)
    if best[0] < err * (1.0 - TIE):
        err, p = best
    return err, p, tried


def _self_heating(
    cv: Callable[[CausalParams, int], float], p: CausalParams, order: int, err: float
) -> tuple[float, CausalParams, dict[str, float]]:
    """The play's self-heating shift δ (:class:`CausalParams` ``self_heating_c``): each δ
    of :data:`SELF_HEATING_GRID_C`, the play started where the PT100 reads (s₀ = 0),
    against the choice so far (δ = 0, s₀ 0 or +1) by the blocked CV, kept only if ≥ 1 %
    (TIE) better; where a δ wins, the warm-up's τ_w (which the shift shares) with δ on
    their joint grid, then the width again. Returns the CV RMSE, the parameters and the
    CV RMSE of each δ first tried."""
    err, p, tried = _new_parameter(
        cv, p, order, err, "self_heating_c", SELF_HEATING_GRID_C, start_branch=0.0
    )
    if p.self_heating_c:  # (τ_w, δ) on their joint grid, then the width at them
        joint = [
            {"warmup_tau_s": tw, "self_heating_c": v}
            for tw in WARMUP_GRID_S
            for v in SELF_HEATING_GRID_C
        ]
        err, p = _descend(cv, order, err, p, joint + _grid("width_c", WIDTH_GRID_C))
    return err, p, tried


def _order_width(
    cv: Callable[[CausalParams, int], float], p: CausalParams, order: int, err: float
) -> tuple[float, CausalParams, int]:
    """The order, the play's width and its self-heating shift δ on their joint grid
    (:data:`ORDERS` × :data:`WIDTH_GRID_C` × ({0} ∪ :data:`SELF_HEATING_GRID_C`)) at
    the lag, warm-up and start branch chosen, then τ_w again. δ > 0 (s₀ = 0) must beat
    the best δ = 0 by TIE, as in :func:`_self_heating`. Why: the lag's joint grid
    chooses the order at the default width and every pass after it keeps that order, so
    an order chosen there can hold the width and δ at a poorer optimum (break unit 7,
    ramp cycle, draw 1: order 2 with w = 0.5 °C at a CV RMSE 4.6 % above order 5 with
    w = 1 °C; docs/results.md). Returns the CV RMSE, the parameters and the order."""

    def best(cands: list[CausalParams]) -> tuple[float, CausalParams, int]:
        b: tuple[float, CausalParams, int] = (np.inf, p, order)
        for q in cands:
            for o in ORDERS:
                e = cv(q, o)
                if e < b[0]:
                    b = (e, q, o)
        return b

    widths = [replace(p, width_c=w) for w in WIDTH_GRID_C]
    chosen = best([replace(q, self_heating_c=0.0) for q in widths])
    shifts = [{"self_heating_c": v, "start_branch": 0.0} for v in SELF_HEATING_GRID_C]
    shifted = best([replace(q, **c) for q in widths for c in shifts])
    if shifted[0] < chosen[0] * (1.0 - TIE):
        chosen = shifted
    err, p, order = chosen
    err, p = _descend(cv, order, err, p, _grid("warmup_tau_s", WARMUP_GRID_S))
    return err, p, order


def _width_temperature(
    cv: Callable[[CausalParams, int], float], p: CausalParams, order: int, err: float
) -> tuple[float, CausalParams, dict[str, float]]:
    """The play width's temperature coefficient κ (:class:`CausalParams`
    ``width_temp_per_c``): each κ of :data:`WIDTH_TEMP_GRID_PER_C` against κ = 0, kept
    only if ≥ 1 % (TIE) better in the blocked CV; where one wins, the width at it again.
    Returns the CV RMSE, the parameters and the CV RMSE of each κ tried."""
    err, p, tried = _new_parameter(cv, p, order, err, "width_temp_per_c", WIDTH_TEMP_GRID_PER_C)
    if p.width_temp_per_c:
        err, p = _descend(cv, order, err, p, _grid("width_c", WIDTH_GRID_C))
    return err, p, tried


def _die_heating(
    feature: Callable[[CausalParams], np.ndarray],
    y: np.ndarray,
    p: CausalParams,
    order: int,
    terms: tuple[str, ...],
) -> tuple[CausalParams, tuple[str, ...], dict[str, Any]]:
    """The die's own self-heating δ_d (:class:`CausalParams` ``die_heating_c``) by
    profile least squares: the in-sample RMS residual of the whole run's fit of the
    order the CV chose, with the terms it kept and the warm-up, over
    :data:`DIE_HEATING_GRID_C` × :data:`WARMUP_GRID_S` (δ_d and the warm-up share the
    first hours), against the choice so far; kept only where it is ≥ 1 %
    (:data:`~gyrolab.compensation.drift_model.TIE`) lower. Why not the blocked CV: the
    transient lives in the first CV segment, which its fold fits cannot predict when it
    is held out (as for the warm-up, :func:`_select_terms_backward`), and it kept an
    additive warm-up of τ_w 1800 s at δ_d = 0 on the break family's unit 28, whose cold
    start then reached 1.79× the oracle (δ_d by profile: 1.28×, docs/results.md). The
    additive warm-up stays beside δ_d: one power-on at one temperature cannot tell the
    two apart, the cold start can (a calibration whose warm-up is not self-heating keeps
    δ_d = 0 unless the fit drops by TIE). Returns the parameters, the terms and a log."""

    def rms(q: CausalParams, tt: tuple[str, ...]) -> float:
        return profile_rms(feature(q), y, order, tt)

    base = rms(p, terms)
    warm = terms if "warmup" in terms else terms + ("warmup",)
    grid = {
        (d, tw): rms(replace(p, die_heating_c=d, warmup_tau_s=tw), warm)
        for d in DIE_HEATING_GRID_C
        for tw in WARMUP_GRID_S
    }
    d, tw = min(grid, key=lambda k: grid[k])
    log = {
        "rms_without": base,
        "rms": grid[(d, tw)],
        "die_heating_c": d,
        "warmup_tau_s": tw,
        "warmup_plain_s": p.warmup_tau_s,
        "terms_plain": list(terms),
    }
    if grid[(d, tw)] < base * (1.0 - TIE):
        return replace(p, die_heating_c=d, warmup_tau_s=tw), warm, log
    log["die_heating_c"] = 0.0
    return p, terms, log


def select_structured(
    cal: CausalCalibration,
    folds: list[np.ndarray],
    extended: bool = False,
    lag_criterion: str = "cv",
) -> tuple[CausalParams, int, tuple[str, ...], float, dict[str, Any]]:
    """Choose (τ, τ_w, order, s₀) on the joint grid with every original term on
    (:data:`TERMS`; ``extended``: :data:`GRID_TERMS`, ridge-stabilised CV), refine τ
    between its grid neighbours (golden section), then w and τ_w again on their grids
    (``extended``: then the self-heating shift δ, :func:`_self_heating`, the order,
    width and δ on their joint grid, :func:`_order_width`, and the width's temperature
    coefficient κ, :func:`_width_temperature`); then the terms
    (:func:`_select_terms`; ``extended``: :func:`_select_terms_backward`); with
    ``lag_criterion="profile"`` τ is finally chosen again, for the terms kept, by profile
    least squares (``"profile_warmup"``: with τ_w where the warm-up term is kept)
    (:func:`_profile_lag`); ``extended``: last, the die's own self-heating δ_d by profile
    least squares (:func:`_die_heating`). The lag, the warm-up and (``extended`` only)
    the start branch (:data:`START_BRANCHES`) are searched together because all three
    shape the first hours of a run. Returns the choice and a log."""
    if lag_criterion not in LAG_CRITERIA:
        raise ValueError(f"lag_criterion must be one of {LAG_CRITERIA}, not {lag_criterion!r}")
    y = cal.rate
    base = CausalParams()
    feats: dict[CausalParams, np.ndarray] = {}
    on, ridge = (GRID_TERMS, CV_RIDGE) if extended else (TERMS, 0.0)

    def feature(p: CausalParams) -> np.ndarray:
        if p not in feats:
            feats[p] = block_features(cal, p)
        return feats[p]

    def cv(p: CausalParams, order: int) -> float:
        return cv_linear(feature(p), y, order, on, folds, ridge=ridge)

    bests: dict[float, tuple[float, CausalParams, int]] = {}
    for s0 in START_BRANCHES if extended else (0.0,):
        best: tuple[float, CausalParams, int] = (np.inf, base, 1)
        for tau in TAU_GRID_S:
            for tw in WARMUP_GRID_S:
                p = replace(base, tau_s=tau, warmup_tau_s=tw, start_branch=s0)
                for order in ORDERS:
                    e = cv(p, order)
                    if e < best[0]:
                        best = (e, p, order)
        bests[s0] = best
    err, p, order = bests[0.0]
    for s0 in list(bests)[1:]:  # a start branch must beat starting at 0 by TIE
        if bests[s0][0] < err * (1.0 - TIE):
            err, p, order = bests[s0]
    tau, err = _refine_tau(lambda t: cv(replace(p, tau_s=t), order), p.tau_s, err)
    p = replace(p, tau_s=tau)
    err, p = _descend(
        cv, order, err, p, _grid("width_c", WIDTH_GRID_C) + _grid("warmup_tau_s", WARMUP_GRID_S)
    )
    shifts: dict[str, float] = {}
    slopes: dict[str, float] = {}
    if extended:
        err, p, shifts = _self_heating(cv, p, order, err)
        err, p, order = _order_width(cv, p, order, err)
        err, p, slopes = _width_temperature(cv, p, order, err)
    select = _select_terms_backward if extended else _select_terms
    terms, err, log = select(feature(p), y, order, folds)
    log["order"] = order
    if lag_criterion != "cv":
        warm = lag_criterion == "profile_warmup"
        p, log["lag_profile"] = _profile_lag(feature, y, p, order, terms, warm)
    if extended:
        p, terms, log["die_heating"] = _die_heating(feature, y, p, order, terms)
        log["terms"] = list(terms)
    log["cv_rmse_by_start_branch"] = {str(k): v[0] for k, v in bests.items()}
    if shifts:
        log["cv_rmse_by_self_heating"] = shifts
    if slopes:
        log["cv_rmse_by_width_temp"] = slopes
    return p, order, terms, err, log


__all__ = [
    "ALL_TERMS",
    "DEFAULT_LAG_CRITERION",
    "DIE_HEATING_GRID_C",
    "EXTRA_TERMS",
    "LAG_CRITERIA",
    "ORDERS",
    "SELF_HEATING_GRID_C",
    "WIDTH_TEMP_GRID_PER_C",
    "START_BRANCHES",
    "TERMS",
    "T_KEEP",
    "effective_samples",
    "StructuredModel",
    "block_features",
    "cv_design",
    "cv_linear",
    "design",
    "lstsq",
    "model_from_coef",
    "fit_structured",
    "profile_rms",
    "select_structured",
]
