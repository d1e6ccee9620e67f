"""The hard validation suite (issue 11): causal compensation held out across trajectories.

    python benchmarks/validation_suite.py [--units 12] [--workers 2] [--rate 10]
                                          [--out docs/results.md] [--json FILE] [--quick]

**Units.** A Monte-Carlo family of simulated gyros, unit ``u`` drawn from
``default_rng([2026, u])`` around the nominal model (:func:`unit_model`): polynomial
coefficients c0…c3 dispersed, thermal lag τ ~ U(0, 1200 s), hysteresis h ~ U(0, 3e-3 °/s)
with width U(0.5, 2 °C), thermal-rate sensitivity k ~ U(−3e-3, 3e-3) °/s per °C/min,
warm-up A ~ U(−6e-3, 6e-3) °/s with τ_w ~ U(300, 1200 s), bias-instability floor
B ~ U(0.15, 0.45) °/h, ARW N = 0.0523 · U(0.8, 1.2) °/√h. Unit 0 is the nominal model
(the paper's simulator) with none of the extra effects.

**Trajectories** (all from power-on at 25 °C, the paper's chamber): ``paper`` (the
cooling staircase, 13 h), ``heating`` (it reversed), ``ramp0.5`` and ``ramp2`` (setpoint
ramps at ±0.5 and ±2 °C/min between −40 and 60 °C with soaks; the chamber's cooling limit
— 1.5 °C/min, less below 40 °C — caps the −2 °C/min ramp), ``random`` (random setpoints in
−40…60 °C held 20–90 min, per unit), ``soak`` (3 h soaks at four temperatures).

**Protocol.** Each unit is calibrated on its ``paper`` run only and evaluated on its five
other trajectories (never refitted). Methods, all causal except the paper's offline one:
the selected causal model (the headline, :mod:`gyrolab.compensation.causal`), each causal
family, the paper's GA-BP drift model on T applied causally, the paper's full offline
method (VMD at the nominal run's GPSO choice K = 11, α = 5000 — the GPSO search itself is
left out to keep the suite inside 15 min), and the **oracle**: the run minus its true
simulated deterministic drift (simulated separately with the same thermal history), the
floor no temperature model can go below.

**Rate.** Simulated at 10 Hz (not the recordings' 100 Hz): every metric is taken on 3.6 s
(36 samples) and 100 s averages, whose white-noise level depends only on the ARW
coefficient, not the sample rate; the PT100 is read at 1 Hz as on the bench.

**Metrics** per (unit, trajectory, method): bias stability (std of 3.6 s averages, °/h),
drift p-p of 100 s averages (28 blocks of 3.6 s = 100.8 s) and of 3.6 s averages (°/s).
Tables: median and mean ± sd over units, paired differences (causal − other) with their
mean ± sd, and the targets of issue 11 point 3.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from docsections import write_section  # noqa: E402

from gyrolab.compensation.evaluate import DRIFT_PP_WINDOW_S  # noqa: E402
from gyrolab.numerics.averaging import PAPER_BLOCK_S, block_means  # noqa: E402
from gyrolab.profiles.profile import BUILTIN, Profile, Step  # noqa: E402

TRAJECTORIES = ("paper", "heating", "ramp0.5", "ramp2", "random", "soak")
CALIBRATION = "paper"


# ----------------------------------------------------------------------- trajectories


def _ramp(start: float, end: float, rate_c_per_min: float, label: str) -> list[Step]:
    """A setpoint ramp as 30 s setpoint steps (what a controller's ramp mode does)."""
    n = max(1, int(round(abs(end - start) / abs(rate_c_per_min) * 2)))
    return [
        Step(start + (end - start) * (i + 1) / n, 30.0, f"{label} {i + 1}/{n}") for i in range(n)
    ]


def trajectory(name: str, unit: int) -> Profile:
    """The suite's temperature trajectories (module docstring)."""
    if name == "paper":
        return BUILTIN["paper"]
    if name == "heating":
        return BUILTIN["paper"].reversed("heating")
    if name in ("ramp0.5", "ramp2"):
        r = 0.5 if name == "ramp0.5" else 2.0
        steps = [Step(25.0, 3600.0, "power-on")]
        steps += _ramp(25.0, 60.0, r, "up") + [Step(60.0, 3600.0, "soak 60")]
        steps += _ramp(60.0, -40.0, r, "down") + [Step(-40.0, 3600.0, "soak -40")]
        steps += _ramp(-40.0, 60.0, r, "up") + [Step(60.0, 1800.0, "soak 60")]
        steps += _ramp(60.0, 25.0, r, "down") + [Step(25.0, 1800.0, "end")]
        return Profile(name, tuple(steps))
    if name == "random":
        rng = np.random.default_rng([77, unit])
        steps, total = [Step(25.0, 3600.0, "power-on")], 3600.0
        while total < 10 * 3600.0:
            d = float(rng.uniform(20, 90)) * 60.0
            steps.append(Step(float(np.round(rng.uniform(-40, 60), 1)), d, "random"))
            total += d
        return Profile(name, tuple(steps))
    if name == "soak":
        steps = [Step(25.0, 3600.0, "power-on")]
        steps += [Step(sp, 3 * 3600.0, f"soak {sp:g}") for sp in (60.0, 10.0, -30.0, 40.0)]
        return Profile(name, tuple(steps))
    raise ValueError(name)


# ----------------------------------------------------------------------------- units


def unit_model(unit: int):
    """Unit ``unit`` of the Monte-Carlo family (module docstring); 0 is nominal."""
    from gyrolab.sim.model import nominal_model

    m = nominal_model()
    if unit == 0:
        return m, {"nominal": True}
    rng = np.random.default_rng([2026, unit])
    p = {
        "c0": float(rng.uniform(-0.05, 0.05)),
        "c1": 3.84e-4 * float(rng.uniform(0.6, 1.4)),
        "c2": 3.4e-6 * float(rng.uniform(-1.5, 1.5)),
        "c3": float(rng.normal(0.0, 1.5e-8)),
        "lag_tau_s": float(rng.uniform(0.0, 1200.0)),
        "hyst_h": float(rng.uniform(0.0, 3e-3)),
        "hyst_width_c": float(rng.uniform(0.5, 2.0)),
        "rate_k": float(rng.uniform(-3e-3, 3e-3)),
        "warmup_A": float(rng.uniform(-6e-3, 6e-3)),
        "warmup_tau_s": float(rng.uniform(300.0, 1200.0)),
        "B": float(rng.uniform(0.15, 0.45)),
        "N": 0.0523 * float(rng.uniform(0.8, 1.2)),
    }
    m = m.with_effect("bias_poly", c0=p["c0"], c1=p["c1"], c2=p["c2"], c3=p["c3"])
    m = m.with_effect("arw", N=p["N"]).with_effect("bias_instability", B=p["B"])
    if p["lag_tau_s"] >= 1.0:
        m = m.with_effect("thermal_lag", tau_s=p["lag_tau_s"])
    m = m.with_effect("hysteresis", h=p["hyst_h"], width_c=p["hyst_width_c"])
    m = m.with_effect("thermal_rate", k=p["rate_k"])
    m = m.with_effect("warmup", A=p["warmup_A"], tau_s=p["warmup_tau_s"])
    return m, p


DETERMINISTIC = {"arw", "bias_instability", "rate_random_walk", "outliers", "quantization"}


def simulate(
    model, profile: Profile, rate_hz: float, seed: int, die_offset_c: float | None = None
) -> dict[str, np.ndarray]:
    """Run ``profile`` through :class:`~gyrolab.sim.physics.Physics` step by step (time
    rule only): the raw output as a bench converts it, the true deterministic drift (same
    model without its stochastic effects, same thermal history) and 1 Hz PT100 readings
    (CVD inverse of the case resistance plus the multimeter's noise). With
    ``die_offset_c`` (the unit's die-sensor offset, °C) also ``die_c``: the unit's
    internal (die) thermometer at the same 1 Hz (:class:`~gyrolab.sim.sensors.DieThermometer`,
    its register's resolution and noise)."""
    from gyrolab.pt100 import cvd_resistance, cvd_temperature
    from gyrolab.sim.noise import effect_rng
    from gyrolab.sim.physics import Physics

    det_model = model
    for e in model.effects:
        if e.name in DETERMINISTIC:
            det_model = det_model.without_effect(e.name)
    full = Physics(model, rate_hz=rate_hz, seed=seed, ambient_c=profile.ambient_c)
    det = Physics(det_model, rate_hz=rate_hz, seed=seed, ambient_c=profile.ambient_c)
    raw, drift, case, die = [], [], [], []
    for s in profile.steps:
        n = int(round(s.duration_s * rate_hz))
        full.set_setpoint(s.setpoint_c)
        det.set_setpoint(s.setpoint_c)
        b = full.advance(n)
        raw.append(full.adc.counts_to_dps(b.counts))
        drift.append(det.advance(n).rate_dps)
        case.append(b.case_trace)
        die.append(b.die_trace)
    raw_a, drift_a, case_a = (np.concatenate(x) for x in (raw, drift, case))
    t = np.arange(raw_a.size) / rate_hz
    step = int(round(rate_hz))  # PT100 at 1 Hz, read at the start of each second
    pt_t = t[::step]
    r = cvd_resistance(case_a[::step])
    r = r + model.sensors.dmm_noise_ohm * effect_rng(seed, "dmm").standard_normal(r.size)
    out = {"t": t, "raw": raw_a, "drift": drift_a, "pt_t": pt_t, "pt_c": cvd_temperature(r)}
    if die_offset_c is not None:
        from gyrolab.sim.sensors import DieThermometer

        d = np.concatenate(die)[::step]
        th = DieThermometer()
        w = np.random.default_rng([seed, 71]).standard_normal(d.size)
        out["die_c"] = th.to_celsius(th.codes(d, die_offset_c, w))
    return out


# ------------------------------------------------------------------------ evaluation


def _metrics(x: np.ndarray) -> dict[str, float]:
    """Bias stability (°/h) and drift p-p of 3.6 s and 100 s averages (°/s) of a 3.6 s
    block-mean series."""
    m100 = block_means(x, 1.0 / PAPER_BLOCK_S, DRIFT_PP_WINDOW_S)  # 28 blocks: 100.8 s
    return {
        "bias_stability_deg_per_h": float(np.std(x, ddof=1) * 3600.0),
        "drift_pp_100s_deg_per_s": float(np.ptp(m100)),
        "drift_pp_3p6s_deg_per_s": float(np.ptp(x)),
    }


def suite_config(quick: bool):
    from gyrolab.compensation.config import PipelineConfig

    cfg = PipelineConfig(vmd_K=11, vmd_alpha=5000.0)
    if quick:
        cfg = replace(cfg, ga_population=16, ga_generations=8, bp_max_iter=80, vmd_K=6)
    return cfg


def run_unit(unit: int, rate_hz: float, quick: bool) -> dict[str, Any]:
    """Simulate one unit on every trajectory, calibrate on ``paper``, evaluate the rest."""
    import torch

    from gyrolab.compensation.apply import compensate_offline
    from gyrolab.compensation.causal import family_models
    from gyrolab.compensation.fit import fit
    from gyrolab.compensation.prepare import prepare_arrays
    from gyrolab.numerics.averaging import block_average

    torch.set_num_threads(1)
    t0 = time.perf_counter()
    cfg = suite_config(quick)
    model, params = unit_model(unit)
    runs = {
        name: simulate(model, trajectory(name, unit), rate_hz, seed=1000 * unit + i + 1)
        for i, name in enumerate(TRAJECTORIES)
    }
    t_sim = time.perf_counter() - t0
    prep = {
        k: prepare_arrays(k, r["t"], r["raw"], 1.0 / rate_hz, r["pt_t"], r["pt_c"], cfg)
        for k, r in runs.items()
    }
    t1 = time.perf_counter()
    cm, dec = fit(prep[CALIBRATION], cfg, seed=unit)
    t_fit = time.perf_counter() - t1
    fams = family_models(cm.causal)
    bs = cfg.block_s
    out: dict[str, Any] = {
        "unit": unit,
        "params": params,
        "winner": cm.causal.family,
        "features": cm.causal.params.to_dict(),
        "structured": cm.causal.selection.get("structured", {}),
        "cv_rmse": cm.causal.cv_rmse,
        "runs": {},
    }
    for name, r in runs.items():
        run = prep[name]
        app = compensate_offline(cm, run, dec if name == CALIBRATION else None)

        def causal_means(c, r=r, run=run) -> np.ndarray:
            y = r["raw"] - c.drift_at(r["t"], run.pt_t, run.pt_c)
            return block_average(r["t"], y, bs, 1.0 / rate_hz)[1]

        series = {
            "raw": app.series["raw"],
            "oracle": block_average(r["t"], r["raw"] - r["drift"], bs, 1.0 / rate_hz)[1],
            "causal": causal_means(cm.causal),
            **{f"causal.{f}": causal_means(m) for f, m in fams.items()},
            "paper_gabp_T_causal": app.series["compensated_drift_only"],
            "paper_offline": app.series["compensated"],
        }
        n = min(v.size for v in series.values())
        out["runs"][name] = {k: _metrics(v[:n]) for k, v in series.items()}
        out["runs"][name]["_case_range_c"] = [float(run.pt_c.min()), float(run.pt_c.max())]
        out["runs"][name]["_max_case_rate_c_per_min"] = float(
            60.0 * np.max(np.abs(np.diff(run.temp))) / bs
        )
        out["runs"][name]["_offline_f3db_hz"] = app.bandwidth["f3db_hz"]
    out["timing_s"] = {
        "simulate": t_sim,
        "fit": t_fit,
        "total": time.perf_counter() - t0,
        "fit_breakdown": cm.timing_s,
    }
    print(
        f"unit {unit:2d}: winner {out['winner']:<10} τ={out['features']['tau_s']:.0f} s "
        f"(true {params.get('lag_tau_s', 0):.0f})  {out['timing_s']['total']:.0f} s",
        file=sys.stderr,
        flush=True,
    )
    return out


def rotation_check(rate_hz: float, quick: bool) -> dict[str, dict[str, float]]:
    """Issue 11 point 5: unit 0 (nominal) calibrated on its paper run; known rotations
    (:func:`gyrolab.compensation.rotation.rotation_events`, 2 h into the run) added to its
    held-out ``soak`` run; the share of each event's angle every output keeps."""
    import torch

    from gyrolab.compensation.apply import StreamingCompensator, compensate_offline
    from gyrolab.compensation.fit import fit
    from gyrolab.compensation.prepare import prepare_arrays
    from gyrolab.compensation.rotation import angle_kept, rotation_events

    torch.set_num_threads(1)
    cfg = suite_config(quick)
    model, _ = unit_model(0)
    cal = simulate(model, trajectory(CALIBRATION, 0), rate_hz, seed=1)
    static = simulate(model, trajectory("soak", 0), rate_hz, seed=6)
    per = 1.0 / rate_hz
    prep = prepare_arrays("cal", cal["t"], cal["raw"], per, cal["pt_t"], cal["pt_c"], cfg)
    cm, _ = fit(prep, cfg, seed=0)
    t, pt_t, pt_c = static["t"], static["pt_t"], static["pt_c"]
    comp = StreamingCompensator(cm.causal, pt_t, pt_c)

    def outputs(x: np.ndarray) -> dict[str, np.ndarray]:
        run = prepare_arrays("static", t, x, per, pt_t, pt_c, cfg)
        app = compensate_offline(cm, run)
        return {
            "causal": comp(t, x),
            "offline": app.series["compensated"],
            "stream_flp": app.series["compensated_streaming_flp"],
        }

    base = outputs(static["raw"])
    dts = {"causal": per, "offline": cfg.block_s, "stream_flp": cfg.block_s}
    out: dict[str, dict[str, float]] = {}
    for name, omega in rotation_events(t, t0=7200.0, seed=1).items():
        w = outputs(static["raw"] + omega)
        out[name] = {
            k: angle_kept(w[k], base[k], dts[k], omega, per)
            for k in ("causal", "offline", "stream_flp")
        }
        out[name]["angle_deg"] = float(np.sum(omega) * per)
    return out


def rotation_table(rot: dict[str, dict[str, float]]) -> str:
    L = [
        "### Rotation survives (issue 11, point 5)",
        "",
        "Nominal unit calibrated on its paper run; known rotations added 2 h into its held-out "
        "soak run (`gyrolab/compensation/rotation.py`). Share of the injected angle that each "
        "output keeps, integrated over the whole run:",
        "",
        "| event | angle ° | causal headline | paper's method, offline | GA-BP + causal FLP "
        "(3.6 s) |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    for name, r in rot.items():
        L.append(
            f"| {name} | {r['angle_deg']:.0f} | {100 * r['causal']:.4f} % | "
            f"{100 * r['offline']:.1f} % | {100 * r['stream_flp']:.1f} % |"
        )
    worst = max(abs(r["causal"] - 1.0) for r in rot.values())
    L.append("")
    L.append(
        f"Causal output: largest angle error {100 * worst:.2g} % (target ≤ 0.1 %: "
        f"{'**pass**' if worst <= 1e-3 else '**FAIL**'}) — the causal model reads only the "
        "PT100, so a rotation passes through untouched. The offline reconstruction drops the "
        "VMD noise modes and re-decomposes the run: what it keeps of a rotation depends on the "
        "event's spectrum; the FLP row predicts the output from its own past and removes "
        "whatever is unpredictable."
    )
    return "\n".join(L)


# -------------------------------------------------------------------------- tables

METHODS = [
    ("oracle", "oracle (true deterministic drift removed)"),
    ("causal", "**causal model, selected family** (headline)"),
    ("causal.structured", "causal structured (lagged poly + rate + hysteresis + warm-up)"),
    ("causal.gabp", "causal GA-BP on (F, R, S, E)"),
    ("causal.bp", "causal plain BP on (F, R, S, E)"),
    ("causal.poly", "causal polynomial in T (baseline)"),
    ("paper_gabp_T_causal", "paper's GA-BP on T, causal (the old headline)"),
    ("paper_offline", "paper's method, offline (VMD low-pass, f3dB {f3db})"),
    ("raw", "raw output"),
]


def _ms(v: np.ndarray, fmt: str = ".3g") -> str:
    return f"{np.mean(v):{fmt}} ± {np.std(v, ddof=1) if v.size > 1 else 0.0:{fmt}}"


def collect(results: list[dict[str, Any]], held: list[str]):
    """arrays[method][metric] of shape (units, held-out trajectories)."""
    keys = [k for k, _ in METHODS]
    metrics = ("bias_stability_deg_per_h", "drift_pp_100s_deg_per_s", "drift_pp_3p6s_deg_per_s")
    arr = {
        k: {m: np.array([[r["runs"][tr][k][m] for tr in held] for r in results]) for m in metrics}
        for k in keys
    }
    return arr


def tables(results: list[dict[str, Any]], meta: dict[str, Any]) -> str:
    held = [t for t in TRAJECTORIES if t != CALIBRATION]
    a = collect(results, held)
    f3 = [r["runs"][tr]["_offline_f3db_hz"] for r in results for tr in held]
    f3db = f"{1e3 * min(f3):.2f}–{1e3 * max(f3):.2f} mHz"
    bs, pp = "bias_stability_deg_per_h", "drift_pp_100s_deg_per_s"
    raw_bs, raw_pp = a["raw"][bs], a["raw"][pp]
    L: list[str] = []
    L.append(
        f"`python benchmarks/validation_suite.py` — {meta['date']}, {meta['machine']}, "
        f"{len(results)} units × {len(held)} held-out trajectories, simulated at "
        f"{meta['rate_hz']:g} Hz; wall clock {meta['wall_s']:.0f} s with {meta['workers']} "
        f"worker(s); load average {meta['load_before']} before, {meta['load_after']} after "
        f"(shared machine)."
    )
    L.append("")
    # targets
    ratio = a["causal"][bs] / a["oracle"][bs]
    cut = 1.0 - a["causal"][pp] / raw_pp
    unit_med_ratio = np.median(ratio, axis=1)
    unit_med_cut = np.median(cut, axis=1)
    worse = int(np.sum((a["causal"][bs] >= raw_bs) | (a["causal"][pp] >= raw_pp)))
    L.append("### Targets (issue 11, point 3), held out across trajectories")
    L.append("")
    L.append("| target | measured | verdict |")
    L.append("| --- | --- | --- |")
    med_ratio = float(np.median(unit_med_ratio))
    med_cut = float(np.median(unit_med_cut))
    L.append(
        f"| causal bias stability ≤ 1.15 × oracle (median over units of each unit's median "
        f"over its 5 held-out runs) | {med_ratio:.3f} × (all runs: median "
        f"{np.median(ratio):.3f}, worst {ratio.max():.2f}) | "
        f"{'**pass**' if med_ratio <= 1.15 else '**FAIL**'} |"
    )
    L.append(
        f"| drift p-p of 100 s averages cut ≥ 90 % (median over units) | {100 * med_cut:.1f} % "
        f"(all runs: median {100 * np.median(cut):.1f} %, worst {100 * cut.min():.1f} %) | "
        f"{'**pass**' if med_cut >= 0.9 else '**FAIL**'} |"
    )
    L.append(
        f"| no unit worse than raw (bias stability and 100 s p-p, every held-out run) | "
        f"{worse} of {cut.size} runs worse | {'**pass**' if worse == 0 else '**FAIL**'} |"
    )
    oracle_cut = 1.0 - a["oracle"][pp] / raw_pp
    L.append("")
    L.append(
        f"For scale: the oracle itself cuts the 100 s p-p by {100 * np.median(oracle_cut):.1f} % "
        f"(median), and its bias stability is {np.median(a['oracle'][bs]):.2f} °/h "
        f"(median) — white noise and the 1/f bias instability that no temperature model "
        f"removes."
    )
    L.append("")
    # main table
    L.append("### All methods, held out (mean ± sd over units of each unit's mean over runs)")
    L.append("")
    L.append(
        "| method | bias stability °/h | ÷ oracle (median) | drift p-p 100 s, °/s | cut "
        "(median) | drift p-p 3.6 s, °/s |"
    )
    L.append("| --- | ---: | ---: | ---: | ---: | ---: |")
    for k, label in METHODS:
        b = a[k][bs].mean(axis=1)
        p = a[k][pp].mean(axis=1)
        p3 = a[k]["drift_pp_3p6s_deg_per_s"].mean(axis=1)
        r_ = np.median(a[k][bs] / a["oracle"][bs])
        c_ = np.median(1.0 - a[k][pp] / raw_pp)
        L.append(
            f"| {label.format(f3db=f3db)} | {_ms(b)} | {r_:.3f} | {_ms(p)} | "
            f"{'—' if k == 'raw' else f'{100 * c_:.1f} %'} | {_ms(p3)} |"
        )
    L.append("")
    # per trajectory
    L.append("### Per held-out trajectory (median over units)")
    L.append("")
    L.append(
        "| trajectory | case range °C | max case rate °C/min | raw BS °/h | oracle BS | causal BS "
        "| causal ÷ oracle | poly(T) ÷ oracle | paper GA-BP(T) ÷ oracle | causal 100 s p-p cut |"
    )
    L.append("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for j, tr in enumerate(held):
        lo = np.median([r["runs"][tr]["_case_range_c"][0] for r in results])
        hi = np.median([r["runs"][tr]["_case_range_c"][1] for r in results])
        rate = np.median([r["runs"][tr]["_max_case_rate_c_per_min"] for r in results])
        o = a["oracle"][bs][:, j]
        L.append(
            f"| {tr} | {lo:.1f} … {hi:.1f} | {rate:.2f} | {np.median(raw_bs[:, j]):.3g} | "
            f"{np.median(o):.3g} | {np.median(a['causal'][bs][:, j]):.3g} | "
            f"{np.median(a['causal'][bs][:, j] / o):.3f} | "
            f"{np.median(a['causal.poly'][bs][:, j] / o):.3f} | "
            f"{np.median(a['paper_gabp_T_causal'][bs][:, j] / o):.3f} | "
            f"{100 * np.median(cut[:, j]):.1f} % |"
        )
    L.append("")
    # paired differences
    L.append("### Paired differences (causal headline − other), per unit mean over its runs")
    L.append("")
    L.append(
        "| other method | Δ bias stability °/h, mean ± sd | units where causal is better | "
        "Δ drift p-p 100 s °/s, mean ± sd | units better |"
    )
    L.append("| --- | ---: | ---: | ---: | ---: |")
    for k, label in METHODS:
        if k == "causal":
            continue
        db = (a["causal"][bs] - a[k][bs]).mean(axis=1)
        dp = (a["causal"][pp] - a[k][pp]).mean(axis=1)
        L.append(
            f"| {label.format(f3db=f3db)} | {_ms(db)} | {int(np.sum(db < 0))}/{db.size} | "
            f"{_ms(dp)} | "
            f"{int(np.sum(dp < 0))}/{dp.size} |"
        )
    L.append("")
    # selection
    L.append("### Which family won (CV inside each unit's calibration run)")
    L.append("")
    wins: dict[str, int] = {}
    for r in results:
        wins[r["winner"]] = wins.get(r["winner"], 0) + 1
    L.append(
        "Winners: "
        + ", ".join(f"{k} {v}/{len(results)}" for k, v in sorted(wins.items(), key=lambda x: -x[1]))
        + "."
    )
    L.append("")
    L.append(
        "| unit | true τ s | fitted τ s | terms kept | order | CV RMSE poly / structured / "
        "bp / gabp (1e-4 °/s) | winner |"
    )
    L.append("| ---: | ---: | ---: | --- | ---: | --- | --- |")
    for r in results:
        s = r["structured"]
        cv = r["cv_rmse"]
        cvs = " / ".join(
            f"{1e4 * cv[f]:.3f}" if f in cv else "—" for f in ("poly", "structured", "bp", "gabp")
        )
        L.append(
            f"| {r['unit']} | {r['params'].get('lag_tau_s', 0.0):.0f} | "
            f"{s.get('features', {}).get('tau_s', float('nan')):.0f} | "
            f"{', '.join(s.get('terms', [])) or '—'} | {s.get('order', '—')} | {cvs} | "
            f"{r['winner']} |"
        )
    # reading the numbers: derived from them, not written by hand
    worst_i = np.unravel_index(np.argmax(ratio), ratio.shape)
    worst_c = np.unravel_index(np.argmin(cut), cut.shape)
    taus = [(r["params"].get("lag_tau_s", 0.0), r["features"]["tau_s"]) for r in results[1:]]
    tau_err = np.median([abs(f - t) for t, f in taus])
    st = a["causal.structured"][bs]
    n_bp = int(np.sum((st - a["causal.bp"][bs]).mean(axis=1) < 0))
    n_ga = int(np.sum((st - a["causal.gabp"][bs]).mean(axis=1) < 0))
    ga_bp = (a["causal.gabp"][bs] - a["causal.bp"][bs]).mean(axis=1)
    n_blow = sum(
        int(r["cv_rmse"].get(f, 0.0) > 10 * r["cv_rmse"]["structured"])
        for r in results
        for f in ("bp", "gabp")
    )
    L += [
        "",
        "Reading these numbers:",
        "",
        f"- The causal headline is within {100 * (med_ratio - 1):.0f} % of the oracle's bias "
        f"stability (median); the temperature-only models — the polynomial baseline and the "
        f"paper's GA-BP — sit at {np.median(a['causal.poly'][bs] / a['oracle'][bs]):.2f}× and "
        f"{np.median(a['paper_gabp_T_causal'][bs] / a['oracle'][bs]):.2f}×: a static function "
        "of the case temperature cannot follow the die's lag, the rate term or the "
        "hysteresis, and the paper's offline denoising does not change that "
        f"({np.median(a['paper_offline'][bs] / a['oracle'][bs]):.2f}×).",
        f"- Worst held-out run: unit {results[worst_i[0]]['unit']} on "
        f"{held[worst_i[1]]}, {ratio.max():.2f}× the oracle; lowest 100 s p-p cut "
        f"{100 * cut.min():.1f} % (unit {results[worst_c[0]]['unit']}, {held[worst_c[1]]}). "
        f"The lag is identified from one cooling staircase (median |τ̂ − τ| {tau_err:.0f} s "
        "over the lagged units): the rate term absorbs part of a lag error, the rest shows on "
        "trajectories faster than the calibration one.",
        f"- The networks on the same causal inputs lose to the structured model held out: "
        f"plain BP on {n_bp}/{len(results)} units, GA-BP on {n_ga}/{len(results)} (paired, "
        f"bias stability). GA-BP − plain BP: {_ms(ga_bp)} °/h (paired, per unit; GA-BP "
        f"better on {int(np.sum(ga_bp < 0))}/{len(results)}). Their CV RMSE inside the "
        f"calibration run exceeds 10× the structured model's on {n_blow} of "
        f"{2 * len(results)} fits: a held-out segment whose inputs lie outside the training "
        "range (the warm-up input is non-zero only in the first hour) is extrapolated along "
        "the network's edge gradient.",
        f"- On the nominal unit 0 (no lag, rate, hysteresis or warm-up) the selection chose "
        f"`{results[0]['winner']}`"
        + (
            ": the structured model could not beat the polynomial by 1 %, as it should not."
            if results[0]["winner"] == "poly"
            else "."
        ),
    ]
    return "\n".join(L)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--units", type=int, default=12)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--rate", type=float, default=10.0)
    ap.add_argument("--out", default=str(REPO / "docs" / "results.md"), help="'' to skip")
    ap.add_argument("--json", type=Path, default=REPO / "benchmarks/results/validation_suite.json")
    ap.add_argument("--quick", action="store_true", help="tiny GA/BP/VMD settings (smoke test)")
    ap.add_argument(
        "--tables-only", action="store_true", help="re-render the tables from --json (no runs)"
    )
    args = ap.parse_args(argv)
    if args.tables_only:
        d = json.loads(args.json.read_text())
        body = tables(d["units"], d["meta"]) + "\n\n" + rotation_table(d["rotation"])
        print(body)
        if args.out:
            write_section(Path(args.out), "validation_suite", body)
        return 0
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    os.environ.setdefault("GYROLAB_NO_PROGRESS", "1")  # per-unit lines instead of bars
    load_before = "{:.1f} {:.1f} {:.1f}".format(*os.getloadavg())
    t0 = time.perf_counter()
    units = list(range(args.units))
    if args.workers > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(args.workers) as ex:
            rot_f = ex.submit(rotation_check, args.rate, args.quick)
            results = list(
                ex.map(run_unit, units, [args.rate] * len(units), [args.quick] * len(units))
            )
            rot = rot_f.result()
    else:
        rot = rotation_check(args.rate, args.quick)
        results = [run_unit(u, args.rate, args.quick) for u in units]
    wall = time.perf_counter() - t0
    meta = {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "machine": f"{platform.machine()} {os.cpu_count()} cores, Python "
        f"{platform.python_version()}",
        "rate_hz": args.rate,
        "workers": args.workers,
        "wall_s": wall,
        "load_before": load_before,
        "load_after": "{:.1f} {:.1f} {:.1f}".format(*os.getloadavg()),
        "quick": args.quick,
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(
        json.dumps({"meta": meta, "units": results, "rotation": rot}, indent=1, default=str)
    )
    body = tables(results, meta) + "\n\n" + rotation_table(rot)
    print(body)
    if args.out and not args.quick:
        write_section(Path(args.out), "validation_suite", body)
    return 0


if __name__ == "__main__":
    sys.exit(main())
