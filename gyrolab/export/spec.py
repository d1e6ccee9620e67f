"""The exported model: a versioned, self-contained JSON description of a fitted model.

``gyrolab export MODEL_DIR --format json`` writes it; the C exporter (:mod:`.c_code`) is
generated from it, so what the JSON says is what the C computes. Schema
``gyrolab.export`` version 1 (docs/export.md has the full reference)::

    {
      "format": "gyrolab.export", "format_version": 1,
      "software_version": ..., "created_utc": ..., "model_dir": ...,
      "units": {"rate": "deg/s", "temperature": "degC", "time": "s"},
      "correction": "y(t) = raw(t) - f(inputs(t))",
      "temperature_input": "zero-order hold: the last temperature reading at or before t",
      "axes": [{"axis": "x", "calibration_range_c": [lo, hi], "model": MODEL}, ...]
    }

``MODEL`` is one of

* ``{"kind": "mlp", "inputs": ["T"] | ["T", "dTdt"], "dtdt_window_s", "hidden",
  "x_mean", "x_std", "x_min", "x_max", "W" (inputs × hidden), "a" (hidden), "w" (hidden),
  "b", "y_mean", "y_std"}`` — the eq. 15–17 network of GA-BP / BP:
  ``f = y_std·(Σ_h w_h σ(Σ_i W_ih z_i + a_h) + b + Σ_i g_i (x_i − c_i)/x_std_i) + y_mean``
  with ``c = clip(x, x_min, x_max)``, ``z = (c − x_mean)/x_std``, σ the logistic function
  and ``g_i = Σ_h W_ih w_h σ_h (1 − σ_h)`` (linear continuation outside the calibrated
  range; inside it the last term is 0);
* ``{"kind": "legendre", "coef", "t_lo", "t_hi", "rate_coef" | null, "dtdt_window_s"}`` —
  the polynomial baseline ``Σ c_k P_k(u)`` (+ ``rate_coef``·dT/dt), ``u = (2T − lo − hi)/
  (hi − lo)``, *not* clamped (as the Python model);
* ``{"kind": "poly3", "coef" (c0..c3, deg/s), "t_ref", "t_min", "t_max"}`` — the firmware
  cubic, ``Σ c_k Δ^k``, ``Δ = clamp(T, t_min, t_max) − t_ref``;
* ``{"kind": "causal", "family", "features": {"tau_s", "rate_tau_min_s", "width_c",
  "warmup_tau_s"}, "model": INNER}`` — the causal model of
  :mod:`gyrolab.compensation.causal`: a state machine run at every temperature reading
  (:func:`causal_readings` states its equations) gives the features F (die temperature),
  R (its rate), S (hysteresis branch), E (warm-up); ``INNER`` maps them to the drift, held
  until the next reading: ``{"kind": "structured", "coef", "lo", "hi", "k", "h", "A",
  "kp", "k2", "hT"}`` (``Σ c_i L_i(u) + k R + h S + A E + kp max(R, 0) + k2 R|R| +
  hT S v``, ``u = (2F − lo − hi)/(hi − lo)``, ``v`` = u clipped to [−1, 1], the Legendre
  part continued linearly beyond u = ±1; ``kp``, ``k2``, ``hT`` absent = 0, in models
  written before issue 23) or an ``mlp`` with inputs ``["F", "R", "S", "E"]``.

dT/dt, when a model uses it, is ``(T(t) − T(t − w)) / w`` with both temperatures taken by
the same zero-order hold (the first reading when ``t − w`` precedes it).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from gyrolab import __version__
from gyrolab.errors import InputError

EXPORT_FORMAT = "gyrolab.export"
EXPORT_FORMAT_VERSION = 1
KINDS = ("chosen", "causal", "gabp", "bp", "poly", "poly3")


def _mlp_spec(m: Any, cfg: Any) -> dict[str, Any]:
    from gyrolab.compensation.gabp import unpack

    W, a, w, b = unpack(np.asarray(m.theta, dtype=float), m.n_in, m.hidden)
    if m.x_min is None or m.x_max is None:
        raise InputError(None, "network without a calibrated input range: refit the model")
    return {
        "kind": "mlp",
        "init": m.init,
        "inputs": ["T", "dTdt"][: m.n_in],
        "dtdt_window_s": float(cfg.dtdt_window_s) if m.n_in > 1 else None,
        "hidden": int(m.hidden),
        "x_mean": np.asarray(m.x_mean, dtype=float).tolist(),
        "x_std": np.asarray(m.x_std, dtype=float).tolist(),
        "x_min": np.asarray(m.x_min, dtype=float).tolist(),
        "x_max": np.asarray(m.x_max, dtype=float).tolist(),
        "W": W.tolist(),
        "a": a.tolist(),
        "w": w.tolist(),
        "b": float(b),
        "y_mean": float(m.y_mean),
        "y_std": float(m.y_std),
    }


def _legendre_spec(m: Any, cfg: Any) -> dict[str, Any]:
    return {
        "kind": "legendre",
        "coef": np.asarray(m.coef, dtype=float).tolist(),
        "t_lo": float(m.t_lo),
        "t_hi": float(m.t_hi),
        "rate_coef": m.rate_coef,
        "dtdt_window_s": float(cfg.dtdt_window_s) if m.rate_coef is not None else None,
    }


def _causal_spec(c: Any, cfg: Any) -> dict[str, Any]:
    """A :class:`gyrolab.compensation.causal.CausalDriftModel` (read by attribute, so this
    module does not depend on the causal module's presence)."""
    from gyrolab.compensation.gabp import MLPDriftModel

    inner = c.model
    if isinstance(inner, MLPDriftModel):
        m = _mlp_spec(inner, cfg)
        m["inputs"], m["dtdt_window_s"] = ["F", "R", "S", "E"][: inner.n_in], None
    else:
        m = {
            "kind": "structured",
            "coef": np.asarray(inner.coef, dtype=float).tolist(),
            "lo": float(inner.lo),
            "hi": float(inner.hi),
            "k": float(inner.k),
            "h": float(inner.h),
            "A": float(inner.A),
            "kp": float(getattr(inner, "kp", 0.0)),
            "k2": float(getattr(inner, "k2", 0.0)),
            "hT": float(getattr(inner, "hT", 0.0)),
        }
    p = c.params
    return {
        "kind": "causal",
        "family": str(c.family),
        "features": {
            "tau_s": float(p.tau_s),
            "rate_tau_min_s": float(p.rate_tau_min_s),
            "width_c": float(p.width_c),
            "warmup_tau_s": float(p.warmup_tau_s),
        },
        "model": m,
    }


def model_spec(model_dir: Path, kind: str = "chosen") -> dict[str, Any]:
    """The ``MODEL`` entry of one axis: ``kind`` ``chosen`` (the causal model when the
    directory has one, else GA-BP), ``causal``, ``gabp``, ``bp`` or ``poly`` (the
    baselines) or ``poly3`` (the firmware cubic)."""
    from gyrolab.compensation.axes import load_poly3
    from gyrolab.compensation.baselines import PolyDriftModel
    from gyrolab.compensation.gabp import MLPDriftModel
    from gyrolab.compensation.model_dir import load_model

    if kind == "poly3":
        p3 = load_poly3(model_dir)
        return {
            "kind": "poly3",
            "coef": list(p3.coef),
            "t_ref": p3.t_ref,
            "t_min": p3.t_min,
            "t_max": p3.t_max,
        }
    model = load_model(str(model_dir))
    causal = getattr(model, "causal", None)
    if kind == "chosen":
        kind = "causal" if causal is not None else "gabp"
    if kind == "causal":
        if causal is None:
            raise InputError(model_dir, "model has no causal drift model (an older fit)")
        return _causal_spec(causal, model.config)
    drift = model.drift if kind == "gabp" else model.baselines.get(kind)
    if drift is None:
        raise InputError(model_dir, f"model has no {kind!r} drift model")
    if isinstance(drift, MLPDriftModel):
        return _mlp_spec(drift, model.config)
    if isinstance(drift, PolyDriftModel):
        return _legendre_spec(drift, model.config)
    # A drift model this exporter does not know (e.g. a newer causal structured model) is
    # refused rather than exported without its state.
    raise InputError(model_dir, f"export of a {type(drift).__name__} drift model is not supported")


def export_spec(model_dir: str | Path, kind: str = "chosen") -> dict[str, Any]:
    """The whole JSON document for every axis of ``model_dir``."""
    from gyrolab.compensation.axes import axis_dirs
    from gyrolab.compensation.model_dir import load_model

    axes = []
    for name, d in axis_dirs(model_dir):
        cal = load_model(str(d)).calibration
        axes.append(
            {
                "axis": name,
                "calibration_range_c": [cal.get("temp_min_c"), cal.get("temp_max_c")],
                "calibration_run": cal.get("path"),
                "model": model_spec(d, kind),
            }
        )
    return {
        "format": EXPORT_FORMAT,
        "format_version": EXPORT_FORMAT_VERSION,
        "software_version": __version__,
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "model_dir": str(model_dir),
        "model_kind": kind,
        "units": {"rate": "deg/s", "temperature": "degC", "time": "s"},
        "correction": "y(t) = raw(t) - f(inputs(t))",
        "temperature_input": "zero-order hold: the last temperature reading at or before t "
        "(the first reading before it)",
        "axes": axes,
    }


# ------------------------------------------------------------ reference evaluation


def _sigmoid(z: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * z))


def evaluate_spec(model: dict[str, Any], X: np.ndarray) -> np.ndarray:
    """``f(inputs)`` of one axis's ``MODEL`` (float64), ``X`` = (N, n_inputs): the
    equations of the module docstring, independent of the fitting code (the test checks
    it against the fitted model)."""
    X = np.asarray(X, dtype=float)
    X = X[:, None] if X.ndim == 1 else X
    k = model["kind"]
    if k == "poly3":
        d = np.clip(X[:, 0], model["t_min"], model["t_max"]) - model["t_ref"]
        c = model["coef"]
        return c[0] + d * (c[1] + d * (c[2] + d * c[3]))
    if k == "legendre":
        u = (2.0 * X[:, 0] - (model["t_lo"] + model["t_hi"])) / (model["t_hi"] - model["t_lo"])
        y = np.polynomial.legendre.legval(u, model["coef"])
        if model["rate_coef"] is not None:
            y = y + model["rate_coef"] * X[:, 1]
        return y
    if k == "mlp":
        W, a, w = (np.asarray(model[n], dtype=float) for n in ("W", "a", "w"))
        xm, xs = np.asarray(model["x_mean"]), np.asarray(model["x_std"])
        c = np.clip(X, model["x_min"], model["x_max"])
        s = _sigmoid(((c - xm) / xs) @ W + a)
        y = s @ w + model["b"]
        g = (s * (1.0 - s) * w) @ W.T
        y = y + np.sum(g * (X - c) / xs, axis=1)
        return y * model["y_std"] + model["y_mean"]
    if k == "structured":
        lo, hi = model["lo"], model["hi"]
        u = (2.0 * X[:, 0] - (lo + hi)) / (hi - lo)
        uc = np.clip(u, -1.0, 1.0)
        c = np.asarray(model["coef"], dtype=float)
        y = np.polynomial.legendre.legval(uc, c)
        y = y + np.polynomial.legendre.legval(uc, np.polynomial.legendre.legder(c)) * (u - uc)
        y = y + model["k"] * X[:, 1] + model["h"] * X[:, 2] + model["A"] * X[:, 3]
        R = X[:, 1]
        return (
            y
            + model.get("kp", 0.0) * np.maximum(R, 0.0)
            + model.get("k2", 0.0) * R * np.abs(R)
            + model.get("hT", 0.0) * X[:, 2] * uc
        )
    raise ValueError(f"unknown model kind {k!r}")


def causal_readings(
    features: dict[str, float], pt_t: np.ndarray, pt_c: np.ndarray, t_power_on: float = 0.0
) -> np.ndarray:
    """The causal features ``(F, R, S, E)`` at every reading (float64, one reading at a
    time as firmware runs it). At rest at the first reading (``F = G = p = T_0``,
    ``t = t_0 − t_power_on``); then, with ``Δt`` the time since the previous reading,
    ``τ_r = max(τ, τ_min)``, ``w/2`` half the play width::

        F += a (T − F),  a = −expm1(−Δt/τ)  (1 when τ = 0)      die temperature
        G += b (T − G),  b = −expm1(−Δt/τ_r);  R = (T − G)/τ_r   rate
        p = min(max(p, F − w/2), F + w/2);     S = (F − p)/(w/2) hysteresis branch
        t += Δt;                               E = exp(−t/τ_w)    warm-up
    """
    import math

    tau, tmin = features["tau_s"], features["rate_tau_min_s"]
    tau_r, half, tau_w = max(tau, tmin), 0.5 * features["width_c"], features["warmup_tau_s"]
    out = np.empty((len(pt_c), 4))
    F = G = p = float(pt_c[0])
    t = float(pt_t[0]) - t_power_on
    prev = float(pt_t[0])
    for n, (tn, T) in enumerate(zip(pt_t, pt_c, strict=True)):
        dt = float(tn) - prev
        prev = float(tn)
        a = -math.expm1(-dt / tau) if tau > 0 else 1.0
        F += a * (T - F)
        G += -math.expm1(-dt / tau_r) * (T - G)
        p = min(max(p, F - half), F + half)
        t += dt
        out[n] = (F, (T - G) / tau_r, (F - p) / half, math.exp(-t / tau_w))
    return out


def evaluate_causal(model: dict[str, Any], pt_t: np.ndarray, pt_c: np.ndarray) -> np.ndarray:
    """Drift (°/s) at every reading of a ``causal`` ``MODEL`` (held until the next one)."""
    return evaluate_spec(model["model"], causal_readings(model["features"], pt_t, pt_c))
