"""Discrepancy battery: hide one (or two) vocabulary effects in simulated oven runs and
check that ``gyrolab discrepancy`` names them (docs/discrepancy.md, issue 8 acceptance).

For every effect a static oven test can reveal, ``--seeds`` runs of the paper profile are
simulated with truth = nominal + that effect, its parameters drawn from the realistic
ranges of :data:`RANGES` (a sign is drawn too where the effect has one); plus nominal-only
runs, which must name nothing; plus a smaller battery of pairs. Each run goes through the
same reduction as a recording (``synth.simulate_bench`` → ``data.from_arrays``) and the
workflow starts from the nominal model.

A run counts as named when the hidden effect is in ``effects_found`` or in an ``ambiguous``
set of at most three; the gap check compares the hidden effect's own gap metric
(``workflow.PRIMARY_GAP``) before and after.

    python benchmarks/discrepancy_battery.py --seeds 5 --nominal 10 --pairs 2 \
        --out benchmarks/results/discrepancy_battery.json

prints the confusion table (truth × named) in Markdown and writes every run's outcome.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

os.environ.setdefault("GYROLAB_NO_PROGRESS", "1")
# run against this checkout, not whatever gyrolab happens to be installed
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gyrolab.profile import load_profile  # noqa: E402
from gyrolab.sim.discrepancy.synth import simulate_bench  # noqa: E402
from gyrolab.sim.discrepancy.workflow import PRIMARY_GAP, run_discrepancy  # noqa: E402
from gyrolab.sim.model import nominal_model  # noqa: E402

Sampler = Callable[[np.random.Generator], dict[str, float]]


def _sign(rng: np.random.Generator) -> float:
    return float(rng.choice([-1.0, 1.0]))


RANGES: dict[str, Sampler] = {
    # deterministic gyro terms (°/s units as in gyrolab/sim/effects.py)
    "cubic_temp": lambda r: {"c3": _sign(r) * r.uniform(2e-8, 6e-8)},
    "thermal_rate": lambda r: {"k": _sign(r) * r.uniform(2.5e-3, 6e-3)},
    "thermal_lag": lambda r: {"tau_s": r.uniform(300.0, 1800.0)},
    "hysteresis": lambda r: {"h": _sign(r) * r.uniform(1.5e-3, 4e-3), "width_c": r.uniform(0.5, 2)},
    "warmup": lambda r: {"A": _sign(r) * r.uniform(3e-3, 1e-2), "tau_s": r.uniform(300, 1800)},
    "aging_ramp": lambda r: {"r": _sign(r) * r.uniform(2e-4, 5e-4)},
    "periodic": lambda r: {
        "A": r.uniform(3e-4, 2e-3),
        "period_s": r.uniform(300.0, 2400.0),
        "phase_rad": r.uniform(-np.pi, np.pi),
    },
    # stochastic / sample-level terms
    "rate_random_walk": lambda r: {"K": r.uniform(2.0, 6.0)},
    "quantization": lambda r: {"q": r.uniform(2e-3, 1e-2)},
    "outliers": lambda r: {"rate_per_h": r.uniform(10.0, 60.0), "amplitude": r.uniform(0.05, 0.5)},
    # thermal channels
    "oven_overshoot": lambda r: {
        "overshoot": r.uniform(0.05, 0.3),
        "period_s": r.uniform(600, 2400),
    },
    "rtd_self_heating": lambda r: {"offset_c": r.uniform(0.1, 0.5)},
}

PAIRS = [
    ("thermal_rate", "periodic"),
    ("warmup", "outliers"),
    ("hysteresis", "oven_overshoot"),
    ("aging_ramp", "quantization"),
    ("cubic_temp", "rtd_self_heating"),
    ("thermal_lag", "rate_random_walk"),
]


def one_run(
    hidden: list[str], seed: int, rate_hz: float, profile: str = "paper"
) -> dict[str, object]:
    """Simulate truth = nominal + ``hidden`` and run the workflow on it."""
    rng = np.random.default_rng([seed, *[len(h) for h in hidden], 8])
    model = nominal_model()
    params = {}
    for h in hidden:
        params[h] = RANGES[h](rng)
        model = model.with_effect(h, **params[h])
    t0 = time.perf_counter()
    data = simulate_bench(model, load_profile(profile), rate_hz=rate_hz, seed=seed)
    t1 = time.perf_counter()
    res = run_discrepancy(data)
    t2 = time.perf_counter()
    named = set(res.effects_found) | {e for s in res.ambiguous if len(s) <= 3 for e in s}
    shrink = {}
    for h in hidden:
        key = PRIMARY_GAP[h]
        b, a = res.gap_before[key], res.gap_after[key]
        shrink[h] = {"metric": key, "before": b, "after": a, "shrink": 1.0 - a / b if b else 0.0}
    return {
        "hidden": hidden,
        "seed": seed,
        "params": params,
        "effects_found": res.effects_found,
        "ambiguous": res.ambiguous,
        "named_ok": {h: h in named for h in hidden},
        "gap": shrink,
        "gap_before": res.gap_before,
        "gap_after": res.gap_after,
        "sim_s": t1 - t0,
        "analysis_s": t2 - t1,
    }


def confusion_table(runs: list[dict]) -> str:
    """Markdown table: rows = hidden effect, columns = what was added (ambiguous sets in
    parentheses count under every member)."""
    single = [r for r in runs if len(r["hidden"]) <= 1]
    rows = sorted({r["hidden"][0] if r["hidden"] else "(nominal)" for r in single})
    cols = sorted({e for r in single for e in r["effects_found"]} | {"(nothing)"})
    lines = ["| truth \\ named | " + " | ".join(cols) + " | named ok | gap shrink ≥ 50 % |"]
    lines.append("|" + "---|" * (len(cols) + 3))
    for row in rows:
        rs = [r for r in single if (r["hidden"][0] if r["hidden"] else "(nominal)") == row]
        cells = []
        for c in cols:
            if c == "(nothing)":
                k = sum(1 for r in rs if not r["effects_found"])
            else:
                k = sum(1 for r in rs if c in r["effects_found"])
            cells.append(str(k) if k else "·")
        if row == "(nominal)":
            ok = sum(1 for r in rs if not r["effects_found"] and not r["ambiguous"])
            gap = "—"
        else:
            ok = sum(1 for r in rs if r["named_ok"][row])
            g = sum(1 for r in rs if r["gap"][row]["shrink"] >= 0.5)
            gap = f"{g}/{len(rs)}"
        lines.append(f"| {row} | " + " | ".join(cells) + f" | {ok}/{len(rs)} | {gap} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--nominal", type=int, default=10)
    ap.add_argument("--pairs", type=int, default=2, help="seeds per pair of effects")
    ap.add_argument("--rate", type=float, default=10.0, help="ADC rate, Hz (default 10)")
    ap.add_argument("--only", nargs="*", help="effects to run (default all)")
    ap.add_argument("--out", default="benchmarks/results/discrepancy_battery.json")
    a = ap.parse_args(argv)
    jobs: list[list[str]] = []
    for _ in range(a.nominal):
        jobs.append([])
    effects = a.only or list(RANGES)
    for e in effects:
        jobs += [[e]] * a.seeds
    for p in PAIRS if not a.only else []:
        jobs += [list(p)] * a.pairs
    runs = []
    seen: dict[tuple[str, ...], int] = {}
    for hidden in jobs:
        k = tuple(hidden)
        seed = seen.get(k, 0)
        seen[k] = seed + 1
        r = one_run(hidden, 100 + seed, a.rate)
        runs.append(r)
        ok = all(r["named_ok"].values()) if hidden else not r["effects_found"]
        print(
            f"{'+'.join(hidden) or 'nominal'} seed {seed}: found {r['effects_found']} "
            f"amb {r['ambiguous']} {'OK' if ok else 'MISS'} "
            f"gap {[round(g['shrink'], 2) for g in r['gap'].values()]} "
            f"({r['analysis_s']:.1f} s)",
            flush=True,
        )
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(runs, indent=1, default=float))
    print()
    print(confusion_table(runs))
    pairs = [r for r in runs if len(r["hidden"]) == 2]
    if pairs:
        both = sum(1 for r in pairs if all(r["named_ok"].values()))
        print(f"\npairs: both named in {both}/{len(pairs)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
