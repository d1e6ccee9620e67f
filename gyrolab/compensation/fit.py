"""Fit the paper's hybrid compensation model on a calibration run (:func:`fit`).

The paper's parallel model (§3.5, Fig. 7), as gyrolab runs it:

1. **Decimate** (:mod:`gyrolab.compensation.prepare`). The rate is averaged to the paper's
   1000 points/h (``block_s`` = 3.6 s); the drift model's input at each block centre is the
   last PT100 reading (causal). Everything below runs at that rate.
2. **GPSO-VMD** (§3.1–3.2) chooses (K, α) and decomposes the averaged rate into K modes.
3. **MPE** (§3.4, scale 12) classifies the modes: high entropy = *noise*, middle = *mixed*,
   low = *drift* (thresholds of :func:`gyrolab.compensation.mpe.classify_modes`; when no
   mode falls below the drift threshold, the most regular mode is taken as the drift).
4. **Noise** modes are dropped; **mixed** modes are filtered by the forward linear
   predictor (FLP); **drift** modes are summed into the drift target ``d(t)``.
5. **GA-BP** (§3.3) learns ``d ≈ f(T)`` (optionally ``f(T, dT/dt)``) from the PT100
   temperature.
6. Output: ``y = FLP(mixed) + (drift − f(T))`` (the reconstruction of §3.5 step 3,
   :func:`gyrolab.compensation.apply.compensate_offline`).

Baselines, fitted on the same calibration run and applied the same causal way:
``poly`` (polynomial in T, order by blocked CV) and ``bp`` (plain BP, random initial
weights), both fitted directly on the averaged raw output (the classical approach, no
decomposition). Beside them the causal headline model (:mod:`gyrolab.compensation.causal`,
:func:`fit_causal_model`).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gyrolab.compensation.causal import fit_causal
from gyrolab.compensation.config import DEFAULT_CONFIG, PipelineConfig
from gyrolab.compensation.drift_model import CausalCalibration, DriftModel, join_calibrations
from gyrolab.compensation.fitness import search_vmd_parameters
from gyrolab.compensation.flp import ForwardLinearPredictor
from gyrolab.compensation.guards import calibration_ranges
from gyrolab.compensation.mpe import classify_modes, mean_mpe
from gyrolab.compensation.prepare import PreparedRun
from gyrolab.compensation.temperature_model import TemperatureModel, fit_temperature_model
from gyrolab.compensation.vmd import vmd
from gyrolab.errors import InputError


@dataclass
class Decomposition:
    """VMD modes at 1000 points/h with their MPE values and classes."""

    K: int
    alpha: float
    modes: np.ndarray  # (K, N), °/s
    omega: np.ndarray  # (K,), cycles/sample
    mpe: np.ndarray  # (K,), mean MPE over scales 1..mpe_scale, in [0, 1]
    classes: dict[str, list[int]]
    history: dict[str, np.ndarray] = field(default_factory=dict)

    def part(self, name: str) -> np.ndarray:
        idx = self.classes.get(name, [])
        if not idx:
            return np.zeros(self.modes.shape[1])
        return self.modes[idx].sum(axis=0)


def _vmd_fixed(x: np.ndarray, K: int, alpha: float) -> tuple[np.ndarray, np.ndarray]:
    r = vmd(x, alpha=alpha, K=K)
    return r.modes, r.omega


def _gpso_vmd(
    x: np.ndarray, cfg: PipelineConfig, seed: int
) -> tuple[int, float, dict[str, np.ndarray]]:
    """GPSO search of (K, α) in the paper's box (fitness.py's default criterion); returns
    the choice and the swarm history (every evaluated position and its fitness)."""
    s = search_vmd_parameters(
        x,
        criterion=cfg.vmd_fitness,
        K_bounds=cfg.k_range,
        alpha_bounds=cfg.alpha_range,
        population=cfg.gpso_population,
        generations=cfg.gpso_generations,
        seed=seed,
    )
    g = s.gpso
    history = {
        "best_fitness": g.best_history,
        "best_position": g.best_position_history,
        "positions": g.positions,
        "fitness": g.fitness,
    }
    return s.K, s.alpha, history


def _classify(modes: np.ndarray, cfg: PipelineConfig) -> tuple[np.ndarray, dict[str, list[int]]]:
    """Mean MPE over scales 1..``mpe_scale`` per mode and the threshold classes (mpe.py)."""
    values = mean_mpe(modes, scales=cfg.mpe_scale, order=cfg.mpe_order, delay=cfg.mpe_delay)
    classes = classify_modes(values, cfg.mpe_noise_min, cfg.mpe_drift_max)
    if not classes["drift"]:
        # The temperature drift is always the most regular thing in the run; when the noise
        # riding on it keeps every mode above drift_max, the most regular mode is the drift.
        k = int(np.argmin(values))
        for name in ("noise", "mixed"):
            if k in classes[name]:
                classes[name].remove(k)
        classes["drift"] = [k]
    return values, classes


def fit_flp(x: np.ndarray, cfg: PipelineConfig) -> ForwardLinearPredictor:
    """Forward linear predictor fitted on ``x`` (Burg, order by ``flp_criterion``)."""
    return ForwardLinearPredictor(max_order=cfg.flp_max_order, criterion=cfg.flp_criterion).fit(x)


def decompose(
    x: np.ndarray, cfg: PipelineConfig, seed: int, K: int | None = None, alpha: float | None = None
) -> Decomposition:
    """GPSO-VMD (or VMD at a given (K, α)) + MPE classes of the averaged rate ``x``."""
    history: dict[str, np.ndarray] = {}
    if K is None or alpha is None:
        K, alpha = cfg.vmd_K, cfg.vmd_alpha
    if K is None or alpha is None:
        K, alpha, history = _gpso_vmd(x, cfg, seed)
    modes, omega = _vmd_fixed(x, int(K), float(alpha))
    mpe, classes = _classify(modes, cfg)
    return Decomposition(int(K), float(alpha), modes, omega, mpe, classes, history)


# ------------------------------------------------------------------------ the model


@dataclass
class CompensationModel:
    """What ``gyrolab compensate`` fits and ``gyrolab apply`` uses: the paper's drift
    model ``drift`` (f(T) in the hybrid reconstruction), the baselines, the decomposition
    settings, and the causal headline model ``causal`` — each drift model a
    :class:`~gyrolab.compensation.drift_model.DriftModel`."""

    config: PipelineConfig
    drift: TemperatureModel
    baselines: dict[str, TemperatureModel]
    K: int
    alpha: float
    calibration: dict[str, Any]
    flp_mixed: ForwardLinearPredictor | None = None  # the mixed modes (None: no mixed mode)
    flp_stream: ForwardLinearPredictor | None = None  # the causal drift-compensated series
    diagnostics: dict[str, np.ndarray] = field(default_factory=dict)
    decomposition_info: dict[str, Any] = field(default_factory=dict)
    timing_s: dict[str, float] = field(default_factory=dict)
    causal: DriftModel | None = None  # the causal headline model (causal.py)
    seed: int | None = None  # None: a model written before the seed was recorded

    def drift_model(self, which: str) -> DriftModel:
        """The drift model of one causal output: ``causal`` (the headline), ``gabp`` (the
        paper's drift model, whatever ``drift_model`` fitted it), a baseline's name, or
        ``chosen`` (:meth:`headline`)."""
        if which == "chosen":
            return self.headline()
        if which == "causal":
            if self.causal is None:
                raise ValueError("model has no causal drift model (an older fit)")
            return self.causal
        if which == "gabp":
            return self.drift
        try:
            return self.baselines[which]
        except KeyError:
            raise ValueError(f"model has no {which!r} drift model") from None

    def headline(self) -> DriftModel:
        """What ``apply`` writes and ``export`` exports by default: the causal model, or
        the paper's drift model for a model fitted before there was one."""
        return self.causal if self.causal is not None else self.drift


def causal_calibration(run: PreparedRun, also: Sequence[PreparedRun] = ()) -> CausalCalibration:
    """What the causal model is fitted on: the run's block means and PT100 readings, and
    those of the ``also`` runs (each from its own power-on) joined after it
    (:func:`~gyrolab.compensation.drift_model.join_calibrations`)."""
    parts = [
        CausalCalibration(t=r.t, rate=r.rate, pt_t=r.pt_t, pt_c=r.pt_c) for r in (run, *also)
    ]
    return parts[0] if len(parts) == 1 else join_calibrations(parts)


def fit_causal_model(
    run: PreparedRun, cfg: PipelineConfig, seed: int = 0, also: Sequence[PreparedRun] = ()
) -> DriftModel:
    """The causal drift model (:func:`gyrolab.compensation.causal.fit_causal`): every family
    of ``cfg.causal_families``, the winner by CV inside ``run`` (and the ``also`` runs:
    :func:`causal_calibration`)."""
    return fit_causal(causal_calibration(run, also), config=cfg, seed=seed)


def fit_prior_model(run: PreparedRun, prior: Any) -> DriftModel:
    """The causal model as the MAP fit towards a fleet prior (:mod:`.prior`); a unit
    outside the prior is an :class:`InputError` asking for the full profile."""
    from gyrolab.compensation.prior import fit_map

    got = fit_map(causal_calibration(run), prior)
    if not got.membership.belongs:
        raise InputError(run.path, got.membership.message())
    return got.model


def fit_drift_model(
    X: np.ndarray, drift: np.ndarray, cfg: PipelineConfig, seed: int
) -> TemperatureModel:
    """The drift model ``f`` of ``cfg.drift_model`` fitted to ``drift ≈ f(X)``: the paper's
    GA-BP, plain BP (random initial weights) or the polynomial of :mod:`.baselines`
    (:data:`gyrolab.compensation.temperature_model.FITS`)."""
    return fit_temperature_model(cfg.drift_model, X, drift, cfg, seed)


def fit(
    run: PreparedRun,
    cfg: PipelineConfig = DEFAULT_CONFIG,
    seed: int = 0,
    prior: Any = None,
    also: Sequence[PreparedRun] = (),
) -> tuple[CompensationModel, Decomposition]:
    """Fit the hybrid model (and the baselines) on a prepared calibration run; with a
    fleet prior (:class:`~gyrolab.compensation.prior.FleetPrior`) the causal model is its
    MAP fit, and a unit that does not belong to the prior is refused (one line: calibrate
    it on the full profile). ``also``: further runs of the unit, each from its own
    power-on, that the causal model is fitted on beside ``run`` (model.json's
    ``calibration.also``); the calibrated ranges stay ``run``'s, the one range every
    output of the model shares."""
    import torch  # heavy: imported only when a model is fitted

    span = float(np.ptp(run.temp))
    if span < cfg.min_temp_span_c:
        raise InputError(
            run.path,
            f"temperature spans only {span:.2f} °C; fitting a temperature model needs a "
            f"sweep of at least {cfg.min_temp_span_c} °C",
        )
    torch.manual_seed(seed)
    timing: dict[str, float] = {}
    t0 = time.perf_counter()
    dec = decompose(run.rate, cfg, seed)
    timing["gpso_vmd_mpe"] = time.perf_counter() - t0
    drift = dec.part("drift")
    if not dec.classes.get("drift"):
        raise InputError(run.path, "no VMD mode was classified as drift: nothing to model")
    t1 = time.perf_counter()
    gabp = fit_drift_model(run.X, drift, cfg, seed)
    timing["gabp"] = time.perf_counter() - t1
    t2 = time.perf_counter()
    # the classical approach: fitted on the raw rate, no decomposition
    baselines = {
        name: fit_temperature_model(name, run.X, run.rate, cfg, seed)
        for name in dict.fromkeys(cfg.baselines)
    }
    timing["baselines"] = time.perf_counter() - t2
    t3 = time.perf_counter()
    if prior is None:
        causal = fit_causal_model(run, cfg, seed, also)
    else:
        causal = fit_prior_model(run, prior)
    timing["causal"] = time.perf_counter() - t3
    mixed = dec.part("mixed")
    flp_mixed = fit_flp(mixed, cfg) if dec.classes.get("mixed") else None
    flp_stream = fit_flp(run.rate - gabp.predict(run.X), cfg)
    diagnostics = {
        "calib_t": run.t,
        "calib_rate": run.rate,
        "calib_temp": run.temp,
        "calib_X": run.X,
        "calib_modes": dec.modes,
        "calib_omega": dec.omega,
        "calib_mpe": dec.mpe,
        "drift_target": drift,
        "drift_fit": gabp.predict(run.X),
    }
    for k, v in dec.history.items():
        diagnostics[f"gpso_{k}"] = np.asarray(v)
    model = CompensationModel(
        config=cfg,
        drift=gabp,
        baselines=baselines,
        K=dec.K,
        alpha=dec.alpha,
        calibration={
            "path": run.name,
            **_run_size(run, cfg),
            **calibration_ranges(run, cfg.dtdt_window_s),
            "raw_rate_hz": 1.0 / run.raw_period,
            "filled_blocks": run.filled_blocks,
            "content_hash": run.content_hash,
            # the model's input: the PT100 or the unit's internal sensor (guards.source_check)
            "temperature_source": run.temperature_source,
            # the unit it was fitted on, as its recording names it (guards.unit_check)
            **({"unit_serial": run.serial} if run.serial else {}),
            # the causal model's further runs, each from its own power-on (--also)
            **({"also": [_run_entry(a, cfg) for a in also]} if also else {}),
        },
        flp_mixed=flp_mixed,
        flp_stream=flp_stream,
        diagnostics=diagnostics,
        decomposition_info={"classes": dec.classes, "mpe": dec.mpe.tolist()},
        timing_s=timing,
        causal=causal,
        seed=int(seed),
    )
    return model, dec


def _run_size(run: PreparedRun, cfg: PipelineConfig) -> dict[str, Any]:
    """model.json's size of a calibration run: its blocks and its length (s)."""
    return {
        "n_points": int(run.t.size),
        "duration_s": float(run.t[-1] - run.t[0] + cfg.block_s),
    }


def _run_entry(run: PreparedRun, cfg: PipelineConfig) -> dict[str, Any]:
    """model.json's record of one ``also`` run: its name, size, length and content hash."""
    return {"path": run.name, **_run_size(run, cfg), "content_hash": run.content_hash}
