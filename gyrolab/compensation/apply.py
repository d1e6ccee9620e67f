"""Apply a fitted compensation model (:mod:`gyrolab.compensation.fit`) to any run.

Applying a fitted model to a **new** run (held out) keeps what was learned — the drift
model ``f``, the decomposition settings (K, α), the class rule and the FLP coefficients
fitted on the calibration run's mixed modes — and re-runs the signal processing on the new
run's own samples: VMD with the stored (K, α), MPE classes by the same rule, the stored FLP
on its mixed modes. The temperature drift removed is always ``f(T_new(t))``: never
refitted on held-out data.

Two outputs come from every application:

* **offline** (:func:`compensate_offline`, the paper's method) at 1000 points/h — it
  low-passes the signal (noise modes dropped), so its ARW is *not* the sensor's noise
  density: :func:`effective_bandwidth` says which bandwidth it leaves;
* **streaming** (:class:`StreamingCompensator`, causal, full rate):
  ``y(t) = raw(t) − f(T(t⁻))`` where ``T(t⁻)`` is the last PT100 reading at or before
  ``t`` (zero-order hold) and dT/dt a backward difference — no future sample is used, so
  it can run on a live stream. It keeps the sensor's full bandwidth; ``gyrolab apply``
  writes it as ``/gyro/rate``.

``compensated_drift_only`` is the paper's GA-BP drift model applied the causal way (no
noise removal): the like-for-like comparison with the baselines.
``denoised_baselines.<name>`` puts each baseline drift model behind the paper's noise
removal instead of GA-BP: the like-for-like comparison with the paper's full method.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import signal

from gyrolab.compensation.drift_model import DriftModel
from gyrolab.compensation.fit import CompensationModel, Decomposition, decompose, fit_flp
from gyrolab.compensation.flp import ForwardLinearPredictor
from gyrolab.compensation.prepare import PreparedRun, run_rate_batches
from gyrolab.numerics.averaging import BlockAverager


@dataclass
class Application:
    """A model applied to one run, at 1000 points/h (``series``) plus diagnostics."""

    t: np.ndarray
    # raw, compensated, compensated_drift_only, baselines.*; evaluate adds stream.<which>
    series: dict[str, np.ndarray]
    decomposition: Decomposition
    flp_info: dict[str, Any]
    bandwidth: dict[str, float]


def run_flp(
    flp: ForwardLinearPredictor, x: np.ndarray, block_s: float
) -> tuple[np.ndarray, dict[str, Any]]:
    """Filter ``x`` from a fresh state with a fitted predictor; report what it did."""
    flp.reset()
    y = flp.filter(x)
    info = {
        "order": flp.order,
        "variance_in": float(np.var(x)),
        "variance_out": float(np.var(y)),
        "bandwidth_hz": float(flp.bandwidth_hz(1.0 / block_s)),
    }
    return y, info


def compensate_offline(
    model: CompensationModel,
    run: PreparedRun,
    dec: Decomposition | None = None,
) -> Application:
    """The paper's reconstruction on ``run`` (module docstring), plus the causal outputs of
    the drift-only model and the baselines averaged to the same rate."""
    cfg = model.config
    if dec is None:
        dec = decompose(run.rate, cfg, 0, K=model.K, alpha=model.alpha)
    mixed = dec.part("mixed")
    flp_info: dict[str, Any] = {}
    mixed_f = mixed
    if dec.classes.get("mixed"):
        # the calibration run's predictor; a run whose modes were all mixed-free at
        # calibration but not now gets one fitted on its own mixed modes (recorded)
        flp = model.flp_mixed if model.flp_mixed is not None else fit_flp(mixed, cfg)
        mixed_f, flp_info = run_flp(flp, mixed, cfg.block_s)
        flp_info["fitted_on"] = "calibration" if model.flp_mixed is not None else "this run"
    drift = dec.part("drift")
    pred = model.drift.predict(run.X)
    denoised = mixed_f + drift
    drift_only = run.rate - pred
    stream_flp, _ = run_flp(model.flp_stream, drift_only, cfg.block_s)
    series = {
        "raw": run.rate,
        "compensated": denoised - pred,
        "compensated_drift_only": drift_only,
        "compensated_streaming_flp": stream_flp,
        "denoised": denoised,
        "drift_prediction": pred,
    }
    for name, m in model.baselines.items():
        bpred = m.predict(run.X)
        series[f"baselines.{name}"] = run.rate - bpred
        # the paper's noise removal with this drift model instead of GA-BP: isolates what
        # the drift model itself contributes
        series[f"denoised_baselines.{name}"] = denoised - bpred
    return Application(
        t=run.t,
        series=series,
        decomposition=dec,
        flp_info=flp_info,
        bandwidth=effective_bandwidth(run.rate, denoised, cfg.block_s),
    )


class StreamingCompensator:
    """Causal full-rate compensation ``raw(t) − d(t)`` by one drift model (module
    docstring), block by block: ``comp(t, rate)`` for any run of samples in time order.

    A model whose drift changes only at readings (``DriftModel.reading_drift``: the
    causal families, f(T) without dT/dt) is evaluated once per PT100 reading and looked up
    per sample with one ``searchsorted``; otherwise (dT/dt changes through the ``t − w``
    lookup) it is evaluated per sample (``DriftModel.drift_at``)."""

    def __init__(self, model: DriftModel, pt_t: np.ndarray, pt_c: np.ndarray) -> None:
        self.model = model
        self.pt_t, self.pt_c = pt_t, pt_c
        self._at_reading = model.reading_drift(pt_t, pt_c)

    def drift(self, t: np.ndarray) -> np.ndarray:
        if self._at_reading is not None:
            i = np.searchsorted(self.pt_t, t, side="right") - 1
            return self._at_reading[np.clip(i, 0, None)]
        return self.model.drift_at(t, self.pt_t, self.pt_c)

    def __call__(self, t: np.ndarray, rate: np.ndarray) -> np.ndarray:
        out = np.empty(rate.size)
        chunk = 1 << 20  # bounded temporaries on long runs
        for s in range(0, rate.size, chunk):
            out[s : s + chunk] = rate[s : s + chunk] - self.drift(t[s : s + chunk])
        return out


def streaming_compensate(
    model: CompensationModel,
    t: np.ndarray,
    rate: np.ndarray,
    pt_t: np.ndarray,
    pt_c: np.ndarray,
    which: str = "gabp",
) -> np.ndarray:
    """:class:`StreamingCompensator` of ``model.drift_model(which)`` applied to whole
    arrays."""
    comp = StreamingCompensator(model.drift_model(which), pt_t, pt_c)
    return comp(t, np.asarray(rate, dtype=float))


def streaming_block_means(
    model: CompensationModel, run: PreparedRun, which: str = "gabp"
) -> np.ndarray:
    """The causal full-rate output averaged to the run's 1000 points/h grid: from the
    samples in memory, or by streaming the file again when the run was prepared from it.
    ``which``: ``gabp`` (the paper's drift model on T), a baseline name, or ``causal``."""
    return streaming_block_means_many(model, run, (which,))[which]


def streaming_block_means_many(
    model: CompensationModel, run: PreparedRun, whiches: tuple[str, ...]
) -> dict[str, np.ndarray]:
    """:func:`streaming_block_means` of several causal outputs in one pass over the run
    (one read of the file when the run was prepared from it)."""
    comps = {w: StreamingCompensator(model.drift_model(w), run.pt_t, run.pt_c) for w in whiches}
    accs = {w: BlockAverager(model.config.block_s) for w in whiches}
    if run.raw_rate is not None and run.raw_t is not None:
        batches: Iterable[tuple[np.ndarray, np.ndarray, float]] = [
            (run.raw_t, run.raw_rate, run.raw_period)
        ]
    else:
        batches = run_rate_batches(run)
    for t, x, period in batches:
        for w in whiches:
            accs[w].add(t, comps[w](t, x), period)
    return {w: accs[w].result()[1] for w in whiches}


def effective_bandwidth(raw: np.ndarray, filtered: np.ndarray, block_s: float) -> dict[str, float]:
    """Bandwidth the offline filtering leaves, from the estimated transfer function
    ``H(f) = P_xy(f) / P_xx(f)`` (Welch, raw x → filtered y, at 1000 points/h):

    * ``f3db_hz`` — the lowest frequency where ``|H|² < ½``;
    * ``enbw_hz`` — equivalent noise bandwidth ``∫₀^{f_N} |H|² df`` (white noise of
      density S leaves the filter with variance S·ENBW);
    * ``nyquist_hz`` — ``1 / (2 block_s)``, what 1000 points/h alone keeps."""
    nper = int(min(1024, max(16, raw.size // 8)))
    f, pxx = signal.welch(raw, fs=1.0 / block_s, nperseg=nper, detrend="linear")
    _, pxy = signal.csd(raw, filtered, fs=1.0 / block_s, nperseg=nper, detrend="linear")
    h2 = np.abs(pxy / np.where(pxx > 0, pxx, np.inf)) ** 2
    h2 = np.minimum(h2, 1.0)
    below = np.flatnonzero((h2 < 0.5) & (f > 0))
    f3 = float(f[below[0]]) if below.size else float(f[-1])
    enbw = float(np.trapezoid(h2, f))
    return {"f3db_hz": f3, "enbw_hz": enbw, "nyquist_hz": 0.5 / block_s}
