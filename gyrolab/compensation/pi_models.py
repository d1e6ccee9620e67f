"""The ``structured_pi`` drift-model family: ``structured_rate`` with its single
hysteresis play replaced by a Prandtl–Ishlinskii superposition of plays
(:mod:`gyrolab.compensation.hysteresis`).

The model (features ``F, R, S, E`` of :mod:`gyrolab.compensation.causal_features`,
branches ``S_j`` of the plays of widths ``W_j`` =
:data:`~gyrolab.compensation.hysteresis.PI_WIDTHS_C` on ``F``)::

    d = Σ_{i≤P} c_i L_i(u(F)) + [k R + A E + kp max(R, 0) + k2 R|R|] + Σ_j h_j S_j

The lag, warm-up, start branch, order and terms are ``structured_rate``'s choice
(:func:`~gyrolab.compensation.structured.select_structured`, ``extended``: the same
search, done once when both families are fitted); where that choice keeps the hysteresis
term, its single play (and ``S·v``) is replaced by the plays ``S_j``, every coefficient
is refitted by least squares, and the plays' start offset δ at power-on
(:func:`~gyrolab.compensation.hysteresis.pi_start`) is chosen on
:data:`OFFSET_GRID_C` by the CV. Its CV RMSE
is the ridge-stabilised one (:data:`~gyrolab.compensation.structured.CV_RIDGE`), as
``structured_rate``'s. The plays replace the single one whatever the CV says: on the
break family the CV did not tell the two apart (within ±2 %, either way) where the
held-out runs preferred the plays (docs/results.md, issue 23). Not a default family, and
without a firmware form yet (:meth:`PICausalModel.spec`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gyrolab.compensation.causal_features import (
    CausalParams,
    hold,
    initial_state,
    power_on_edges,
    reading_features,
    step,
)
from gyrolab.compensation.causal_models import (
    CausalDriftModel,
    CausalState,
    cv_lag_params,
    cv_lag_terms,
    extended_choice,
)
from gyrolab.compensation.drift_model import Candidate, Family, FitContext, NotExportable
from gyrolab.compensation.hysteresis import PI_WIDTHS_C, pi_branches, pi_start, pi_step
from gyrolab.compensation.structured import (
    CV_RIDGE,
    StructuredModel,
    cv_design,
    design,
    lstsq,
    model_from_coef,
)

#: the single-play terms the plays replace
PLAY_TERMS = ("hyst", "hyst_T")
#: the plays' start offset δ (°C) searched by the CV: 0 and 2 are the single play's start
#: branches s₀ = 0 and +1 for every width ≤ 4 °C
OFFSET_GRID_C = (0.0, 0.25, 0.5, 1.0, 2.0)


@dataclass
class PIModel:
    """``base`` (a structured model without hysteresis terms) plus ``Σ h_j S_j`` on
    feature rows ``(F, R, S, E, S_1, …, S_m)``."""

    base: StructuredModel
    widths: tuple[float, ...] = ()  # W_j, °C
    hw: tuple[float, ...] = ()  # h_j, °/s
    offset_c: float = 0.0  # δ: the plays' start below F at power-on, °C

    def predict(self, X: np.ndarray) -> np.ndarray:
        X = np.atleast_2d(np.asarray(X, dtype=float))
        y = self.base.predict(X[:, :4])
        for j, h in enumerate(self.hw):  # element by element: one row or many, same sums
            y = y + h * X[:, 4 + j]
        return y

    def to_dict(self) -> dict[str, Any]:
        return {
            "widths_c": [float(w) for w in self.widths],
            "h": [float(h) for h in self.hw],
            "offset_c": float(self.offset_c),
        }


@dataclass
class PIState(CausalState):
    """The causal feature state plus the plays' positions (°C)."""

    plays: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass
class PICausalModel(CausalDriftModel):
    """A ``structured_pi`` model: the feature parameters and a :class:`PIModel`."""

    def start(self) -> PIState:
        return PIState()

    def reading(self, state: CausalState, t_s: float, temp_c: float) -> None:
        assert isinstance(state, PIState)
        if state.features is None:
            state.features, dt = initial_state(temp_c, t_s, self.params), 0.0
            state.plays = pi_start(temp_c, self.model.widths, self.model.offset_c)
        else:
            dt = t_s - state.t_last
        x = step(state.features, temp_c, dt, self.params)
        s = pi_step(state.plays, x[0], self.model.widths)
        state.t_last = t_s
        state.held = float(self.model.predict(np.array([[*x, *s]]))[0])

    def reading_drift(self, pt_t: np.ndarray, pt_c: np.ndarray) -> np.ndarray:
        m = self.model
        return m.predict(pi_features(pt_t, pt_c, self.params, m.widths, m.offset_c))

    def parameters(self) -> dict[str, Any]:
        return {"structured": self.model.base.to_dict(), "pi": self.model.to_dict()}

    def spec(self) -> dict[str, Any]:
        raise NotExportable(
            "the structured_pi drift model has no firmware form yet (its Prandtl-Ishlinskii "
            "plays are not in the exported state machine); use structured_rate"
        )


def pi_features(
    pt_t: np.ndarray,
    pt_c: np.ndarray,
    params: CausalParams,
    widths: tuple[float, ...],
    offset_c: float = 0.0,
    power_ons: tuple[float, ...] = (),
) -> np.ndarray:
    """Rows ``(F, R, S, E, S_1, …, S_m)`` at every reading: the causal features and the
    branches of the plays of ``widths`` on ``F``, at the first reading ``offset_c`` below
    it (:func:`~gyrolab.compensation.hysteresis.pi_start`); at rest again at each of the
    later ``power_ons`` (s), as the features are."""
    X = reading_features(pt_t, pt_c, params, power_ons=power_ons)
    if not widths or not X.shape[0]:
        return X
    pt_c = np.asarray(pt_c, dtype=float)
    edges = power_on_edges(pt_t, power_ons)
    S = [
        pi_branches(X[a:b, 0], widths, pi_start(float(pt_c[a]), widths, offset_c))
        for a, b in zip(edges[:-1], edges[1:], strict=True)
        if b > a
    ]
    return np.hstack([X, np.vstack(S)])


def _load(meta: dict[str, Any], arrays: dict[str, np.ndarray], prefix: str) -> PICausalModel:
    pi = meta["pi"]
    model = PIModel(
        StructuredModel.from_dict(meta["structured"]),
        tuple(float(w) for w in pi["widths_c"]),
        tuple(float(h) for h in pi["h"]),
        float(pi["offset_c"]),
    )
    return PICausalModel(str(meta["family"]), CausalParams.from_dict(meta["features"]), model)


def _fit(ctx: FitContext) -> Candidate:
    """``structured_rate``'s choice, its single play replaced by the plays (docstring).
    The offset δ and the score are the CV's at the lag the CV chose
    (:func:`~gyrolab.compensation.causal_models.cv_lag_params`), as every family's: a
    profile lag moves τ only; the held-out predictions (the band) are the model's own."""
    ps, order, terms, _err, log = extended_choice(ctx)
    cal, y = ctx.cal, ctx.cal.rate
    widths = PI_WIDTHS_C if "hyst" in terms else ()
    base_terms = tuple(t for t in terms if t not in PLAY_TERMS) if widths else terms
    plain = cv_lag_terms(terms, log)  # the score's terms, as every family's
    score_terms = tuple(t for t in plain if t not in PLAY_TERMS) if widths else plain

    def columns(
        p: CausalParams, off: float, tt: tuple[str, ...] = base_terms
    ) -> tuple[np.ndarray, np.ndarray]:
        feats = pi_features(cal.pt_t, cal.pt_c, p, widths, off, tuple(cal.power_ons))
        X = hold(cal.t, cal.pt_t, feats)
        lo, hi = float(X[:, 0].min()), float(X[:, 0].max())
        return X, np.hstack([design(X[:, :4], order, tt, lo, hi), X[:, 4:]])

    pc = cv_lag_params(ps, log)
    cvs = {
        off: cv_design(columns(pc, off, score_terms)[1], y, ctx.folds, ridge=CV_RIDGE)
        for off in (OFFSET_GRID_C if widths else (0.0,))
    }
    off = min(cvs, key=lambda o: cvs[o])
    X, A = columns(ps, off)
    pred = np.empty_like(y)
    own = cv_design(A, y, ctx.folds, pred, ridge=CV_RIDGE)
    c = lstsq(A, y)
    model = PIModel(
        model_from_coef(c, X[:, :4], order, base_terms),
        tuple(widths),
        tuple(float(h) for h in c[order + 1 + len(base_terms) :]),
        float(off),
    )
    info = {
        **log,
        "features": ps.to_dict(),
        "terms": list(base_terms),
        "pi_widths_c": list(widths),
        "cv_rmse_by_offset": {str(k): v for k, v in cvs.items()},
        **({"cv_rmse_at_profile_lag": own} if pc != ps else {}),
    }
    return Candidate(PICausalModel("structured_pi", ps, model), cvs[off], info, pred)


FAMILIES = (
    Family(
        "structured_pi",
        _fit,
        _load,
        2.6,
        "structured_rate with a Prandtl-Ishlinskii sum of plays for its hysteresis",
    ),
)
KINDS = ()

__all__ = ["FAMILIES", "KINDS", "PICausalModel", "PIModel", "PIState", "pi_features"]
