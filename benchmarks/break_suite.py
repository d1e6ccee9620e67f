"""The break-the-model validation family (issue 23): gyrolab's causal models on gyros they
were not designed around, scored independently, beside the oracle.

    python benchmarks/break_suite.py [--units 12] [--workers 2] [--protocol staircase]
                                     [--families poly,structured,bp,gabp] [--noise FILE.npz]
                                     [--out docs/results.md] [--tables-only] [--quick]

**Units** (:mod:`breakfam.physics`, drawn per unit): a two-node thermal network (package
and die, two time constants and a weak back-coupling) with self-heating that grows with
temperature — the warm-up is its transient —, a quartic bias in the die temperature,
three play operators whose widths change with temperature, an asymmetric and quadratic
rate sensitivity, a die–package gradient term, aging between runs (days apart), and
temperature-dependent noise. Each effect is present with probability 0.75. Even-numbered
units carry noise cut from real static ADIS16405 records (benchmarks/data), scaled to
the unit's ARW; odd ones synthetic white + flicker + random walk + Gauss–Markov noise.

**Protocols**: ``staircase`` — calibrate on the cooling staircase, evaluate on heating,
random steps, fast ramps (±3 °C/min), a cold start and a slow ramp; ``random`` —
calibrate on random steps, evaluate on the others (the staircase included);
``staircase_ramps`` — calibrate on the staircase followed by one ±3 °C/min cycle
(:data:`breakfam.trajectories.CALIBRATIONS`; its variants ``staircase_upramp``,
``staircase_midcycle``, ``staircase_centrecycle``, ``staircase_ramps15`` and
``staircase_ramps3c`` move the cycle or change its rates), evaluate on the staircase
protocol's five runs (``--before staircase-TAG`` pairs it with a staircase run).
``--first-unit 12 --units 8`` runs the development units 12–19 (never in the tables of
units 0–11). ``--cold-power-on`` appends a second calibration run to the protocol's, a
3.6 h one powered on cold at −20 °C (``coldcal``, seed + 55 555), on the same time axis
1e6 s after the first ends: one calibration with two power-ons
(``CausalCalibration.power_ons``; the features start again at rest at the second).

**Methods**: gyrolab's selected causal model (``fit_causal`` on the calibration run's
3.6 s means, the PT100 readings, every family of ``--families``), each family alone, the
**oracle** (the output minus the true deterministic drift) and the raw output. Every
causal output is ``raw(t) − d(t)`` at 10 Hz.

**Scoring** (:mod:`breakfam.score`, not gyrolab's metrics): bias stability (std of 3.6 s
means, °/h), 100 s p-p, residual mean bias (°/h) and, where the model states one, the
coverage of its 90 % band by the 100 s means. Per-unit results are cached in
``benchmarks/results/break_suite/<protocol>[-<tag>].json.gz`` (:mod:`runcache`; runs cached
before as plain ``.json`` still read); ``--tables-only`` re-renders them.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from breakfam.family import RATE_HZ, simulate_run, units  # noqa: E402
from breakfam.realnoise import DATA  # noqa: E402
from breakfam.score import coverage, score, window_means  # noqa: E402
from breakfam.trajectories import CALIBRATIONS, NAMES  # noqa: E402
from docsections import write_section  # noqa: E402
from machine import load as load_now  # noqa: E402
from machine import run_meta  # noqa: E402
from runcache import load, path_of, save  # noqa: E402

from gyrolab.compensation.band import grade  # noqa: E402
from gyrolab.compensation.config import DEFAULT_CONFIG  # noqa: E402
from gyrolab.compensation.structured import LAG_CRITERIA  # noqa: E402

CACHE = REPO / "benchmarks" / "results" / "break_suite"
DEFAULT_LAG = DEFAULT_CONFIG.causal_lag_criterion
BLOCK_S = 3.6


def calibration(cals: list[Any]):  # noqa: ANN201
    """The calibration of one or more runs (each from its own power-on): each run's 3.6 s
    block means and PT100 readings, joined as ``gyrolab compensate RUN --also ...`` joins
    them (:func:`~gyrolab.compensation.drift_model.join_calibrations`)."""
    from gyrolab.compensation.drift_model import CausalCalibration, join_calibrations
    from gyrolab.numerics.averaging import block_average

    parts = []
    for c in cals:
        tb, xb, _ = block_average(c.t, c.raw, BLOCK_S, 1.0 / RATE_HZ)
        parts.append(CausalCalibration(t=tb, rate=xb, pt_t=c.pt_t, pt_c=c.pt_c))
    return join_calibrations(parts)


def fit_and_apply(
    cals: list[Any],
    runs: dict[str, Any],
    families: tuple[str, ...],
    seed: int,
    quick: bool,
    lag_criterion: str = DEFAULT_LAG,
) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, Any]]:
    """gyrolab's causal selection fitted on the calibration runs ``cals`` (each from its
    own power-on: :func:`calibration`); every family's 10 Hz output (and its band, where
    the model states one) on every run of ``runs``."""
    import torch

    from gyrolab.compensation.causal import family_models, fit_causal
    from gyrolab.compensation.config import PipelineConfig

    torch.set_num_threads(1)
    cfg = PipelineConfig(causal_lag_criterion=lag_criterion)
    if quick:
        cfg = replace(cfg, bp_max_iter=60, ga_population=12, ga_generations=6)
    t0 = time.perf_counter()
    cm = fit_causal(
        calibration(cals),
        families=families,
        config=cfg,
        seed=seed,
    )
    info: dict[str, Any] = {
        "winner": cm.family,
        "features": cm.params.to_dict(),
        "cv_rmse": cm.cv_rmse,
        "selection": cm.selection,
        "fit_s": time.perf_counter() - t0,
    }
    models = {"causal": cm, **{f"causal.{f}": m for f, m in family_models(cm).items()}}
    out: dict[str, dict[str, np.ndarray]] = {}
    for name, r in runs.items():
        o: dict[str, np.ndarray] = {"raw": r.raw, "oracle": r.raw - r.drift}
        for key, m in models.items():
            o[key] = r.raw - m.drift_at(r.t, r.pt_t, r.pt_c)
            band = getattr(m, "band_at", None)
            if band is not None and key == "causal":
                lo, hi = band(r.t, r.pt_t, r.pt_c)
                o["causal.band_lo"], o["causal.band_hi"] = lo, hi
                o["causal.band_ratio"] = hi / m.band.half_width
        out[name] = o
    return out, info


def run_unit(
    u: int,
    protocol: str,
    families: tuple[str, ...],
    noise: str,
    quick: bool,
    lag: str = DEFAULT_LAG,
    draw: int = 0,
    cold: bool = False,
):
    """Simulate unit ``u`` on every trajectory, calibrate on ``protocol``, score the rest;
    ``draw`` > 0 re-draws the calibration run's noise (seed + 100 000 × draw), the held-out
    runs kept; ``cold``: a second calibration run, ``coldcal`` (seed + 55 555), powered on
    cold (module docstring)."""
    t0 = time.perf_counter()
    unit = units(u + 1)[u]
    names = list(NAMES)
    base = CALIBRATIONS.get(protocol, protocol)
    held = [n for n in names if n != base]
    runs = {
        n: simulate_run(unit, n, seed=100 * u + names.index(n) + 1, noise_path=noise)
        for n in held
    }
    # the calibration run, once (a calibration-only one is seeded as the run it extends)
    seed = 100 * u + names.index(base) + 1 + 100_000 * draw
    runs[protocol] = simulate_run(unit, protocol, seed=seed, noise_path=noise)
    cals = [runs[protocol]]
    if cold:
        cals.append(simulate_run(unit, "coldcal", seed=seed + 55_555, noise_path=noise))
    t_sim = time.perf_counter() - t0
    outs, info = fit_and_apply(cals, {n: runs[n] for n in held}, families, u, quick, lag)
    res: dict[str, Any] = {
        "unit": u,
        "protocol": protocol,
        "effects": list(unit.effects),
        "real_noise": unit.real_noise,
        "tau_dp": unit.tau_dp,
        "tau_pa": unit.tau_pa,
        **info,
        "runs": {},
    }
    for n in held:
        o = outs[n]
        r = runs[n]
        rr = {k: score(v) for k, v in o.items() if not k.startswith("causal.band")}
        if "causal.band_lo" in o:
            hw = window_means(o["causal.band_hi"])
            rr["causal"]["band_coverage"] = coverage(
                o["causal"], window_means(o["causal.band_lo"]), hw
            )
            p90 = float(np.quantile(o["causal.band_ratio"], 0.9))
            rr["causal"]["expected_error"] = {"grade": grade(p90), "ratio_p90": p90}
            yw = window_means(o["causal"])[: hw.size]
            rr["causal"]["band_ratios"] = [round(float(v), 4) for v in np.abs(yw) / hw[: yw.size]]
        rr["_case_range_c"] = [float(r.pt_c.min()), float(r.pt_c.max())]
        res["runs"][n] = rr
    res["timing_s"] = {"simulate": t_sim, "total": time.perf_counter() - t0}
    print(
        f"unit {u:2d} [{protocol}]: winner {info['winner']:<10} "
        f"τ={info['features']['tau_s']:.0f} s (τ_dp {unit.tau_dp:.0f}) "
        f"{res['timing_s']['total']:.0f} s",
        file=sys.stderr,
        flush=True,
    )
    return res


# ---------------------------------------------------------------------------- tables

BS, PP, MB = "bias_stability_deg_per_h", "pp_100s_deg_per_s", "mean_bias_deg_per_h"


def _ms(v: np.ndarray, fmt: str = ".3g") -> str:
    return f"{np.mean(v):{fmt}} ± {np.std(v, ddof=1) if v.size > 1 else 0.0:{fmt}}"


def arrays(results: list[dict[str, Any]], key: str, metric: str) -> np.ndarray:
    """(units, held-out runs) of one method's metric."""
    return np.array([[r["runs"][n][key][metric] for n in r["runs"]] for r in results])


def tables(results: list[dict[str, Any]], meta: dict[str, Any]) -> str:
    """The markdown section: targets, all methods, per trajectory, paired differences."""
    proto = results[0]["protocol"]
    held = list(results[0]["runs"])
    keys = [k for k in results[0]["runs"][held[0]] if not k.startswith("_")]
    methods = [
        k
        for k in (
            "oracle",
            "causal",
            "causal.structured",
            "causal.structured_rate",
            "causal.poly",
            "causal.bp",
            "causal.gabp",
            "raw",
        )
        if k in keys
    ]
    a = {k: {m: arrays(results, k, m) for m in (BS, PP, MB)} for k in methods}
    ratio = a["causal"][BS] / a["oracle"][BS]
    cut = 1.0 - a["causal"][PP] / a["raw"][PP]
    ocut = 1.0 - a["oracle"][PP] / a["raw"][PP]
    gap = 100.0 * (ocut - cut)
    worse = int(np.sum((a["causal"][BS] >= a["raw"][BS]) | (a["causal"][PP] >= a["raw"][PP])))
    crit = meta.get("lag_criterion", "cv")  # runs cached before the option: the CV's
    lag = f" --lag-criterion {crit}" if crit != DEFAULT_LAG else ""
    L = [
        f"`python benchmarks/break_suite.py --protocol {proto} --families "
        f"{','.join(meta['families'])}{lag}` — {meta['date']}, "
        f"{meta['machine']}, {len(results)} units × {len(held)} held-out trajectories "
        f"({sum(r['real_noise'] for r in results)} units with real ADIS16405 noise), "
        f"families {', '.join(meta['families'])}; wall clock {meta['wall_s']:.0f} s, "
        f"load average {meta['load']} (shared machine).",
        "",
        "| target (issue 23) | measured | verdict |",
        "| --- | --- | --- |",
    ]
    med = float(np.median(ratio))

    def v(ok: bool) -> str:
        return "**pass**" if ok else "**FAIL**"

    L.append(
        f"| causal bias stability ÷ oracle: median ≤ 1.15, worst ≤ 1.4 (all held-out runs) "
        f"| median {med:.3f}, worst {ratio.max():.2f} | {v(med <= 1.15 and ratio.max() <= 1.4)} |"
    )
    L.append(
        f"| 100 s p-p cut within 5 points of the oracle's (median) and 10 (worst) | "
        f"gap median {np.median(gap):.1f}, worst {gap.max():.1f} points (oracle's cut "
        f"median {100 * np.median(ocut):.1f} %) | "
        f"{v(np.median(gap) <= 5 and gap.max() <= 10)} |"
    )
    L.append(
        f"| no run worse than raw (bias stability or 100 s p-p) | {worse} of {cut.size} | "
        f"{v(worse == 0)} |"
    )
    if all("band_coverage" in r["runs"][n]["causal"] for r in results for n in held):
        cov = np.array([[r["runs"][n]["causal"]["band_coverage"] for n in held] for r in results])
        L.append(
            f"| 90 % band covers ≥ 85 % of held-out 100 s means (pooled over runs) | "
            f"{100 * cov.mean():.1f} % (runs: median {100 * np.median(cov):.0f} %, "
            f"lowest {100 * cov.min():.0f} %) | {v(cov.mean() >= 0.85)} |"
        )
    if all("expected_error" in r["runs"][n]["causal"] for r in results for n in held):
        L += [
            "",
            "| expected error (graded, per held-out run) | runs | causal ÷ oracle (median, "
            "worst) | band coverage (pooled) |",
            "| --- | ---: | ---: | ---: |",
        ]
        for g in ("none", "mild", "severe"):
            sel = [
                (i, j)
                for i, r in enumerate(results)
                for j, n in enumerate(held)
                if r["runs"][n]["causal"]["expected_error"]["grade"] == g
            ]
            if not sel:
                L.append(f"| {g} | 0 | — | — |")
                continue
            rs = np.array([ratio[i, j] for i, j in sel])
            cv = np.mean([results[i]["runs"][held[j]]["causal"]["band_coverage"] for i, j in sel])
            L.append(
                f"| {g} | {len(sel)} | {np.median(rs):.3f}, {rs.max():.2f} | {100 * cv:.0f} % |"
            )
    L += [
        "",
        "| method | bias stability °/h | ÷ oracle (median, worst) | 100 s p-p °/s | "
        "cut (median) | |mean bias| °/h (median, worst) |",
        "| --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for k in methods:
        b = a[k][BS].mean(axis=1)
        p = a[k][PP].mean(axis=1)
        r_ = a[k][BS] / a["oracle"][BS]
        c_ = 1.0 - a[k][PP] / a["raw"][PP]
        mb = np.abs(a[k][MB])
        L.append(
            f"| {k} | {_ms(b)} | {np.median(r_):.3f}, {r_.max():.2f} | {_ms(p)} | "
            f"{'—' if k == 'raw' else f'{100 * np.median(c_):.1f} %'} | "
            f"{np.median(mb):.3g}, {mb.max():.3g} |"
        )
    L += [
        "",
        "| held-out trajectory | causal ÷ oracle (median, worst) | causal cut | "
        "oracle cut | poly(T) ÷ oracle (median) |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    for j, n in enumerate(held):
        pr = a["causal.poly"][BS][:, j] / a["oracle"][BS][:, j] if "causal.poly" in a else None
        L.append(
            f"| {n} | {np.median(ratio[:, j]):.3f}, {ratio[:, j].max():.2f} | "
            f"{100 * np.median(cut[:, j]):.1f} % | {100 * np.median(ocut[:, j]):.1f} % | "
            f"{'—' if pr is None else f'{np.median(pr):.3f}'} |"
        )
    L += [
        "",
        "Paired differences (causal headline − other), per unit mean over its runs:",
        "",
        "| other | Δ bias stability °/h | units causal better | Δ 100 s p-p °/s |",
        "| --- | ---: | ---: | ---: |",
    ]
    for k in methods:
        if k == "causal":
            continue
        db = (a["causal"][BS] - a[k][BS]).mean(axis=1)
        dp = (a["causal"][PP] - a[k][PP]).mean(axis=1)
        L.append(f"| {k} | {_ms(db)} | {int(np.sum(db < 0))}/{db.size} | {_ms(dp)} |")
    wi = np.unravel_index(np.argmax(ratio), ratio.shape)
    L += [
        "",
        f"Worst run: unit {results[wi[0]]['unit']} on {held[wi[1]]} "
        f"({ratio.max():.2f}× the oracle; its effects: "
        f"{', '.join(results[wi[0]]['effects'])}). Winners: "
        + ", ".join(
            f"{w} {sum(r['winner'] == w for r in results)}/{len(results)}"
            for w in sorted({r["winner"] for r in results})
        )
        + ".",
    ]
    return "\n".join(L)


def paired_table(results: list[dict[str, Any]], before: list[dict[str, Any]], tag: str) -> str:
    """Paired differences, per unit (mean over its held-out runs), of this run's causal
    headline against the same units' results of an earlier run (today's models)."""
    units_b = {r["unit"]: r for r in before}
    both = [r for r in results if r["unit"] in units_b]
    rows = []
    for key, lab in ((BS, "bias stability °/h"), (PP, "100 s p-p °/s"), (MB, "|mean bias| °/h")):
        now = np.array([[abs(x["causal"][key]) for x in r["runs"].values()] for r in both])
        was = np.array(
            [[abs(x["causal"][key]) for x in units_b[r["unit"]]["runs"].values()] for r in both]
        )
        d = (now - was).mean(axis=1)
        rows.append(
            f"| {lab} | {_ms(was.mean(axis=1))} | {_ms(now.mean(axis=1))} | {_ms(d)} | "
            f"{int(np.sum(d < 0))}/{d.size} |"
        )
    ratio_now = np.array(
        [[x["causal"][BS] / x["oracle"][BS] for x in r["runs"].values()] for r in both]
    )
    ratio_was = np.array(
        [
            [x["causal"][BS] / x["oracle"][BS] for x in units_b[r["unit"]]["runs"].values()]
            for r in both
        ]
    )
    return "\n".join(
        [
            f"Paired against today's models (run `{tag}`, same units, same runs), per unit mean "
            "over its held-out runs:",
            "",
            "| metric | before | now | Δ (now − before) | units better |",
            "| --- | ---: | ---: | ---: | ---: |",
            *rows,
            "",
            f"Causal ÷ oracle: median {np.median(ratio_was):.3f} → {np.median(ratio_now):.3f}, "
            f"worst {ratio_was.max():.2f} → {ratio_now.max():.2f}.",
        ]
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--units", type=int, default=12)
    ap.add_argument(
        "--first-unit", type=int, default=0, help="development units: 12 and up (never scored)"
    )
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument(
        "--protocol", default="staircase", choices=("staircase", "random", *CALIBRATIONS)
    )
    ap.add_argument("--families", default="poly,structured,bp,gabp")
    ap.add_argument("--noise", default=str(DATA), help="real static records (.npz)")
    ap.add_argument("--out", default="", help="docs page to write the section into")
    ap.add_argument("--tag", default="", help="cache name suffix (a variant's results)")
    ap.add_argument("--tables-only", action="store_true")
    ap.add_argument("--before", default="", help="cache tag of an earlier run to pair with")
    ap.add_argument("--quick", action="store_true", help="tiny network settings")
    ap.add_argument(
        "--lag-criterion",
        default=DEFAULT_LAG,
        choices=LAG_CRITERIA,
        help="PipelineConfig.causal_lag_criterion of the causal selection",
    )
    ap.add_argument(
        "--cal-draw",
        type=int,
        default=0,
        help="re-draw the calibration run's noise (K > 0; held-out runs unchanged)",
    )
    ap.add_argument(
        "--cold-power-on",
        action="store_true",
        help="a second calibration run powered on cold (coldcal) beside the protocol's",
    )
    args = ap.parse_args(argv)
    fams = tuple(args.families.split(","))
    name = f"{args.protocol}{('-' + args.tag) if args.tag else ''}"
    if args.tables_only:
        d = load(CACHE / name)
        results, meta = d["units"], d["meta"]
    else:
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        os.environ.setdefault("GYROLAB_NO_PROGRESS", "1")
        t0 = time.perf_counter()
        la = load_now()
        job = (
            args.protocol,
            fams,
            args.noise,
            args.quick,
            args.lag_criterion,
            args.cal_draw,
            args.cold_power_on,
        )
        us = list(range(args.first_unit, args.first_unit + args.units))
        if args.workers > 1:
            from concurrent.futures import ProcessPoolExecutor

            with ProcessPoolExecutor(args.workers) as ex:
                results = list(ex.map(run_unit, us, *[[j] * len(us) for j in job]))
        else:
            results = [run_unit(u, *job) for u in us]
        meta = {
            **run_meta(t0, la),
            "families": list(fams),
            "quick": args.quick,
            "lag_criterion": args.lag_criterion,
            "cal_draw": args.cal_draw,
            "cold_power_on": args.cold_power_on,
        }
        save(CACHE / name, {"meta": meta, "units": results})
    body = tables(results, meta)
    if args.before:
        # a tag of this protocol, or a whole cache name (another protocol, same held-out runs)
        stem = CACHE / f"{args.protocol}-{args.before}"
        prev = load(stem if path_of(stem).exists() else CACHE / args.before)["units"]
        body += "\n\n" + paired_table(results, prev, args.before)
    print(body)
    if args.out:
        write_section(Path(args.out), f"break_suite_{name}", body)
    return 0


if __name__ == "__main__":
    sys.exit(main())
