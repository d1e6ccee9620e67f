"""A causal family set on gyrolab's own validation family, the causal selection alone.

    python benchmarks/family_check.py [--families poly,structured] [--units 12]
                                      [--workers 2] [--lag-criterion profile]

The units, trajectories and seeds of ``benchmarks/validation_suite.py`` (each unit
calibrated on its ``paper`` run, evaluated on the five others), but only the causal
selection (``fit_causal`` on the calibration run's 3.6 s means and PT100 readings, the
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


def run_unit(
    u: int, families: tuple[str, ...], lag: str = DEFAULT_CONFIG.causal_lag_criterion
) -> tuple[str, list[tuple[float, float]]]:
    """Simulate unit ``u`` (the suite's seeds), calibrate on ``paper``, score the rest:
    a line and the (causal ÷ oracle, cut gap points) of each held-out run."""
    import validation_suite as vs

    from gyrolab.compensation.causal import CausalCalibration, fit_causal
    from gyrolab.compensation.config import PipelineConfig
    from gyrolab.numerics.averaging import block_average

    model, _ = vs.unit_model(u)
    runs = {
        n: vs.simulate(model, vs.trajectory(n, u), 10.0, seed=1000 * u + i + 1)
        for i, n in enumerate(vs.TRAJECTORIES)
    }
    c = runs[vs.CALIBRATION]
    tb, xb, _ = block_average(c["t"], c["raw"], 3.6, 0.1)
    cm = fit_causal(
        CausalCalibration(t=tb, rate=xb, pt_t=c["pt_t"], pt_c=c["pt_c"]),
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
        f"unit {u:2d}: {cm.family:<16} τ={cm.params.tau_s:5.0f} s {','.join(terms):<40} "
        + " ".join(f"{a:.3f}" for a, _ in out)
    )
    return line, out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--families", default="poly,structured")
    ap.add_argument("--units", type=int, default=12)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument(
        "--lag-criterion",
        default=DEFAULT_CONFIG.causal_lag_criterion,
        choices=LAG_CRITERIA,
        help="PipelineConfig.causal_lag_criterion",
    )
    args = ap.parse_args(argv)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    fams = tuple(args.families.split(","))
    us = list(range(args.units))
    if args.workers > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(args.workers) as ex:
            res = list(ex.map(run_unit, us, [fams] * len(us), [args.lag_criterion] * len(us)))
    else:
        res = [run_unit(u, fams, args.lag_criterion) for u in us]
    for line, _ in res:
        print(line)
    a = np.array([x for _, o in res for x in o])
    print(
        f"families {','.join(fams)} (lag criterion {args.lag_criterion}): causal ÷ oracle "
        f"median {np.median(a[:, 0]):.3f}, "
        f"worst {a[:, 0].max():.2f}; 100 s p-p cut gap median {np.median(a[:, 1]):.1f}, "
        f"worst {a[:, 1].max():.1f} points ({a.shape[0]} held-out runs)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
