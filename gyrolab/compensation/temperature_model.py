"""Drift models of the held temperature: the paper's f(T) (GA-BP, BP or polynomial, and
f(T, dT/dt) with ``use_dtdt``), the baselines and the firmware cubic.

:class:`TemperatureModel` puts a regressor behind the inputs of
:func:`temperature_inputs` — the last temperature reading at or before the sample
(zero-order hold) and, with a window ``w``, the backward difference ``(T(t) − T(t −
w)) / w`` (°C/s, both temperatures by the same hold; the first reading when ``t − w``
precedes it) — and implements the :class:`~gyrolab.compensation.drift_model.DriftModel`
interface on them. Regressors: :class:`~gyrolab.compensation.gabp.MLPDriftModel`
(GA-BP, BP), :class:`~gyrolab.compensation.baselines.PolyDriftModel` and the firmware
cubic :class:`~gyrolab.compensation.firmware.Poly3`; each has ``predict(X)`` and
``spec(...)`` (the forms of :mod:`gyrolab.compensation.regressors`).

The paper's drift-model slot (``PipelineConfig.drift_model``) and the baselines are fitted
by :data:`FITS`; a saved regressor is read back by its ``kind`` in model.json
(:data:`LOADERS`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gyrolab.compensation.baselines import PolyDriftModel, fit_plain_bp, fit_poly
from gyrolab.compensation.causal_features import hold
from gyrolab.compensation.drift_model import CModel, DriftModel, SpecKind
from gyrolab.compensation.gabp import MLPDriftModel, fit_gabp
from gyrolab.compensation.regressors import RANGE_RULES, c_function, evaluate_inputs


def temperature_inputs(
    t: np.ndarray, pt_t: np.ndarray, pt_c: np.ndarray, window_s: float | None
) -> np.ndarray:
    """Inputs at times ``t``: ``T`` (°C, the last reading at or before ``t``) and, with
    ``window_s`` = w, ``(T(t) − T(t − w)) / w`` (°C/s). Causal; ``(N, 1)`` or ``(N, 2)``."""
    T = hold(t, pt_t, pt_c)
    if window_s is None:
        return T[:, None]
    Tp = hold(t - window_s, pt_t, pt_c)
    return np.column_stack([T, (T - Tp) / window_s])


@dataclass
class TemperatureState:
    """The readings a sample may still need: the held one and those back to ``t − w``."""

    t: list[float] = field(default_factory=list)
    T: list[float] = field(default_factory=list)


@dataclass
class TemperatureModel(DriftModel):
    """``d(t) = f(inputs(t))``, ``f`` a regressor on :func:`temperature_inputs`.

    ``family``: how the regressor was fitted (``gabp``, ``bp``, ``poly``, ``poly3``);
    ``window_s``: the dT/dt window when ``f`` takes dT/dt (``None``: T only)."""

    regressor: Any  # MLPDriftModel | PolyDriftModel | Poly3: predict(X), spec(...)
    family: str = "gabp"
    window_s: float | None = None

    def predict(self, X: np.ndarray) -> np.ndarray:
        """``f`` at inputs ``X`` (N, 1 or 2) (°/s)."""
        return self.regressor.predict(X)

    # -- causal, reading by reading
    def start(self) -> TemperatureState:
        return TemperatureState()

    def reading(self, state: TemperatureState, t_s: float, temp_c: float) -> None:
        state.t.append(float(t_s))
        state.T.append(float(temp_c))
        if self.window_s is None:
            del state.t[:-1], state.T[:-1]
            return
        # the oldest goes once the next one is at or before t − w (samples come later)
        k = 0
        while k + 1 < len(state.t) and state.t[k + 1] <= t_s - self.window_s:
            k += 1
        del state.t[:k], state.T[:k]

    def sample(self, state: TemperatureState, t_s: float) -> float:
        T = state.T[-1]
        if self.window_s is None:
            x = np.array([[T]])
        else:
            Tp = state.T[0]
            for tk, Tk in zip(state.t, state.T, strict=True):
                if tk <= t_s - self.window_s:
                    Tp = Tk
            x = np.array([[T, (T - Tp) / self.window_s]])
        return float(self.regressor.predict(x)[0])

    # -- vectorised
    def reading_drift(self, pt_t: np.ndarray, pt_c: np.ndarray) -> np.ndarray | None:
        if self.window_s is not None:
            return None  # dT/dt changes between readings
        return self.regressor.predict(np.asarray(pt_c, dtype=float)[:, None])

    def drift_at(self, t: np.ndarray, pt_t: np.ndarray, pt_c: np.ndarray) -> np.ndarray:
        if self.window_s is None:
            return super().drift_at(t, pt_t, pt_c)
        return self.regressor.predict(temperature_inputs(t, pt_t, pt_c, self.window_s))

    # -- persistence (the regressor's own form: model.json's drift_model / baselines)
    def describe(self) -> dict[str, Any]:
        return self.save("")[0]

    def save(self, prefix: str) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        return self.regressor.to_state(prefix)

    def torch_state(self) -> dict[str, Any] | None:
        sd = getattr(self.regressor, "torch_state_dict", None)
        return None if sd is None else sd()

    # -- firmware
    def spec(self) -> dict[str, Any]:
        inputs = ["T"] if self.window_s is None else ["T", "dTdt"]
        return self.regressor.spec(inputs, self.window_s)


#: The paper's drift-model slot and the baselines: ``fit(X, y, cfg, seed)`` per name
#: (``PipelineConfig.drift_model``, ``PipelineConfig.baselines``).
FITS: dict[str, Callable[[np.ndarray, np.ndarray, Any, int], Any]] = {
    "gabp": lambda X, y, cfg, seed: fit_gabp(X, y, ga=cfg.ga(), bp=cfg.bp(), seed=seed),
    "bp": lambda X, y, cfg, seed: fit_plain_bp(X, y, bp=cfg.bp(), seed=seed),
    "poly": lambda X, y, cfg, seed: fit_poly(X, y),
}

#: A saved regressor by its model.json ``kind``.
LOADERS: dict[str, Callable[[dict[str, Any], dict[str, np.ndarray], str], Any]] = {
    "mlp": MLPDriftModel.from_state,
    "poly": PolyDriftModel.from_state,
}


def fit_temperature_model(
    name: str, X: np.ndarray, y: np.ndarray, cfg: Any, seed: int
) -> TemperatureModel:
    """``y ≈ f(X)`` by the fit ``name`` of :data:`FITS` on inputs ``X`` of
    :func:`temperature_inputs` (with dT/dt when ``cfg.use_dtdt``)."""
    try:
        fit = FITS[name]
    except KeyError:
        raise ValueError(f"drift_model must be one of {tuple(FITS)}, not {name!r}") from None
    window = float(cfg.dtdt_window_s) if cfg.use_dtdt else None
    return TemperatureModel(fit(X, y, cfg, seed), family=name, window_s=window)


def load_temperature_model(
    meta: dict[str, Any], arrays: dict[str, np.ndarray], prefix: str, cfg: Any, family: str
) -> TemperatureModel:
    """A regressor saved by :meth:`TemperatureModel.save` (its ``kind``: ``mlp`` or
    ``poly``) as the model fitted by ``family``, with the inputs of ``cfg`` (the model's
    pipeline configuration)."""
    try:
        load = LOADERS[meta["kind"]]
    except KeyError:
        raise ValueError(f"unknown drift model kind {meta['kind']!r}") from None
    reg = load(meta, arrays, prefix)
    window = float(cfg.dtdt_window_s) if cfg.use_dtdt else None
    return TemperatureModel(reg, family=family, window_s=window)


# ----------------------------------------------------------------- exported forms


def _evaluate(m: dict[str, Any], t: np.ndarray, pt_t: np.ndarray, pt_c: np.ndarray) -> np.ndarray:
    """The drift of an exported temperature model at sample times ``t`` (float64)."""
    return evaluate_inputs(m, temperature_inputs(t, pt_t, pt_c, m.get("dtdt_window_s")))


def _c_model(m: dict[str, Any], prefix: str) -> CModel:
    return CModel(
        code=c_function(f"{prefix}f", m),
        sample=f"return {prefix}f(x);",
        uses_temperature=True,
        window_s=m.get("dtdt_window_s"),
        note=RANGE_RULES[m["kind"]],
    )


#: The exported kinds: the network, the Legendre polynomial and the firmware cubic on T
#: (and dT/dt).
KINDS = tuple(SpecKind(k, _evaluate, _c_model) for k in ("mlp", "legendre", "poly3"))


__all__ = [
    "FITS",
    "KINDS",
    "LOADERS",
    "TemperatureModel",
    "fit_temperature_model",
    "load_temperature_model",
    "temperature_inputs",
]
