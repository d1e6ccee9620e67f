"""The causal drift model of a calibration run: every family fitted, the winner chosen by
blocked cross-validation inside the run — the headline.

A family (:mod:`gyrolab.compensation.families`; the built-in ones in
:mod:`gyrolab.compensation.causal_models`: ``poly``, ``structured``, ``bp``, ``gabp``)
is a :class:`~gyrolab.compensation.drift_model.DriftModel` whose output at time t uses
temperature readings at or before t only: it runs on a live stream, and in firmware. The
compensated output is ``raw(t) − d(t)`` at the sensor's full rate.

**Selection** (:func:`fit_causal`): blocked 5-fold cross-validation in time *inside the
calibration run* (10 contiguous segments, segment b in fold b mod 5: every fold holds
out two separate stretches of the trajectory — heating, soaks, cooling steps — that the
fit never saw). Segments of 1.3 h on a 13 h run, not shorter: the 1/f bias instability
wanders on the scale of hours, and with short held-out stretches between training ones a
model that bends to follow that wander (e.g. a too-long lag) is rewarded for predicting
noise it saw next door — with 20 segments the lag was chosen 1.5–8× too long on 4 of
12 suite units. Each family of ``PipelineConfig.causal_families`` is scored by its
held-out RMSE on the 3.6 s averages (a structured family's at the lag the CV chose, also
when ``causal_lag_criterion = "profile"`` then moves the winner's lag); the lowest wins,
and a family within 1 % (:data:`~gyrolab.compensation.drift_model.TIE`) of a simpler
one (the families' rank: poly, structured, bp, gabp, then the others) loses to it. The
scores and the winner go into model.json.

Fitting data: the calibration run's 3.6 s block means of the raw rate (the classical
target: no decomposition) and its PT100 readings
(:class:`~gyrolab.compensation.drift_model.CausalCalibration`).

:func:`causal_state` / :func:`causal_from_state` write and read the chosen model in
model.json's ``causal_model`` (the family's :meth:`describe` and :meth:`save`; the family
named there loads it).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from gyrolab.compensation import families as registry
from gyrolab.compensation.band import PredictionBand, fit_band
from gyrolab.compensation.baselines import blocked_folds
from gyrolab.compensation.drift_model import (
    TIE,
    Candidate,
    CausalCalibration,
    DriftModel,
    FitContext,
)

CV_FOLDS, CV_SEGMENTS = 5, 10  # blocked CV: segment b in fold b mod 5 (docstring)


def fit_causal(
    cal: CausalCalibration,
    *,
    families: tuple[str, ...] | None = None,
    config: Any = None,
    seed: int = 0,
) -> DriftModel:
    """Fit every family in ``families`` (default: ``config.causal_families``) on the
    calibration run, score each by blocked 5-fold CV RMSE inside it, and return the
    winner refitted on the whole run (module docstring), with its selection record
    (``cv_rmse``, ``selection``, ``alternatives``: every family fitted). ``config``: the
    :class:`~gyrolab.compensation.config.PipelineConfig` (default: the defaults)."""
    if config is None:
        from gyrolab.compensation.config import DEFAULT_CONFIG

        config = DEFAULT_CONFIG
    names = config.causal_families if families is None else families
    chosen = [registry.family(n) for n in dict.fromkeys(names)]
    if not chosen:
        raise ValueError("no causal drift-model family to fit (causal_families is empty)")
    y = np.asarray(cal.rate, dtype=float)
    ctx = FitContext(cal, blocked_folds(y.size, CV_FOLDS, CV_SEGMENTS), seed, config)
    selection: dict[str, Any] = {
        "method": f"blocked {CV_FOLDS}-fold CV in time ({CV_SEGMENTS} segments)"
    }
    fitted: dict[str, Candidate] = {}
    for fam in sorted(chosen, key=lambda f: (f.rank, f.name)):  # simplest first
        c = fam.fit(ctx)
        fitted[fam.name] = c
        if c.log is not None:
            selection[fam.name] = c.log
    order = list(fitted)
    win = order[0]
    for f in order[1:]:
        if fitted[f].cv_rmse < fitted[win].cv_rmse * (1.0 - TIE):
            win = f
    selection["winner"] = win
    model = fitted[win].model
    model.cv_rmse = {f: c.cv_rmse for f, c in fitted.items()}
    model.selection = selection
    model.alternatives = {f: c.model for f, c in fitted.items()}
    pred = fitted[win].cv_pred
    if pred is not None:  # the winner's 90 % band, from its own held-out predictions
        model.band = fit_band(
            cal.t, y, pred, ctx.folds, cal.pt_t, cal.pt_c, power_ons=tuple(cal.power_ons)
        )
    return model


def family_models(m: DriftModel) -> dict[str, DriftModel]:
    """Every fitted family of a selection (for side-by-side evaluation); empty for a
    model loaded from disk."""
    return dict(m.alternatives)


def causal_state(m: DriftModel, prefix: str) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """model.json's ``causal_model`` (the family's description and what it saves) and
    the arrays (names starting with ``prefix``)."""
    meta = m.describe()
    extra, arrays = m.save(prefix)
    meta.update(extra)
    return meta, arrays


def causal_from_state(
    meta: dict[str, Any], arrays: dict[str, np.ndarray], prefix: str
) -> DriftModel:
    """The model :func:`causal_state` wrote, loaded by the family it names, with its
    selection record."""
    m = registry.family(str(meta["family"])).load(meta, arrays, prefix)
    m.cv_rmse = {k: float(v) for k, v in meta.get("cv_rmse_deg_per_s", {}).items()}
    m.selection = dict(meta.get("selection", {}))
    m.band = PredictionBand.from_dict(meta["band"]) if meta.get("band") else None
    return m


__all__ = [
    "CV_FOLDS",
    "CV_SEGMENTS",
    "CausalCalibration",
    "causal_from_state",
    "causal_state",
    "family_models",
    "fit_causal",
]
