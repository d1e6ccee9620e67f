"""A causal family set on gyrolab's own validation family, the causal selection alone.

    python benchmarks/family_check.py [--families poly,structured] [--units 12] [--first-unit 0]
                                      [--workers 2] [--lag-criterion profile]
                                      [--calibration paper[,paper_ramps[+cold_start]]]

The units, trajectories and seeds of ``benchmarks/validation_suite.py`` (each unit
calibrated on its ``paper`` run, evaluated on the five others; ``--calibration`` names
other built-in profiles or profile TOMLs to calibrate on instead, scored on the same five
runs; ``a+b`` is a calibration of two power-ons, run ``b`` from its own, joined as
``gyrolab compensate a --also b`` joins them), but only
the causal selection (``fit_causal`` on the calibration run's 3.6 s means and PT100 readings, the
families of ``--families``) against the oracle — no GPSO-VMD, GA-BP or baselines, so a
family set is compared on the 60 held-out runs in minutes instead of the suite's
≈ 45 min. Scored with ``breakfam.score`` (bias stability of 3.6 s means, 100 s p-p).
Prints, per unit, the winner, its lag and terms and each held-out run's causal ÷ oracle
bias stability, then the median and worst over the runs and the 100 s p-p cut's gap to
the oracle's (points). Used to decide whether a family joins the defaults
(docs/results.md, "the break-the-model family").
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from breakfam.score import score  # noqa: E402

from gyrolab.compensation.config import DEFAULT_CONFIG  # noqa: E402
from gyrolab.compensation.structured import LAG_CRITERIA  # noqa: E402


def _case_rates(r: dict[str, np.ndarray]) -> tuple[float, float]:
    """Most negative and most positive case (PT100) rate of a run, °C/min, as 300 s
    differences of 300 s means of the 1 Hz readings."""
    k = 300
    c = np.convolve(r["pt_c"], np.ones(k) / k, mode="valid")
    d = (c[k:] - c[:-k]) / k * 60.0
    return float(d.min()), float(d.max())


def run_unit(
    u: int,
    families: tuple[str, ...],
    lag: str = DEFAULT_CONFIG.causal_lag_criterion,
    calibrations: tuple[str, ...] = ("paper",),
) -> dict[str, tuple[str, list[tuple[float, float]], tuple[float, float]]]:
    """Simulate unit ``u`` (the suite's seeds), calibrate on each built-in profile of
    ``calibrations`` (``paper``: the suite's own run; another, e.g. ``paper_ramps``: run
    with the ``paper`` run's seed), score the five held-out runs (never ``paper``): per
    calibration a line, the (causal ÷ oracle, cut gap points) of each held-out run and the
    calibration run's case-rate range (°C/min); under ``"held-out"`` the held-out runs'
    case-rate range."""
    import validation_suite as vs

    from gyrolab.compensation.causal import CausalCalibration, fit_causal
    from gyrolab.compensation.config import PipelineConfig
    from gyrolab.compensation.drift_model import join_calibrations
    from gyrolab.numerics.averaging import block_average
    from gyrolab.profiles.profile import load_profile

    model, _ = vs.unit_model(u)
    runs = {
        n: vs.simulate(model, vs.trajectory(n, u), 10.0, seed=1000 * u + i + 1)
        for i, n in enumerate(vs.TRAJECTORIES)
    }
    cal_seed = 1000 * u + vs.TRAJECTORIES.index(vs.CALIBRATION) + 1
    res = {}
    for cal in calibrations:
        # one run per power-on: "paper_ramps+cold_start" is compensate --also; the case
        # rates reported are the first run's
        parts, first = [], None
        for k, name in enumerate(cal.split("+")):
            if name == vs.CALIBRATION and not k:
                c = runs[name]
            else:
                c = vs.simulate(model, load_profile(name), 10.0, cal_seed + 55_555 * k)
            first = c if first is None else first
            tb, xb, _ = block_average(c["t"], c["raw"], 3.6, 0.1)
            parts.append(CausalCalibration(t=tb, rate=xb, pt_t=c["pt_t"], pt_c=c["pt_c"]))
        cm = fit_causal(
            join_calibrations(parts),
            families=families,
            config=PipelineConfig(causal_lag_criterion=lag),
        )
        out = []
        for n, r in runs.items():
            if n == vs.CALIBRATION:
                continue
            y = r["raw"] - cm.drift_at(r["t"], r["pt_t"], r["pt_c"])
            s, o, raw = score(y), score(r["raw"] - r["drift"]), score(r["raw"])
            bs = "bias_stability_deg_per_h"
            pp = "pp_100s_deg_per_s"
            gap = 100.0 * (s[pp] - o[pp]) / raw[pp]
            out.append((s[bs] / o[bs], gap))
        terms = getattr(cm.model, "terms", ())
        line = (
            f"unit {u:2d} [{cal}]: {cm.family:<16} τ={cm.params.tau_s:5.0f} s "
            f"{','.join(terms):<40} " + " ".join(f"{a:.3f}" for a, _ in out)
        )
        res[cal] = (line, out, _case_rates(first))
    held = [_case_rates(r) for n, r in runs.items() if n != vs.CALIBRATION]
    res["held-out"] = ("", [], (min(a for a, _ in held), max(b for _, b in held)))
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--families", default="poly,structured")
    ap.add_argument("--units", type=int, default=12)
    ap.add_argument(
        "--first-unit",
        type=int,
        default=0,
        help="first unit (default 0; 12 with --units 12: units the family was not tuned on)",
    )
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument(
        "--lag-criterion",
        default=DEFAULT_CONFIG.causal_lag_criterion,
        choices=LAG_CRITERIA,
        help="PipelineConfig.causal_lag_criterion",
    )
    ap.add_argument(
        "--calibration",
        default="paper",
        help="built-in profile(s) or PROFILE.toml to calibrate on, comma-separated "
        "(default paper; e.g. paper,paper_ramps: the same held-out runs scored after "
        "each); a+b: a calibration of two power-ons, as compensate a --also b (b seeded "
        "+55 555)",
    )
    args = ap.parse_args(argv)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    fams = tuple(args.families.split(","))
    cals = tuple(args.calibration.split(","))
    us = list(range(args.first_unit, args.first_unit + args.units))
    n = len(us)
    if args.workers > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(args.workers) as ex:
            res = list(ex.map(run_unit, us, [fams] * n, [args.lag_criterion] * n, [cals] * n))
    else:
        res = [run_unit(u, fams, args.lag_criterion, cals) for u in us]
    for cal in cals:
        for r in res:
            print(r[cal][0])
    import validation_suite as vs

    held = [t for t in vs.TRAJECTORIES if t != vs.CALIBRATION]

    def where(i: int) -> str:
        return f"unit {us[i // len(held)]} {held[i % len(held)]}"

    first = np.array([x for r in res for x in r[cals[0]][1]])
    for cal in cals:
        a = np.array([x for r in res for x in r[cal][1]])
        lo = min(r[cal][2][0] for r in res)
        hi = max(r[cal][2][1] for r in res)
        per_unit = np.array([np.mean([x for x, _ in r[cal][1]]) for r in res])
        base = np.array([np.mean([x for x, _ in r[cals[0]][1]]) for r in res])
        d = per_unit - base
        print(
            f"calibrated on {cal} (case rate {lo:+.2f} … {hi:+.2f} °C/min), families "
            f"{','.join(fams)} (lag criterion {args.lag_criterion}): causal ÷ oracle "
            f"median {np.median(a[:, 0]):.3f}, "
            f"worst {a[:, 0].max():.2f} ({where(int(a[:, 0].argmax()))}); 100 s p-p cut gap "
            f"median {np.median(a[:, 1]):.1f}, "
            f"worst {a[:, 1].max():.1f} points ({where(int(a[:, 1].argmax()))}) "
            f"({a.shape[0]} held-out runs)"
            + (
                f"; per unit Δ vs {cals[0]} {d.mean():+.4f} ± {d.std(ddof=1):.4f}, "
                f"better / worse {(d < -0.01).sum()} / {(d > 0.01).sum()}"
                if cal != cals[0] and len(res) > 1
                else ""
            )
        )
    lo = min(r["held-out"][2][0] for r in res)
    hi = max(r["held-out"][2][1] for r in res)
    print(
        f"held-out runs per unit: {', '.join(held)} ({first.shape[0] // len(res)}); "
        f"their case rate {lo:+.2f} … {hi:+.2f} °C/min"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
