"""Issue 26's battery: self-heating on every profile, limits stable across seeds and a
calibrated promise, look-alike pairs on a short profile and the separating runs the
workflow proposes (docs/discrepancy.md, "Limits you can promise" and "Look-alike
effects").

Profiles (:data:`PROFILES`): ``paper`` (13 h cooling staircase), ``heating`` (it
reversed), ``random`` (random setpoints in −40…60 °C, 20–90 min each, 10 h), ``short28``
(a 2.8 h staircase 25 → 60 → 0 → −40 → 25 °C). Noise (:data:`NOISES`): ``sim`` (the
simulator's white + flicker), ``reallike`` (``reallike.py``: a resonance, a Gauss–Markov
hump, an output lattice), and ``adis`` (real static-record noise: pieces of five ADIS16405
records, benchmarks/data/README.md, scaled to the nominal ARW and averaged to the run's
rate, added to the noise-free simulated output).

Cells:

* ``nominal``: nominal runs (nothing hidden) for every profile × noise × seed: what is
  named (must be nothing) and the detection limits (their spread across seeds);
* ``selfheat``: ``rtd_self_heating`` at 0.3 °C (and ``--offsets``) on every profile ×
  noise;
* ``calib``: each effect of :data:`CALIB` at 2× and 0.5× the limit the nominal run of the
  same profile and noise with seed 900 states (at its reference shape), on other seeds;
* ``lookalike``: pairs that look alike on ``short28`` (:data:`LOOKALIKE`); for every
  ambiguous set with a proposed profile, the truth is simulated on that profile (another
  seed) and analysed again (``separated``: the truth named and no set holds the other).

Every run is cached in ``--out`` (JSON lines) and skipped when there; runs go ``nice``
and in ``--workers`` processes. ``--table`` prints the Markdown tables of a results file.

    nice -n 10 python benchmarks/discrepancy_limits.py --cells nominal selfheat \\
        --seeds 4 --workers 2 --out benchmarks/results/discrepancy_limits.jsonl
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

os.environ.setdefault("GYROLAB_NO_PROGRESS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from breakfam.realnoise import real_noise  # noqa: E402

from gyrolab.profiles.profile import BUILTIN, Profile, Step, profile_from_dict  # noqa: E402
from gyrolab.sim.discrepancy.identify import SEPARATION as SEP  # noqa: E402
from gyrolab.sim.discrepancy.reallike import RealLike, digital_output  # noqa: E402
from gyrolab.sim.discrepancy.synth import simulate_bench  # noqa: E402
from gyrolab.sim.discrepancy.workflow import run_discrepancy  # noqa: E402
from gyrolab.sim.effects import overshoot_period_s  # noqa: E402
from gyrolab.sim.model import nominal_model  # noqa: E402


def _random_profile() -> Profile:
    rng = np.random.default_rng([77, 1])
    steps, total = [Step(25.0, 3600.0, "power-on")], 3600.0
    while total < 10 * 3600.0:
        d = float(rng.uniform(20, 90)) * 60.0
        steps.append(Step(float(np.round(rng.uniform(-40, 60), 1)), d, "random"))
        total += d
    return Profile("random", tuple(steps), description="random setpoints, 20-90 min each")


PROFILES: dict[str, Profile] = {
    "paper": BUILTIN["paper"],
    "heating": BUILTIN["paper"].reversed("heating"),
    "random": _random_profile(),
    "short28": Profile(
        "short28",
        tuple(
            Step(sp, d)
            for sp, d in [(25.0, 1800.0), (60.0, 2400.0), (0.0, 2400.0), (-40.0, 2400.0)]
        )
        + (Step(25.0, 1080.0),),
        description="a 2.8 h staircase",
    ),
}
CALIB = [
    "cubic_temp",
    "thermal_rate",
    "thermal_lag",
    "hysteresis",
    "warmup",
    "aging_ramp",
    "periodic",
    "rate_random_walk",
    "rtd_self_heating",
    "oven_overshoot",
]
LOOKALIKE: dict[str, dict[str, dict[str, float]]] = {
    "lag 120 s": {"thermal_lag": {"tau_s": 120.0}},
    "lag 186 s": {"thermal_lag": {"tau_s": 186.0}},
    "hysteresis": {"hysteresis": {"h": 1.5e-3, "width_c": 1.0}},
    "lag + hysteresis": {
        "thermal_lag": {"tau_s": 400.0},
        "hysteresis": {"h": 2e-3, "width_c": 1.0},
    },
    "aging": {"aging_ramp": {"r": 6e-4}},
    "warmup (slow)": {"warmup": {"A": 5e-3, "tau_s": 1500.0}},
    "warmup + aging": {"warmup": {"A": 6e-3, "tau_s": 900.0}, "aging_ramp": {"r": 8e-4}},
    "rate": {"thermal_rate": {"k": 1.2e-3}},
    "rate + aging": {"thermal_rate": {"k": 2e-3}, "aging_ramp": {"r": 8e-4}},
}
REF_SEED = 900


def real_noise_post(seed: int):
    """A post-transform adding real static-record noise (``breakfam.realnoise``: pieces of
    five ADIS16405 records at 10 Hz, benchmarks/data/README.md, scaled to the nominal
    model's ARW) to the noise-free simulated rate, block-averaged to the run's rate."""
    arw = float(nominal_model().get("arw").params["N"])

    def post(rate: np.ndarray, dt: float) -> np.ndarray:
        k = max(1, int(round(10.0 * dt)))
        x = real_noise(rate.size * k, arw, np.random.default_rng([26, seed]))
        return rate + x.reshape(-1, k).mean(axis=1)

    return post


def _model(noise: str, effects: dict[str, dict[str, float]]):
    m = nominal_model()
    if noise != "sim":  # the record brings the noise
        m = m.with_effect("arw", N=0.0).with_effect("bias_instability", B=0.0)
    for k, v in effects.items():
        m = m.with_effect(k, **v)
    return m


def _post(noise: str, rate: float, seed: int):
    if noise == "reallike":
        sw = RealLike().n_arw / 60.0 * math.sqrt(rate)
        return digital_output(RealLike(lattice_q=0.05 * sw), seed)
    if noise == "adis":
        return real_noise_post(seed)
    return None


def analyse(profile: Profile, noise: str, effects: dict, seed: int, rate: float) -> dict:
    """Simulate and analyse one run; the outcome as a JSON-able dict."""
    t0 = time.process_time()
    data = simulate_bench(_model(noise, effects), profile, rate, seed, _post(noise, rate, seed))
    res = run_discrepancy(data)
    return {
        "effects_found": res.effects_found,
        "ambiguous": res.ambiguous,
        "detection_limits": res.detection_limits,
        "ambiguity": [a.to_json() for a in res.ambiguity],
        "proposals": [a.proposal.profile.to_dict() for a in res.ambiguity if a.proposal],
        "fitted": {n: res.model.get(n).params for n in res.effects_found},
        "cpu_s": time.process_time() - t0,
    }


def _limit_params(entry: dict, factor: float, effect: str) -> dict[str, float]:
    p = {entry["parameter"]: factor * entry["limit"]}
    for k, v in entry.get("at", {}).items():
        if k == "mean_delay_s":  # oven_overshoot: as fast as the first-order chamber
            p["period_s"] = overshoot_period_s(p["overshoot"], v)
        else:
            p[k] = v
    if effect == "periodic":
        p["phase_rad"] = 0.7
    return p


def run_job(job: dict[str, Any]) -> dict[str, Any]:
    """One battery job (module docstring)."""
    prof = PROFILES[job["profile"]]
    out = dict(job)
    if job["cell"] == "calib":
        ref = run_job({**job, "cell": "nominal", "seed": REF_SEED, "effects": {}})
        entry = ref["detection_limits"].get(job["effect"])
        if not entry or entry["limit"] is None:
            return {**out, "skipped": "no limit"}
        job = {
            **job,
            "effects": {job["effect"]: _limit_params(entry, job["factor"], job["effect"])},
        }
        out["effects"] = job["effects"]
        out["limit"] = entry["limit"]
    key = json.dumps([job["profile"], job["noise"], job["effects"], job["seed"], job["rate"]])
    cache = _CACHE.get(key)
    res = (
        cache
        if cache is not None
        else analyse(prof, job["noise"], job["effects"], job["seed"], job["rate"])
    )
    _CACHE[key] = res
    out.update(res)
    hidden = list(job["effects"])
    amb = {e for s in res["ambiguous"] for e in s}
    out["status"] = {
        h: "named" if h in res["effects_found"] else "ambiguous" if h in amb else "missed"
        for h in hidden
    }
    out["false"] = sorted(
        {e for e in res["effects_found"] if e not in hidden and e not in amb}
        | {e for s in res["ambiguous"] if not set(s) & set(hidden) for e in s}
    )
    if job["cell"] == "lookalike" and res["proposals"]:
        sep = []
        for k, pd in enumerate(res["proposals"]):
            p2 = profile_from_dict(pd, "proposal")
            r2 = analyse(p2, job["noise"], job["effects"], job["seed"] + 1000 + k, job["rate"])
            amb2 = [s for s in r2["ambiguous"] if set(s) & set(hidden)]
            sep.append(
                {
                    "profile": pd["name"],
                    "duration_h": p2.duration_s / 3600.0,
                    "effects_found": r2["effects_found"],
                    "ambiguous": r2["ambiguous"],
                    "separated": all(h in r2["effects_found"] for h in hidden)
                    and not [s for s in amb2 if len(s) > 1],
                }
            )
        out["separating_runs"] = sep
    return out


_CACHE: dict[str, dict] = {}


def jobs(a: argparse.Namespace) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = []
    base = {"rate": a.rate}
    for prof in a.profiles:
        for noise in a.noises:
            if "nominal" in a.cells:
                for s in range(a.seeds):
                    out.append(
                        {
                            **base,
                            "cell": "nominal",
                            "profile": prof,
                            "noise": noise,
                            "effects": {},
                            "seed": 100 + s,
                        }
                    )
            if "selfheat" in a.cells:
                for off in a.offsets:
                    for s in range(a.selfheat_seeds):
                        out.append(
                            {
                                **base,
                                "cell": "selfheat",
                                "profile": prof,
                                "noise": noise,
                                "effects": {"rtd_self_heating": {"offset_c": off}},
                                "seed": 200 + s,
                            }
                        )
            if "calib" in a.cells:
                for e in a.effects or CALIB:
                    for f in (2.0, 0.5):
                        for s in range(a.calib_seeds):
                            out.append(
                                {
                                    **base,
                                    "cell": "calib",
                                    "profile": prof,
                                    "noise": noise,
                                    "effect": e,
                                    "factor": f,
                                    "effects": {},
                                    "seed": 300 + s,
                                }
                            )
    if "lookalike" in a.cells:
        for label, eff in LOOKALIKE.items():
            for noise in a.noises:
                for s in range(a.lookalike_seeds):
                    out.append(
                        {
                            **base,
                            "cell": "lookalike",
                            "profile": "short28",
                            "noise": noise,
                            "label": label,
                            "effects": eff,
                            "seed": 400 + s,
                        }
                    )
    return out


def job_key(j: dict) -> str:
    return json.dumps(
        {k: j[k] for k in ("cell", "profile", "noise", "seed", "rate")}
        | {
            "e": j.get("effect"),
            "f": j.get("factor"),
            "l": j.get("label"),
            "x": j.get("effects") if j["cell"] != "calib" else None,
        },
        sort_keys=True,
    )


def tables(rows: list[dict]) -> str:
    """The Markdown tables of docs/discrepancy.md from the battery's rows."""
    lines = []
    nom = [r for r in rows if r["cell"] == "nominal"]
    if nom:
        lines += [
            "| profile | noise | runs | false names | limit spread max/min (worst effect) |",
            "|---|---|---|---|---|",
        ]
        for p, n in sorted({(r["profile"], r["noise"]) for r in nom}):
            rs = [r for r in nom if r["profile"] == p and r["noise"] == n]
            fal = sum(1 for r in rs if r["effects_found"] or r["ambiguous"])
            spread = {}
            for e in rs[0]["detection_limits"]:
                v = [
                    r["detection_limits"][e]["limit"]
                    for r in rs
                    if r["detection_limits"].get(e, {}).get("limit")
                ]
                if len(v) >= 2:
                    spread[e] = max(v) / min(v)
            worst = max(spread.items(), key=lambda kv: kv[1]) if spread else ("—", float("nan"))
            lines.append(f"| {p} | {n} | {len(rs)} | {fal} | {worst[1]:.2f} ({worst[0]}) |")
        lines.append("")
    sh = [r for r in rows if r["cell"] == "selfheat"]
    if sh:
        lines += [
            "| profile | noise | offset °C | named | fitted offset °C |",
            "|---|---|---|---|---|",
        ]
        for r in sorted(sh, key=lambda r: (r["profile"], r["noise"], r["seed"])):
            off = r["effects"]["rtd_self_heating"]["offset_c"]
            fit = r.get("fitted", {}).get("rtd_self_heating", {}).get("offset_c")
            lines.append(
                f"| {r['profile']} | {r['noise']} | {off:g} | {r['status']['rtd_self_heating']} "
                f"| {'' if fit is None else f'{fit:.3f}'} |"
            )
        lines.append("")
    cal = [r for r in rows if r["cell"] == "calib" and not r.get("skipped")]
    if cal:
        lines += ["| effect | named at 2× limit | named at 0.5× limit |", "|---|---|---|"]
        for e in sorted({r["effect"] for r in cal}):
            rs = [r for r in cal if r["effect"] == e]
            for_f = {}
            for f in (2.0, 0.5):
                x = [r["status"][e] != "missed" for r in rs if r["factor"] == f]
                for_f[f] = f"{sum(x)}/{len(x)}"
            lines.append(f"| {e} | {for_f[2.0]} | {for_f[0.5]} |")
        x2 = [r["status"][r["effect"]] != "missed" for r in cal if r["factor"] == 2.0]
        x5 = [r["status"][r["effect"]] != "missed" for r in cal if r["factor"] == 0.5]
        lines.append(f"| **all** | **{sum(x2)}/{len(x2)}** | **{sum(x5)}/{len(x5)}** |")
        lines.append("")
    la = [r for r in rows if r["cell"] == "lookalike"]
    if la:
        lines += [
            "| truth | noise | seed | named | ambiguous | truth covered | proposed | separated |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for r in la:
            cov = all(s != "missed" for s in r["status"].values())
            sep = r.get("separating_runs") or []
            props = [a["proposed_profile"] for a in r["ambiguity"] if a.get("proposed_profile")]
            expect = [
                ""
                if p.get("expected_to_separate", min(p["expected_separation"].values()) >= SEP)
                else ", not expected to separate"
                for p in props
            ] + [""] * len(sep)
            prop = (
                ", ".join(
                    f"{s['profile']} ({s['duration_h']:.1f} h{e})"
                    for s, e in zip(sep, expect, strict=False)
                )
                or "—"
            )
            hid = set(r["effects"])

            def extra(s: dict, hid: set = hid) -> str:
                """Names in a separating run with no hidden effect in them."""
                f = [e for e in s["effects_found"] if e not in hid]
                f += [str(a) for a in s["ambiguous"] if not set(a) & hid]
                return f" (false: {', '.join(f)})" if f else ""

            ok = (
                ", ".join(
                    "yes" + extra(s)
                    if s["separated"]
                    else f"no: {s['effects_found']} {s['ambiguous']}"
                    for s in sep
                )
                or "—"
            )
            named = ", ".join(r["effects_found"]) or "—"
            if not cov:  # what the run itself said of what it missed: truth / its limit
                miss = []
                for h, st in r["status"].items():
                    lim = r["detection_limits"].get(h, {})
                    par = lim.get("parameter")
                    size = r["effects"][h].get(par) if par else None
                    if st == "missed" and lim.get("limit") and size is not None:
                        miss.append(f"{h} at {abs(size) / lim['limit']:.1f}× its limit")
                cov = "no: " + ", ".join(miss) if miss else "no"
            lines.append(
                f"| {r['label']} | {r['noise']} | {r['seed']} | {named} "
                f"| {r['ambiguous'] or '—'} | {'yes' if cov is True else cov} | {prop} | {ok} |"
            )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", nargs="+", default=["nominal", "selfheat", "calib", "lookalike"])
    ap.add_argument("--profiles", nargs="+", default=list(PROFILES))
    ap.add_argument("--noises", nargs="+", default=["sim", "adis"])
    ap.add_argument("--seeds", type=int, default=4, help="nominal runs per profile and noise")
    ap.add_argument("--selfheat-seeds", type=int, default=1)
    ap.add_argument("--offsets", type=float, nargs="+", default=[0.3])
    ap.add_argument("--calib-seeds", type=int, default=1)
    ap.add_argument("--lookalike-seeds", type=int, default=2)
    ap.add_argument("--effects", nargs="*", help=f"calib effects (default {CALIB})")
    ap.add_argument("--rate", type=float, default=2.0, help="ADC rate, Hz (default 2)")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--out", default="benchmarks/results/discrepancy_limits.jsonl")
    ap.add_argument("--table", action="store_true", help="only print the tables of --out")
    a = ap.parse_args(argv)
    out = Path(a.out)
    rows = [json.loads(ln) for ln in out.read_text().splitlines()] if out.exists() else []
    if a.table:
        print(tables(rows))
        return 0
    for r in rows:  # reuse every analysed run (a calib job's reference run too)
        if r["cell"] == "nominal":
            _CACHE[json.dumps([r["profile"], r["noise"], r["effects"], r["seed"], r["rate"]])] = r
    done = {job_key(r) for r in rows}
    todo = [j for j in jobs(a) if job_key(j) not in done]
    # the calibration's reference runs first, once each
    refs = {(j["profile"], j["noise"]) for j in todo if j["cell"] == "calib"}
    pre = [
        {
            "cell": "nominal",
            "profile": p,
            "noise": n,
            "effects": {},
            "seed": REF_SEED,
            "rate": a.rate,
        }
        for p, n in sorted(refs)
    ]
    todo = [j for j in pre if job_key(j) not in done] + todo
    print(f"{len(rows)} runs on file, {len(todo)} to go", flush=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    if a.workers > 1:
        from multiprocessing import get_context

        pool = get_context("fork").Pool(a.workers)
        n_ref = len([j for j in pre if job_key(j) not in done])
        it = list(pool.imap_unordered(run_job, todo[:n_ref]))
        for r in it:
            _CACHE[json.dumps([r["profile"], r["noise"], r["effects"], r["seed"], r["rate"]])] = r
            with out.open("a") as fh:
                fh.write(json.dumps(r, default=float) + "\n")
        pool.close()
        pool = get_context("fork").Pool(a.workers)  # the workers inherit the references
        results = pool.imap_unordered(run_job, todo[n_ref:])
    else:
        results = map(run_job, todo)
    for r in results:
        with out.open("a") as fh:
            fh.write(json.dumps(r, default=float) + "\n")
        print(
            f"{r['cell']} {r['profile']} {r['noise']} {r.get('label') or r.get('effect') or ''} "
            f"×{r.get('factor', '')} seed {r['seed']}: found {r.get('effects_found')} "
            f"amb {r.get('ambiguous')} status {r.get('status')} "
            f"({r.get('cpu_s', 0):.0f} s cpu)",
            flush=True,
        )
    rows = [json.loads(ln) for ln in out.read_text().splitlines()]
    print(tables(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
