"""metrics.json of one application of a model (:func:`evaluate`, docs/cli.md keys; the
firmware cubic's cost beside it, :func:`add_firmware_metrics`).

Every series is compared at the paper's 1000 points/h (:func:`series_metrics`: the five
metrics of :func:`gyrolab.compensation.metrics.signal_metrics` on the 3.6 s averages, the
Allan curve stopped at T/10), the drift peak-to-peak also on 100 s averages
(:func:`drift_pp_table`, the same low-pass for every method), and the IEEE 952 noise terms
that the Allan curve identifies (:func:`series_noise_terms`). The causal outputs are
averaged to the same grid from the full rate
(:func:`gyrolab.compensation.apply.streaming_block_means_many`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from gyrolab.compensation.apply import Application, streaming_block_means_many
from gyrolab.compensation.band import band_metrics
from gyrolab.compensation.firmware import (
    FIRMWARES,
    UPDATE_RULES,
    Poly3,
    chosen_key,
    firmware_block_means,
    firmware_offset_fn,
)
from gyrolab.compensation.fit import CompensationModel
from gyrolab.compensation.guards import range_check
from gyrolab.compensation.metrics import signal_metrics
from gyrolab.compensation.prepare import PreparedRun
from gyrolab.numerics.allan import allan_deviation
from gyrolab.numerics.averaging import block_means
from gyrolab.numerics.noise_terms import noise_terms

DRIFT_PP_WINDOW_S = 100.0  # s; issue 11: p-p of 3.6 s averages is set by white noise


def series_metrics(x: np.ndarray, block_s: float) -> dict[str, float]:
    """The five metrics (docs/cli.md; :func:`gyrolab.compensation.metrics.signal_metrics`) of a
    series sampled every ``block_s`` seconds (°/s). Every series is compared at the paper's
    1000 points/h, so ``rms_deg_per_s`` is that of the 3.6 s averages, and bias stability
    and drift peak-to-peak are those of the series itself. The Allan curve behind ARW and
    bias instability stops at T/10."""
    # Octave taus up to T/10 only: beyond that an Allan point rests on a handful of
    # averages, and a long-tau stretch that happens to fall at slope -1/2 (drift residual
    # turning over) would otherwise be read as the ARW line and extrapolated to 1 s.
    m_max = max(2, x.size // 10)
    taus = block_s * 2.0 ** np.arange(int(np.log2(m_max)) + 1)
    allan = allan_deviation(x, 1.0 / block_s, taus=taus, confidence=None)
    return signal_metrics(
        x, 1.0 / block_s, stability_window_s=block_s, drift_window_s=block_s, allan=allan
    )


def series_noise_terms(x: np.ndarray, block_s: float) -> dict[str, Any]:
    """The IEEE 952 terms (Q, N, B, K, R) the Allan curve of a ``block_s`` series
    identifies — τ ≤ T/10 and slopes supported by the 1σ confidence intervals, B only at a
    floor (:func:`gyrolab.numerics.noise_terms.noise_terms`) — with the τ range of each and a
    reason for each term that is not identifiable (``None``)."""
    return noise_terms(allan_deviation(x, 1.0 / block_s, taus="octave")).to_dict()


def evaluate(
    model: CompensationModel, app: Application, run: PreparedRun, held_out: bool
) -> dict[str, Any]:
    """metrics.json content for one application (docs/cli.md keys plus diagnostics)."""
    bs = model.config.block_s
    m: dict[str, Any] = {"run": run.name, "held_out": bool(held_out)}
    for key in ("raw", "compensated", "compensated_drift_only", "compensated_streaming_flp"):
        m[key] = series_metrics(app.series[key], bs)
    whiches = ("gabp", "causal") if model.causal is not None else ("gabp",)
    # kept in the application (``stream.<which>``): the report's figures plot them
    # (gyrolab.compensation.results), and a second evaluate does not stream the file again
    todo = tuple(w for w in whiches if f"stream.{w}" not in app.series)
    if todo:
        new = streaming_block_means_many(model, run, todo)
        app.series.update({f"stream.{w}": s for w, s in new.items()})
    streams = {w: app.series[f"stream.{w}"] for w in whiches}
    m["compensated_streaming"] = series_metrics(streams["gabp"], bs)
    if model.causal is not None:
        causal_series = streams["causal"]
        m["causal"] = series_metrics(causal_series, bs)
        m["causal_model"] = model.causal.describe()
        m["headline"] = headline_info(model, run)
        m["headline"]["mean_bias_deg_per_h"] = mean_bias(causal_series)
        if model.causal.band is not None:
            m["causal_band"] = band_metrics(
                model.causal.band, run.t, causal_series, run.pt_t, run.pt_c
            )
        m["drift_pp_100s_deg_per_s"] = drift_pp_table(
            {
                "raw": app.series["raw"],
                "causal": causal_series,
                "compensated": app.series["compensated"],
                "compensated_drift_only": app.series["compensated_drift_only"],
                **{f"baselines.{n}": app.series[f"baselines.{n}"] for n in model.baselines},
            },
            bs,
        )
    m["baselines"] = {
        name: series_metrics(app.series[f"baselines.{name}"], bs) for name in model.baselines
    }
    m["baselines_with_noise_removal"] = {
        name: series_metrics(app.series[f"denoised_baselines.{name}"], bs)
        for name in model.baselines
    }
    dec = app.decomposition
    m["vmd"] = {"K": dec.K, "alpha": dec.alpha}
    m["imf_classes"] = dec.classes
    m["mpe_mean"] = [float(v) for v in dec.mpe]
    m["vmd_center_frequency_hz"] = [float(w) / bs for w in dec.omega]
    m["denoising"] = {
        "arw_with_noise_removal_deg_per_sqrt_h": m["compensated"]["arw_deg_per_sqrt_h"],
        "arw_without_noise_removal_deg_per_sqrt_h": m["compensated_drift_only"][
            "arw_deg_per_sqrt_h"
        ],
        "bandwidth": app.bandwidth,
        "raw_bandwidth_hz": 0.5 / run.raw_period,
        "flp": app.flp_info,
    }
    m["noise_terms"] = {
        key: series_noise_terms(x, bs)
        for key, x in (
            ("raw", app.series["raw"]),
            ("compensated", app.series["compensated"]),
            ("compensated_drift_only", app.series["compensated_drift_only"]),
            ("compensated_streaming", streams["gabp"]),
            *((("causal", streams["causal"]),) if "causal" in streams else ()),
        )
    }
    m["residual_mean_bias_deg_per_h"] = {
        "raw": mean_bias(app.series["raw"]),
        "compensated_drift_only": mean_bias(app.series["compensated_drift_only"]),
        "compensated_streaming": mean_bias(streams["gabp"]),
        **({"causal": mean_bias(streams["causal"])} if "causal" in streams else {}),
        **{f"baselines.{n}": mean_bias(app.series[f"baselines.{n}"]) for n in model.baselines},
    }
    rng = range_check(model.calibration, run)
    if rng:
        if "causal_band" in m:
            rng["expected_error"] = m["causal_band"]["expected_error"]
        m["temperature"] = rng
        m["baselines_extrapolation"] = baselines_extrapolation(model, rng)
    m["sample_period_s"] = bs
    m["n_points"] = int(run.t.size)
    return m


def mean_bias(x: np.ndarray) -> float:
    """Residual mean bias (°/h) of a 3.6 s series: 3600 × its mean — what a constant
    offset, aging or a wrong level of the drift model leaves (bias stability, a standard
    deviation, is blind to it)."""
    return float(np.mean(x) * 3600.0)


def baselines_extrapolation(model: CompensationModel, rng: dict[str, Any]) -> dict[str, Any]:
    """metrics.json ``baselines_extrapolation``: whether each baseline (a function of the
    measured temperature, and of dT/dt with ``use_dtdt``) is used beyond its calibrated
    input range on this run, by how much, and how it continues there."""
    how = {
        "poly": "its polynomial's own curve",
        "bp": "a linear continuation from the network's edge",
    }
    frac_t = float(rng.get("fraction_outside_calibration_beyond_margin", 0.0))
    frac_r = float(rng.get("fraction_rate_outside_calibration", 0.0))
    beyond = 0.0
    if "calibration_min_c" in rng:
        beyond = max(
            0.0,
            rng["calibration_min_c"] - rng["min_c"],
            rng["max_c"] - rng["calibration_max_c"],
        )
    out: dict[str, Any] = {}
    for name in model.baselines:
        rate_in = bool(model.config.use_dtdt)
        ext = frac_t > 0 or (rate_in and frac_r > 0)
        out[name] = {
            "extrapolating": bool(ext),
            "fraction_outside_temperature": frac_t,
            "max_beyond_c": float(beyond),
            **({"fraction_outside_rate": frac_r} if rate_in else {}),
            "continues_with": how.get(name, "its own form"),
        }
    return out


def drift_pp_table(
    series: dict[str, np.ndarray], block_s: float, window_s: float = DRIFT_PP_WINDOW_S
) -> dict[str, float]:
    """Peak-to-peak (°/s) of every series after averaging it over ``window_s`` windows
    (whole 3.6 s blocks: 28 → 100.8 s) — the same low-pass for every method."""
    return {
        k: float(np.ptp(block_means(np.asarray(v, float), 1.0 / block_s, window_s)))
        for k, v in series.items()
    }


def headline_info(model: CompensationModel, run: PreparedRun) -> dict[str, Any]:
    """What the headline is: the causal full-bandwidth output, and the paper's offline
    method beside it with its bandwidth (metrics.json ``headline``)."""
    c = model.causal
    return {
        "output": "causal",
        "description": "raw(t) - d(t), d from PT100 readings at or before t (causal, "
        "full bandwidth)",
        "family": None if c is None else c.family,
        "bandwidth_hz": 0.5 / run.raw_period,
        "offline_method": "compensated (the paper's GPSO-VMD/MPE/FLP/GA-BP reconstruction, "
        "offline, low-passed: see denoising.bandwidth)",
        "metrics_window_s": model.config.block_s,
        "drift_pp_window_s": DRIFT_PP_WINDOW_S,
    }


def form_metrics(
    p3: Poly3, run: PreparedRun, block_s: float, metrics: dict[str, Any], form: str = "poly3"
) -> dict:
    """metrics.json ``firmware_<form>``: the cubic's causal residual on ``run`` under
    ``form``'s update rule (:func:`gyrolab.compensation.firmware.firmware_offset_fn`) and how
    much worse it is than the chosen causal output of ``metrics`` (:func:`chosen_key`):
    ratios > 1 mean the firmware leaves more."""
    key = chosen_key(metrics)
    chosen = metrics[key]
    m = series_metrics(
        firmware_block_means(firmware_offset_fn(p3, run, form), run, block_s), block_s
    )
    ratio = {
        f"{k}_ratio": (m[k] / chosen[k] if chosen.get(k) else float("nan"))
        for k in ("rms_deg_per_s", "drift_pp_deg_per_s", "bias_stability_deg_per_h")
    }
    out = {**m, "vs_chosen": {"chosen": key, **ratio}, "model": p3.to_dict()}
    if form != "poly3":
        out["update_rule"] = UPDATE_RULES[form]
    return out


def add_firmware_metrics(
    p3: Poly3 | None, run: PreparedRun, metrics: dict[str, Any], block_s: float | None = None
) -> None:
    """Add ``firmware_poly3`` (the form) and ``firmware_px4`` / ``firmware_ardupilot`` (each
    firmware's own update rule and arithmetic) to ``metrics`` for the model's firmware cubic
    (``None``: a model fitted before it existed; nothing is added). ``block_s`` defaults to
    the run's ``metrics["sample_period_s"]``."""
    if p3 is None:
        return
    if block_s is None:
        block_s = float(metrics["sample_period_s"])
    for form in ("poly3", *FIRMWARES):
        metrics[f"firmware_{form}"] = form_metrics(p3, run, block_s, metrics, form)
