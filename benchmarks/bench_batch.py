"""``gyrolab batch compensate`` of N simulated units: time per unit, parallel efficiency.

    python benchmarks/bench_batch.py [--units 24] [--profile paper] [--rate 100]
                                     [--workers 1,2] [--small]

Simulates one multi-unit run of ``--units`` units (``gyrolab simulate --units``: a seeded
unit family in one chamber), then runs ``batch compensate`` on it once per worker count
(w = 1: one after the other in this process, the serial baseline; w ≥ 2: a fresh
LocalCluster of w one-thread workers, its start-up included) and prints, per worker count: the
wall time (cluster start included), time per unit, the parallel efficiency
``E(w) = T(1) / (w · T(w))``, the largest peak resident memory of a worker, and whether every
unit's ``model.json`` has the same bytes as with one worker. ``--small`` uses the tests'
small pipeline configuration (tiny GA/GPSO) instead of the paper's. There is no peer to
compare with: the figure to meet is E(2) ≥ 80 % on two cores. The machine's load average is
printed beside the figures (docs/performance.md).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from gyrolab.batch import BatchOptions, run_batch
from gyrolab.compensation.config import DEFAULT_CONFIG, PipelineConfig

SMALL = replace(
    PipelineConfig(),
    ga_population=12,
    ga_generations=6,
    bp_max_iter=150,
    hidden=5,
    gpso_population=4,
    gpso_generations=1,
)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--units", type=int, default=24)
    ap.add_argument("--profile", default="paper")
    ap.add_argument("--rate", type=float, default=100.0)
    ap.add_argument("--workers", default="1,2")
    ap.add_argument("--small", action="store_true", help="tests' small pipeline config")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    os.environ.setdefault("GYROLAB_NO_PROGRESS", "1")
    counts = [int(w) for w in args.workers.split(",")]
    cfg = SMALL if args.small else DEFAULT_CONFIG
    with tempfile.TemporaryDirectory(prefix="bench_batch.") as d:
        run = Path(d) / "fleet.mcap"
        t0 = time.perf_counter()
        argv = [
            "simulate",
            "--out",
            str(run),
            "--units",
            str(args.units),
            "--seed",
            str(args.seed),
            "--profile",
            args.profile,
            "--rate",
            str(args.rate),
        ]
        # in a child process, so that this process's peak RSS (the serial w = 1 run happens
        # here, without a cluster) is that of the compensation alone
        subprocess.run(
            [sys.executable, "-m", "gyrolab", *argv], check=True, stdout=subprocess.DEVNULL
        )
        t_sim = time.perf_counter() - t0
        print(
            f"simulated {args.units} units, profile {args.profile}, {args.rate:g} Hz in "
            f"{t_sim:.1f} s; {os.cpu_count()} CPUs; load {os.getloadavg()}"
        )
        ref: dict[str, bytes] = {}
        t1 = None
        print(
            "| workers | wall s | s per unit | efficiency | max worker peak RSS MiB | "
            "item s (mean) | same model.json bytes | load (1 min) |"
        )
        print("| --- | --- | --- | --- | --- | --- | --- | --- |")
        for w in counts:
            out = Path(d) / f"models_w{w}"
            load0 = os.getloadavg()[0]
            t0 = time.perf_counter()
            res = run_batch(
                "compensate", [str(run)], out, options=BatchOptions(config=cfg), workers=w
            )
            wall = time.perf_counter() - t0
            load1 = os.getloadavg()[0]
            failed = [r for r in res if r.status != "done"]
            if failed:
                print(f"{len(failed)} failed: {failed[0].error}", file=sys.stderr)
                return 1
            models = {r.unit or r.out: (Path(r.out) / "model.json").read_bytes() for r in res}
            if not ref:
                ref = models
            same = models == ref
            if not same:  # say what differs
                import json

                for k in ref:
                    a, b = json.loads(ref[k]), json.loads(models[k])
                    diff = [key for key in a if a.get(key) != b.get(key)]
                    print(f"  {k}: model.json differs in {diff}", file=sys.stderr)
            t1 = t1 or (wall if w == 1 else None)
            eff = f"{100 * t1 / (w * wall):.0f} %" if t1 else "—"
            rss = max(r.peak_rss_mib for r in res)
            mean_item = sum(r.seconds for r in res) / len(res)
            print(
                f"| {w} | {wall:.1f} | {wall / len(res):.2f} | {eff} | {rss:.0f} | "
                f"{mean_item:.2f} | {'yes' if same else 'NO'} | {load0:.1f} → {load1:.1f} |"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
