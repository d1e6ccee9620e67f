"""Discrepancy battery: hide vocabulary effects (one, two or three at once) in simulated
oven runs and check that ``gyrolab discrepancy`` names them (docs/discrepancy.md, issues 8
and 18).

Cells (each run goes through the same reduction as a recording: ``synth.simulate_bench``
→ ``data.from_arrays``; the workflow starts from the nominal model):

* ``nominal``: nominal-only runs, which must name nothing;
* ``single``: every effect a static oven test can reveal, parameters drawn from the
  realistic ranges of :data:`RANGES` (a sign too where the effect has one), plus the
  wider forms within a name (:data:`FORMS`: a warm-up of two exponentials of opposite
  sign, a hysteresis whose width depends on temperature);
* ``pair`` / ``triple``: gyro-side and thermal-chain effects mixed (:data:`PAIRS`,
  :data:`TRIPLES`);
* ``weak``: an effect injected at 2× and at 0.5× the detection limit that a nominal run
  of the same configuration (seed 900) states for it (``detection_limits``);
* ``reallike``: static noise with a resonance, a Gauss–Markov hump at long τ and an
  output lattice seen only in the first differences (``reallike.py``) instead of the
  simulator's white + flicker, nominal and with an aging ramp / a cubic term at the
  middle of their ranges.

Scoring per hidden effect: **named** (in ``effects_found``), **ambiguous** (in an
``ambiguous`` set of at most three), **missed**; per run, **false** effects (named, or an
ambiguous set, with no hidden member).

    python benchmarks/discrepancy_battery.py --seeds 3 --nominal 6 --pairs 2 --triples 1 \
        --workers 2 --out benchmarks/results/discrepancy_battery.json

prints the tables in Markdown and writes every run's outcome.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

os.environ.setdefault("GYROLAB_NO_PROGRESS", "1")
# run against this checkout, not whatever gyrolab happens to be installed
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gyrolab.profiles.profile import load_profile  # noqa: E402
from gyrolab.sim.discrepancy.catalogue import gap_of  # noqa: E402
from gyrolab.sim.discrepancy.reallike import RealLike, digital_output  # noqa: E402
from gyrolab.sim.discrepancy.synth import simulate_bench  # noqa: E402
from gyrolab.sim.discrepancy.workflow import run_discrepancy  # noqa: E402
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

FORMS: dict[str, tuple[str, Sampler]] = {
    "warmup (2 exp, opposite signs)": (
        "warmup",
        lambda r: {
            "A": -r.uniform(3e-3, 5e-3),
            "tau_s": r.uniform(1500.0, 2500.0),
            "A2": r.uniform(4e-3, 6e-3),
            "tau2_s": r.uniform(200.0, 400.0),
        },
    ),
    "hysteresis (width(T))": (
        "hysteresis",
        lambda r: {
            "h": _sign(r) * r.uniform(2e-3, 4e-3),
            "width_c": r.uniform(1.0, 2.0),
            "width_tc": r.uniform(0.01, 0.02),
        },
    ),
}

PAIRS = [
    ("thermal_rate", "periodic"),
    ("hysteresis", "aging_ramp"),
    ("thermal_lag", "periodic"),
    ("cubic_temp", "rtd_self_heating"),
    ("hysteresis", "oven_overshoot"),
    ("warmup", "rtd_self_heating"),
    ("aging_ramp", "quantization"),
    ("thermal_rate", "oven_overshoot"),
]
TRIPLES = [
    ("cubic_temp", "warmup", "rtd_self_heating"),
    ("thermal_rate", "aging_ramp", "oven_overshoot"),
    ("hysteresis", "periodic", "rtd_self_heating"),
    ("thermal_lag", "aging_ramp", "outliers"),
]
WEAK = ["aging_ramp", "cubic_temp", "thermal_rate", "warmup", "periodic", "hysteresis"]
WEAK += ["rtd_self_heating"]
REALLIKE = {
    "(nominal)": {},
    "aging_ramp": {"aging_ramp": {"r": 3.5e-4}},
    "cubic_temp": {"cubic_temp": {"c3": 4e-8}},
}


def reallike_model(extra: dict[str, dict[str, float]]):
    """The nominal model with its own white and flicker noise off (the real-like record
    brings the noise), plus ``extra``."""
    m = nominal_model().with_effect("arw", N=0.0).with_effect("bias_instability", B=0.0)
    for k, v in extra.items():
        m = m.with_effect(k, **v)
    return m


def one_run(job: dict[str, Any]) -> dict[str, Any]:
    """Simulate one battery job (``cell``, ``hidden``, ``seed``, optional ``params`` /
    ``reallike``) and run the workflow on it."""
    hidden: list[str] = job["hidden"]
    seed: int = job["seed"]
    rng = np.random.default_rng([seed, *[len(h) for h in hidden], 8])
    params: dict[str, dict[str, float]] = {}
    post = None
    if job.get("reallike") is not None:
        model = reallike_model(job["params"])
        params = job["params"]
        dt = 1.0 / job["rate"]
        sw = RealLike().n_arw / 60.0 / np.sqrt(dt)
        post = digital_output(RealLike(lattice_q=0.05 * sw), seed)
    else:
        model = nominal_model()
        for h in hidden:
            if h in job.get("params", {}):
                params[h] = job["params"][h]
            elif job.get("form"):
                params[h] = FORMS[job["form"]][1](rng)
            else:
                params[h] = RANGES[h](rng)
            model = model.with_effect(h, **params[h])
    t0 = time.perf_counter()
    data = simulate_bench(model, load_profile(job.get("profile", "paper")), job["rate"], seed, post)
    t1 = time.perf_counter()
    res = run_discrepancy(data)
    t2 = time.perf_counter()
    amb_members = {e for s in res.ambiguous if len(s) <= 3 for e in s}
    status = {}
    for h in hidden:
        status[h] = (
            "named" if h in res.effects_found else "ambiguous" if h in amb_members else "missed"
        )
    false = [e for e in res.effects_found if e not in hidden and e not in amb_members]
    false += [e for s in res.ambiguous if not set(s) & set(hidden) for e in s]
    # an effect named that belongs to an ambiguous set with a hidden member is ambiguous,
    # not false; one named outside any such set is false
    false = sorted(set(false) - set(hidden))
    shrink = {}
    for h in hidden:
        key = gap_of(h)
        b, a = res.gap_before[key], res.gap_after[key]
        shrink[h] = {"metric": key, "before": b, "after": a, "shrink": 1.0 - a / b if b else 0.0}
    return {
        **{k: v for k, v in job.items() if k != "params"},
        "params": params,
        "effects_found": res.effects_found,
        "ambiguous": res.ambiguous,
        "status": status,
        "named_ok": {h: status[h] != "missed" for h in hidden},
        "false": false,
        "gap": shrink,
        "gap_before": res.gap_before,
        "gap_after": res.gap_after,
        "detection_limits": res.detection_limits,
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


def score_table(runs: list[dict]) -> str:
    """Markdown: per cell and truth, hidden effects named / ambiguous / missed, runs with
    a false effect, and the hidden effects' own gaps shrinking ≥ 50 %."""
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in runs:
        label = r.get("form") or (" + ".join(r["hidden"]) or "(nominal)")
        if r["cell"] == "weak":
            label = f"{r['hidden'][0]} at {r['factor']:g}× limit"
        groups.setdefault((r["cell"], label), []).append(r)
    lines = [
        "| cell | truth | runs | named | ambiguous | missed | runs with a false effect "
        "| all hidden found | own gap shrink ≥ 50 % |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for (cell, label), rs in groups.items():
        st = [s for r in rs for s in r["status"].values()]
        n_named, n_amb = st.count("named"), st.count("ambiguous")
        n_miss = st.count("missed")
        n_false = sum(1 for r in rs if r["false"])
        allf = sum(1 for r in rs if r["hidden"] and all(r["named_ok"].values()))
        gaps = [g["shrink"] >= 0.5 for r in rs for g in r["gap"].values()]
        lines.append(
            f"| {cell} | {label} | {len(rs)} | {n_named} | {n_amb} | {n_miss} | {n_false} "
            f"| {f'{allf}/{len(rs)}' if rs[0]['hidden'] else '—'} "
            f"| {f'{sum(gaps)}/{len(gaps)}' if gaps else '—'} |"
        )
    return "\n".join(lines)


def job_key(j: dict[str, Any]) -> tuple:
    """Identity of a battery job (for --resume)."""
    return (
        j["cell"],
        tuple(j["hidden"]),
        j["seed"],
        j.get("form"),
        j.get("factor"),
        j.get("reallike"),
    )


def weak_jobs(
    rate: float, seeds: int, profile: str, effects: list[str] | None = None
) -> list[dict[str, Any]]:
    """2× and 0.5× the limits a nominal run (seed 900) states, on other seeds."""
    cache = Path(os.environ.get("GYROLAB_BATTERY_WEAKREF", "/nonexistent"))
    if cache.is_file():
        lim = json.loads(cache.read_text())
    else:
        ref = one_run(
            {"cell": "weak-ref", "hidden": [], "seed": 900, "rate": rate, "profile": profile}
        )
        lim = ref["detection_limits"]
        if cache.parent.is_dir():
            cache.write_text(json.dumps(lim, default=float))
    jobs = []
    for e in effects or WEAK:
        entry = lim.get(e)
        if not entry or entry["limit"] is None:
            continue
        for factor in (2.0, 0.5):
            for s in range(seeds):
                p = {entry["parameter"]: factor * entry["limit"], **entry.get("at", {})}
                if e == "periodic":
                    p["phase_rad"] = 0.7
                jobs.append(
                    {
                        "cell": "weak",
                        "hidden": [e],
                        "seed": 910 + s,
                        "rate": rate,
                        "profile": profile,
                        "factor": factor,
                        "limit": entry["limit"],
                        "params": {e: p},
                    }
                )
    return jobs


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3, help="runs per single effect")
    ap.add_argument("--nominal", type=int, default=6)
    ap.add_argument("--pairs", type=int, default=2, help="seeds per pair of effects")
    ap.add_argument("--triples", type=int, default=1, help="seeds per triple")
    ap.add_argument("--forms", type=int, default=2, help="seeds per wider form")
    ap.add_argument("--weak", type=int, default=1, help="seeds per effect and factor")
    ap.add_argument("--reallike", type=int, default=2, help="seeds per real-like cell")
    ap.add_argument("--rate", type=float, default=10.0, help="ADC rate, Hz (default 10)")
    ap.add_argument("--only", nargs="*", help="single effects to run (default all)")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--profile", default="paper", help="profile (default: the paper's 13 h)")
    ap.add_argument("--table", help="only print the tables of an existing results file")
    ap.add_argument("--resume", action="store_true", help="keep the runs already in --out")
    ap.add_argument("--weak-effects", nargs="*", help=f"effects of the weak cell ({WEAK})")
    ap.add_argument("--out", default="benchmarks/results/discrepancy_battery.json")
    a = ap.parse_args(argv)
    jobs: list[dict[str, Any]] = []

    def add(cell: str, hidden: list[str], n: int, **extra: Any) -> None:
        for s in range(n):
            jobs.append(
                {
                    "cell": cell,
                    "hidden": hidden,
                    "seed": 100 + s,
                    "rate": a.rate,
                    "profile": a.profile,
                    **extra,
                }
            )

    if a.table:
        runs = json.loads(Path(a.table).read_text())
        print(score_table(runs))
        print()
        print(confusion_table([r for r in runs if r["cell"] in ("nominal", "single")]))
        return 0
    # acceptance-critical cells first: the results file is rewritten after every run, so
    # a battery cut short still leaves every finished run on disk (and --resume reuses it)
    add("nominal", [], a.nominal)
    for e in a.only or list(RANGES):
        add("single", [e], a.seeds)
    if not a.only:
        for p in PAIRS:
            add("pair", list(p), a.pairs)
        for label, extra in REALLIKE.items():
            n = a.reallike + (1 if not extra else 0)
            add("reallike", list(extra), n, reallike=label, params=extra)
        if a.weak:
            jobs += weak_jobs(a.rate, a.weak, a.profile, a.weak_effects)
        for t in TRIPLES:
            add("triple", list(t), a.triples)
        for f, (e, _) in FORMS.items():
            add("single", [e], a.forms, form=f)
    runs: list[dict[str, Any]] = []
    if a.resume and Path(a.out).exists():
        runs = json.loads(Path(a.out).read_text())
        done = {job_key(r) for r in runs}
        jobs = [j for j in jobs if job_key(j) not in done]
        print(f"resuming: {len(runs)} runs on file, {len(jobs)} to go", flush=True)
    n_jobs = len(runs) + len(jobs)
    t_all = time.perf_counter()
    if a.workers > 1:
        from multiprocessing import get_context

        pool = get_context("fork").Pool(a.workers)
        it = pool.imap_unordered(one_run, jobs)
    else:
        it = map(one_run, jobs)
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    for r in it:
        runs.append(r)
        tmp = out.with_suffix(".tmp")
        tmp.write_text(json.dumps(runs, indent=1, default=float))
        os.replace(tmp, out)
        ok = all(r["named_ok"].values()) and not r["false"]
        print(
            f"[{len(runs)}/{n_jobs}] {r['cell']} {'+'.join(r['hidden']) or 'nominal'} "
            f"seed {r['seed']}{' ×' + str(r['factor']) if 'factor' in r else ''}: "
            f"found {r['effects_found']} amb {r['ambiguous']} false {r['false']} "
            f"{'OK' if ok else 'MISS'} ({r['analysis_s']:.1f} s)",
            flush=True,
        )
    print(f"\n{len(runs)} runs in {time.perf_counter() - t_all:.0f} s\n")
    print(score_table(runs))
    print()
    print(confusion_table([r for r in runs if r["cell"] in ("nominal", "single")]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
