"""GPSO-VMD search: gyrolab's full search vs the same search on vmdpy, in one process.

Runs the paper's search (population 50, 30 generations after the initial swarm, K 3..11,
alpha 50..5000) on a synthetic 11 000-sample paper-like record and times it. The same
search on vmdpy would take tens of minutes, so it is estimated instead: ``--sample``
positions the search evaluated are decomposed by both (vmdpy with its settings tau = 0,
DC = 0, init = 1, tol = 1e-7, fitness computed the same way), and vmdpy's mean time per
evaluation is multiplied by the number of evaluations the search made (the same cache of
repeated positions applies to both).

Usage: ``python benchmarks/bench_gpso.py [--criterion drift_separation] [--sample 12]
[--seed 0] [--device cuda]``
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import numpy as np

os.environ.setdefault("GYROLAB_NO_PROGRESS", "1")

from gyrolab.compensation.fitness import (  # noqa: E402
    CRITERIA,
    DEFAULT_CRITERION,
    search_vmd_parameters,
    synthetic_drift_signal,
)
from gyrolab.compensation.vmd import VMDResult, vmd  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description="GPSO-VMD: gyrolab vs vmdpy (estimated)")
    ap.add_argument("--criterion", default=DEFAULT_CRITERION, choices=list(CRITERIA))
    ap.add_argument("--population", type=int, default=50)
    ap.add_argument("--generations", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--signal-seed", type=int, default=0)
    ap.add_argument("--sample", type=int, default=12, help="positions timed on vmdpy")
    ap.add_argument("--device", default=None, help="torch device for the VMD batches")
    args = ap.parse_args()
    sys.stdout.reconfigure(line_buffering=True)  # progress visible when piped
    import numba

    print(
        f"{platform.node()}, {os.cpu_count()} CPUs, numba threads {numba.get_num_threads()}, "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}"
    )
    x = synthetic_drift_signal(11_000, seed=args.signal_seed)
    vmd(x[:200], 100.0, 2)  # JIT load outside the timing
    vkw = {"device": args.device} if args.device else None
    t0 = time.perf_counter()
    res = search_vmd_parameters(
        x,
        criterion=args.criterion,
        population=args.population,
        generations=args.generations,
        seed=args.seed,
        vmd_kwargs=vkw,
    )
    t_ours = time.perf_counter() - t0
    g = res.gpso
    print(
        f"\nGPSO-VMD ({args.criterion}), {args.population} x {args.generations} generations "
        f"(+ initial swarm): K = {res.K}, alpha = {res.alpha:.1f}, fitness {res.fitness:.6g}, "
        f"{g.n_evaluations} VMD evaluations, {t_ours:.1f} s"
    )

    try:
        from vmdpy import VMD
    except ImportError:  # pragma: no cover
        print("vmdpy not installed: no comparison")
        return
    crit = CRITERIA[args.criterion]
    pts = np.unique(g.positions.reshape(-1, 2), axis=0)
    pick = pts[np.random.default_rng(args.seed).choice(len(pts), min(args.sample, len(pts)), False)]
    t_ref, t_one = [], []
    for K, alpha in pick:
        K = int(K)
        t1 = time.perf_counter()
        u, _, om = VMD(x, alpha, 0.0, K, 0, 1, 1e-7)
        crit(x, VMDResult(u, om[-1], om.shape[0], True, alpha, K))
        t_ref.append(time.perf_counter() - t1)
        t1 = time.perf_counter()
        crit(x, vmd(x, alpha, K))
        t_one.append(time.perf_counter() - t1)
    per_ref, per_one = float(np.mean(t_ref)), float(np.mean(t_one))
    est = per_ref * g.n_evaluations
    print(
        f"sample of {len(pick)} evaluated positions: vmdpy {per_ref * 1e3:.0f} ms/evaluation, "
        f"ours one at a time {per_one * 1e3:.1f} ms/evaluation ({per_ref / per_one:.0f}x)"
    )
    print(
        f"estimated vmdpy search: {est:.0f} s ({est / 60:.1f} min) -> ours is {est / t_ours:.0f}x "
        f"faster end to end"
    )


if __name__ == "__main__":
    main()
