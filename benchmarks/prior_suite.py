"""Chamber time (issue 30): a unit calibrated in 3.25 h with a fleet prior learned from
the other units only (leave-unit-out), against the same unit's 13 h calibration, on both
validation families, held out on the same trajectories.

    python benchmarks/prior_suite.py [--units 8] [--workers 2] [--families validation,break]
                                     [--held N] [--out docs/results.md] [--tables-only]
                                     [--quick quick|P.toml|design[:WEIGHT[:SETPOINT_MAX]]]
                                     [--fleet N] [--temperature pt100|internal]

**Families.** ``validation``: gyrolab's own Monte-Carlo family
(benchmarks/validation_suite.py: ``unit_model``, simulated by gyrolab's simulator, 13 h
calibration on ``paper``). ``break``: the independent break-the-model family
(benchmarks/breakfam: its own thermal network, physics and noise, half with real ADIS16405
noise; 13 h calibration on its ``staircase``; the quick profile's setpoints run through
its own chamber model, on the calibration day).

**Per unit u** of a family (stage 1 for every unit, then stage 2):

1. *13 h*: gyrolab's causal selection (``fit_causal``, families poly and structured — the
   linear families the prior is over; the networks are left out to keep the suite inside
   the shared machine's budget) on the 13 h calibration run.
2. *quick + prior*: a prior learned from the other units' 13 h models only
   (:func:`gyrolab.compensation.prior.learn_prior`), the unit's 3.25 h ``quick`` run
   fitted by :func:`~gyrolab.compensation.prior.fit_map` — with its membership verdict.
3. *quick alone*: the same selection as 1 on the quick run, no prior (what the prior buys).

All three and the oracle (the output minus the true deterministic drift) are applied
causally at 10 Hz to the same held-out trajectories (``--held`` of them, in the families'
order). **Another part number**: every unit's quick run is also tested against the prior
of all units of the *other* family (it should be refused).

Scoring: bias stability (std of 3.6 s means, °/h) and 100 s p-p (breakfam.score, the
break family's own scorer, for both families). **What the tool says of each held-out
run** of the quick + prior model: gyrolab's range guard (a run beyond the quick run's
case range by more than the margin is flagged: ``guards.outside_fraction``; how far beyond
the quick and the 13 h run's ranges) and its graded expected error (the model's band:
``band.band_metrics``; ``severe`` = more than 2× the calibrated error). A refused unit
is reported as the lab runs it: recalibrated on the 13 h profile (ratio 1 by
construction), its chamber hours counted. Per-unit results are cached in
``benchmarks/results/prior_suite/`` (the tables' data in ``results.json.gz``,
:mod:`runcache`; ``--tables-only`` re-renders them).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from breakfam.family import RATE_HZ  # noqa: E402  (both families run at the break family's rate)
from breakfam.score import score  # noqa: E402
from docsections import write_section  # noqa: E402
from runcache import load, save  # noqa: E402

CACHE = REPO / "benchmarks" / "results" / "prior_suite"
BLOCK_S = 3.6
BS, PP = "bias_stability_deg_per_h", "pp_100s_deg_per_s"
HELD = {
    "validation": ("heating", "ramp0.5", "ramp2", "random", "soak"),
    "break": ("heating", "random", "fastramp", "coldstart", "slowramp"),
}
CAL = {"validation": "paper", "break": "staircase"}
#: the models' temperature input: "pt100" (the case) or "internal" (the unit's own die
#: thermometer: gyrolab's DieThermometer for its family, breakfam.physics.die_sensor for
#: the break family; set by --temperature)
TEMP = "pt100"


def use_temperature(temp: str) -> None:
    """Set the models' temperature input (:data:`TEMP`) in this process; the pool's
    workers run it at start (its initializer), so the choice reaches them under any
    start method, not only fork."""
    global TEMP
    TEMP = temp


# ------------------------------------------------------------------------------ runs


class _Run:
    """t, raw, drift, pt_t, pt_c of one simulated run (both families)."""

    def __init__(self, t, raw, drift, pt_t, pt_c) -> None:  # noqa: ANN001
        self.t, self.raw, self.drift, self.pt_t, self.pt_c = t, raw, drift, pt_t, pt_c


def simulate(
    family: str, u: int, name: str, seed: int, other: bool = False, quick: Any = None
) -> _Run:
    """Run ``name`` (a trajectory of the family, or ``quick``) of unit ``u``; ``other``:
    the unit as *another part number* — its temperature slope and curvature reversed;
    ``quick``: the short profile run as ``quick`` (default the built-in one)."""
    from dataclasses import replace

    from gyrolab.profiles.profile import BUILTIN

    q = quick or BUILTIN["quick"]

    if family == "validation":
        import validation_suite as vs

        model, p = vs.unit_model(u)
        if other:
            c = {k: p.get(k, v) for k, v in (("c0", 0.0), ("c1", 3.84e-4), ("c2", 3.4e-6))}
            model = model.with_effect("bias_poly", c0=c["c0"], c1=-c["c1"], c2=-c["c2"])
        prof = q if name == "quick" else vs.trajectory(name, u)
        off = None
        if TEMP == "internal":  # the unit's die-sensor offset, the same on all its runs
            from gyrolab.sim.sensors import DieThermometer

            off = DieThermometer().offset_sd_c * np.random.default_rng([2026, u, 7]).normal()
        r = vs.simulate(model, prof, RATE_HZ, seed, die_offset_c=off)
        temp = r["pt_c"] if off is None else r["die_c"]
        return _Run(r["t"], r["raw"], r["drift"], r["pt_t"], temp)
    from breakfam.family import simulate_run, units

    unit = units(u + 1)[u]
    if other:
        unit = replace(unit, c=(unit.c[0], -unit.c[1], -unit.c[2], *unit.c[3:]))
    sp = None
    if name == "quick":
        sp = np.concatenate([np.full(int(s.duration_s), s.setpoint_c) for s in q.steps])
    r = simulate_run(unit, name, seed, setpoints=sp)
    return _Run(r.t, r.raw, r.drift, r.pt_t, r.die_sensor_c if TEMP == "internal" else r.pt_c)


def truth(family: str, u: int) -> dict[str, Any]:
    """What the family says of the unit's hysteresis (°/h, up − down) where it is known."""
    if family == "validation":
        import validation_suite as vs

        _, p = vs.unit_model(u)
        # gyrolab's hysteresis effect: bias ± h/2 on the two branches (sim/effects.py)
        return {"hysteresis_width_deg_per_h": 3600.0 * p.get("hyst_h", 0.0)}
    from breakfam.family import units

    unit = units(u + 1)[u]
    return {  # Σ h_i s_i with s_i = ±1 on the two branches (breakfam/physics.py)
        "hysteresis_width_deg_per_h": 7200.0 * float(sum(unit.h)),
        "effects": list(unit.effects),
    }


def calibration(run: _Run):
    from gyrolab.compensation.drift_model import CausalCalibration
    from gyrolab.numerics.averaging import block_average

    tb, xb, _ = block_average(run.t, run.raw, BLOCK_S, 1.0 / RATE_HZ)
    return CausalCalibration(t=tb, rate=xb, pt_t=run.pt_t, pt_c=run.pt_c)


def select(run: _Run):
    from gyrolab.compensation.causal import fit_causal

    return fit_causal(calibration(run), families=("poly", "structured"))


def _pair(cm) -> dict[str, Any]:  # noqa: ANN001
    """A fitted causal model (poly or structured) as JSON: its feature parameters and
    structured model."""
    return {"params": cm.params.to_dict(), "structured": cm.model.to_dict(), "family": cm.family}


def _entry(name: str, d: dict[str, Any]):  # noqa: ANN202
    from gyrolab.compensation.causal_features import CausalParams
    from gyrolab.compensation.prior import UnitEntry
    from gyrolab.compensation.structured import StructuredModel

    return UnitEntry(
        name, CausalParams.from_dict(d["params"]), StructuredModel.from_dict(d["structured"])
    )


def _drift(e, run: _Run) -> np.ndarray:  # noqa: ANN001
    """A unit entry's causal drift at the run's samples (°/s)."""
    from gyrolab.compensation.causal_features import hold, reading_features

    d = e.model.predict(reading_features(run.pt_t, run.pt_c, e.params))
    return hold(run.t, run.pt_t, d)


# ------------------------------------------------------------------------ stage 1, 2


def quick_profile(spec: str, prior: Any):  # noqa: ANN201
    """The short profile a unit is run on: ``quick`` (built in), a profile TOML, or
    ``design[:WEIGHT[:SETPOINT_MAX]]`` — ``gyrolab profile design --hours 3.25`` with the
    unit's leave-unit-out ``prior`` (WEIGHT: the design's ``weight``, default ``paper``;
    the setpoint limit, default 60 °C)."""
    from gyrolab.compensation.profile_design import design_profile
    from gyrolab.profiles.profile import load_profile

    kind, *opt = spec.split(":")
    if kind == "design":  # design[:WEIGHT[:SETPOINT_MAX]]
        weight = opt[0] if opt else "paper"
        top = float(opt[1]) if len(opt) > 1 else 60.0
        return design_profile(3.25, prior=prior, weight=weight, setpoint_max_c=top)[0]
    return load_profile(spec)


def stage1(family: str, u: int) -> dict[str, Any]:
    """Unit ``u``'s 13 h model and timing (cached: it does not depend on the prior)."""
    cached = CACHE / f"stage1-{family}-{u}{'-internal' if TEMP == 'internal' else ''}.json"
    if cached.exists():
        return json.loads(cached.read_text())
    t0 = time.perf_counter()
    cm = select(simulate(family, u, CAL[family], seed=1000 * u + 1))
    print(f"{family} unit {u}: 13 h fit {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    out = {"unit": u, "model": _pair(cm), "s": time.perf_counter() - t0}
    CACHE.mkdir(parents=True, exist_ok=True)
    cached.write_text(json.dumps(out))
    return out


def stage2(
    family: str,
    u: int,
    others: list[dict[str, Any]],
    foreign: list[dict[str, Any]],
    held: int,
    neff: bool = True,
    quick_spec: str = "quick",
) -> dict[str, Any]:
    """Unit ``u``: quick run with the leave-unit-out prior, alone, and the 13 h model, on
    the held-out runs; the quick run against the other family's prior."""
    from gyrolab.compensation.band import band_metrics
    from gyrolab.compensation.causal_models import hysteresis_width
    from gyrolab.compensation.guards import outside_fraction
    from gyrolab.compensation.prior import fit_map, learn_prior
    from gyrolab.numerics.averaging import block_average

    t0 = time.perf_counter()
    mine = _entry("13h", next(o["model"] for o in others if o["unit"] == u))
    prior = learn_prior(
        [_entry(f"{family}{o['unit']}", o["model"]) for o in others if o["unit"] != u]
    )
    qp = quick_profile(quick_spec, prior)
    quick = simulate(family, u, "quick", seed=1000 * u + 99, quick=qp)
    cal = calibration(quick)
    fit = fit_map(cal, prior, neff=neff)
    alone = _entry("alone", _pair(select(quick)))
    foreign_mem = fit_map(
        cal, learn_prior([_entry(f"x{o['unit']}", o["model"]) for o in foreign])
    ).membership
    other = simulate(family, u, "quick", seed=1000 * u + 98, other=True, quick=qp)
    other_mem = fit_map(calibration(other), prior, neff=neff).membership
    models = {"13h": mine, "quick_prior": _entry("prior", _pair(fit.model)), "quick_alone": alone}
    res: dict[str, Any] = {
        "unit": u,
        "truth": truth(family, u),
        "membership": fit.membership.to_dict(),
        # the terms of the unit's own 13 h model (is a term the rare-term test says the
        # run wants one the unit's full calibration has?)
        "terms_13h": list(mine.model.terms),
        "foreign_membership": foreign_mem.to_dict(),
        "other_part_membership": other_mem.to_dict(),
        "prior_clusters": len(prior.clusters),
        "quick_case_range_c": [float(quick.pt_c.min()), float(quick.pt_c.max())],
        "quick_profile": [[s.setpoint_c, s.duration_s] for s in qp.steps],
        "features": {k: m.params.to_dict() for k, m in models.items()},
        "hysteresis": {k: hysteresis_width(m.model) for k, m in models.items()},
        "runs": {},
    }
    # the 13 h run again (same seed as stage 1): its case range, the 13 h model's
    full = simulate(family, u, CAL[family], seed=1000 * u + 1)
    res["cal_case_range_c"] = [float(full.pt_c.min()), float(full.pt_c.max())]
    ranges = {"13h": res["cal_case_range_c"], "quick": res["quick_case_range_c"]}
    names = list(HELD[family])[:held]
    for i, name in enumerate(names):
        r = simulate(family, u, name, seed=1000 * u + 2 + i)
        rr = {"raw": score(r.raw), "oracle": score(r.raw - r.drift)}
        for k, m in models.items():
            rr[k] = score(r.raw - _drift(m, r))
        rr["_case_range_c"] = [float(r.pt_c.min()), float(r.pt_c.max())]
        # the quick + prior model's graded expected error on the run (its band's law:
        # what `compensate --validate` / `apply` report beside the range flag)
        tb, yb, _ = block_average(
            r.t, r.raw - _drift(models["quick_prior"], r), BLOCK_S, 1.0 / RATE_HZ
        )
        rr["_expected_error"] = band_metrics(fit.model.band, tb, yb, r.pt_t, r.pt_c)[
            "expected_error"
        ]
        # what gyrolab's range guard says of the run for each calibration: the fraction
        # of PT100 readings beyond its case range by more than the margin (the flag),
        # and how far beyond, °C
        rr["_outside"] = {
            k: {
                "fraction": outside_fraction(r.pt_c, lo, hi)[0],
                "beyond_c": max(lo - float(r.pt_c.min()), float(r.pt_c.max()) - hi, 0.0),
            }
            for k, (lo, hi) in ranges.items()
        }
        res["runs"][name] = rr
    res["s"] = time.perf_counter() - t0
    print(
        f"{family} unit {u}: d2 {fit.membership.d2:.1f} (p {fit.membership.p_value:.2g}), "
        f"foreign d2 {foreign_mem.d2:.0f}; {res['s']:.0f} s",
        file=sys.stderr,
        flush=True,
    )
    return res


# ---------------------------------------------------------------------------- tables


def _pass(ok: bool) -> str:
    return "**pass**" if ok else "**FAIL**"


def family_table(family: str, results: list[dict[str, Any]]) -> tuple[list[str], dict]:
    """Rows of the chamber-time table and the per-unit table of one family."""
    names = list(results[0]["runs"])
    a = {
        k: {m: np.array([[r["runs"][n][k][m] for n in names] for r in results]) for m in (BS, PP)}
        for k in ("raw", "oracle", "13h", "quick_prior", "quick_alone")
    }
    base = a["13h"][BS]
    cut = {k: 100.0 * (1.0 - a[k][PP] / a["raw"][PP]) for k in a}
    rows = []
    for k, label, hours in (
        ("13h", f"13 h `{CAL[family]}`, own fit", 13.0),
        ("quick_prior", "3.25 h `quick` + leave-unit-out prior (MAP)", 3.25),
        ("quick_alone", "3.25 h `quick`, own fit, no prior", 3.25),
    ):
        ratio = a[k][BS] / base
        rows.append(
            f"| {family} | {label} | {hours:g} | {np.median(ratio):.3f} | {ratio.max():.3f} | "
            f"{np.median(a[k][BS] / a['oracle'][BS]):.3f} | {np.median(cut[k]):.1f} % | "
            f"{np.median(cut['13h'] - cut[k]):+.1f} / {np.max(cut['13h'] - cut[k]):+.1f} |"
        )
    # the system as a lab runs it: a refused unit goes back for the 13 h profile
    refused = np.array([not r["membership"]["belongs"] for r in results])
    sys_bs = np.where(refused[:, None], base, a["quick_prior"][BS])
    sys_cut = np.where(refused[:, None], cut["13h"], cut["quick_prior"])
    ratio_s = sys_bs / base
    hours = 3.25 + 13.0 * refused.mean()
    rows.append(
        f"| {family} | 3.25 h `quick` + prior; a refused unit ({int(refused.sum())} of "
        f"{refused.size}) recalibrated on 13 h | {hours:.2f} (mean) | "
        f"{np.median(ratio_s):.3f} | {ratio_s.max():.3f} | "
        f"{np.median(sys_bs / a['oracle'][BS]):.3f} | {np.median(sys_cut):.1f} % | "
        f"{np.median(cut['13h'] - sys_cut):+.1f} / {np.max(cut['13h'] - sys_cut):+.1f} |"
    )
    ratio = a["quick_prior"][BS] / base
    dcut = cut["13h"] - cut["quick_prior"]

    def grid(get: Any) -> np.ndarray:
        """``get`` of every held-out run, units × runs (keys absent in results written
        before them: what ``get`` does with ``{}``)."""
        return np.array([[get(r["runs"][n]) for n in names] for r in results])

    def subset_row(label: str, mask: np.ndarray) -> None:
        """The quick + prior row over the runs in ``mask``."""
        if mask.any():
            rows.append(
                f"| {family} | 3.25 h `quick` + prior, held-out runs {label} "
                f"({int(mask.sum())} of {mask.size}; refused units left out) | 3.25 | "
                f"{np.median(ratio[mask]):.3f} | {ratio[mask].max():.3f} | "
                f"{np.median((a['quick_prior'][BS] / a['oracle'][BS])[mask]):.3f} | "
                f"{np.median(cut['quick_prior'][mask]):.1f} % | "
                f"{np.median(dcut[mask]):+.1f} / {np.max(dcut[mask]):+.1f} |"
            )

    # gyrolab's range guard on the quick calibration: a held-out run reaching beyond the
    # quick run's case range is flagged (extrapolated) when the model is applied
    flag = grid(lambda rr: rr.get("_outside", {}).get("quick", {}).get("fraction", 0.0) > 0)
    beyond = np.array(
        [
            grid(lambda rr, k=k: rr.get("_outside", {}).get(k, {}).get("beyond_c", 0.0))
            for k in ("quick", "13h")
        ]
    )
    severe = grid(lambda rr: rr.get("_expected_error", {}).get("grade") == "severe")
    trusted = ~severe & ~refused[:, None]
    if severe.any():
        subset_row("whose expected error is not graded severe", trusted)
    ws = np.unravel_index(np.argmax(np.where(severe, ratio, -np.inf)), ratio.shape)
    inside = ~flag & ~refused[:, None]
    subset_row("the range guard does not flag", inside)
    fl = flag & ~refused[:, None]
    wf = np.unravel_index(np.argmax(np.where(fl, ratio, -np.inf)), ratio.shape)
    stats = {
        "median": float(np.median(ratio)),
        "worst": float(ratio.max()),
        "dcut_median": float(np.median(dcut)),
        "dcut_worst": float(np.max(dcut)),
        "ratio": ratio,
        "names": names,
        "sys_median": float(np.median(ratio_s)),
        "sys_worst": float(ratio_s.max()),
        "sys_hours": hours,
        "sys_dcut_worst": float(np.max(cut["13h"] - sys_cut)),
        "flag": flag,
        "beyond": beyond,
        "in_n": int(inside.sum()),
        "in_worst": float(ratio[inside].max()) if inside.any() else float("nan"),
        "in_dcut_worst": float(dcut[inside].max()) if inside.any() else float("nan"),
        "flag_n": int(fl.sum()),
        "trusted_n": int(trusted.sum()),
        "n_runs": int(ratio.size),
        "trusted_worst": float(ratio[trusted].max()),
        "trusted_dcut_worst": float(dcut[trusted].max()),
        "severe": [
            (int(results[i]["unit"]), names[j], float(ratio[i, j]))
            for i, j in zip(*np.nonzero(severe), strict=True)
        ],
        "severe_worst": (
            (float(ratio[ws]), int(results[ws[0]]["unit"]), names[ws[1]]) if severe.any() else None
        ),
        "flag_worst": (
            (
                float(ratio[wf]),
                int(results[wf[0]]["unit"]),
                names[wf[1]],
                float(beyond[0][wf]),
                float(beyond[1][wf]),
            )
            if fl.any()
            else None
        ),
    }
    return rows, stats


def unit_rows(family: str, results: list[dict[str, Any]], stats: dict) -> list[str]:
    L = []
    for i, r in enumerate(results):
        m, f = r["membership"], r["foreign_membership"]
        hw = r["hysteresis"]
        tr = r["truth"]["hysteresis_width_deg_per_h"]
        worst = int(np.argmax(stats["ratio"][i]))
        ext = (
            f", beyond the quick range by {stats['beyond'][0][i, worst]:.0f} °C"
            if stats["flag"][i, worst]
            else ""
        )
        L.append(
            f"| {family} {r['unit']} | {np.median(stats['ratio'][i]):.3f} | "
            f"{stats['ratio'][i].max():.3f} ({stats['names'][worst]}{ext}) | "
            f"{m['mahalanobis_d2']:.1f} / {m['dof']} (p {m['p_value']:.2g}) "
            f"{'belongs' if m['belongs'] else '**refused**'}{_wants(m)} | "
            f"{f['mahalanobis_d2']:.0f} (p {f['p_value']:.1g}) "
            f"{'**refused**' if not f['belongs'] else 'accepted'}{_wants(f)} | "
            f"{tr:.2f} | {hw['13h']['at_mid_deg_per_h']:.2f} | "
            f"{hw['quick_prior']['at_mid_deg_per_h']:.2f} "
            f"({hw['quick_prior']['at_low_deg_per_h']:.2f} … "
            f"{hw['quick_prior']['at_high_deg_per_h']:.2f}) |"
        )
    return L


def _wants(m: dict[str, Any]) -> str:
    """The rare terms a unit's run wants (prior.wanted_terms), as a table cell's tail."""
    w = m.get("wanted_terms") or {}
    return "".join(f", wants {k} (log odds {v:.2g})" for k, v in w.items())


def wanted_line(data: dict[str, list[dict[str, Any]]]) -> str:
    """How often the rare-term test (prior.wanted_terms) fires, beside the p-value."""
    fams = list(data)
    kinds = (
        ("membership", "own-family units"),
        ("other_part_membership", "another part number"),
        ("foreign_membership", "units against the other family's prior"),
    )
    parts = []
    for key, lab in kinds:
        per = [sum(bool(r[key].get("wanted_terms")) for r in data[f]) for f in fams]
        only = [
            sum(
                bool(r[key].get("wanted_terms")) and r[key]["p_value"] >= r[key]["threshold_p"]
                for r in data[f]
            )
            for f in fams
        ]
        parts.append(
            f"{lab} {' / '.join(str(x) for x in per)} ({' / '.join(str(x) for x in only)} "
            "of them not refused by the p-value)"
        )
    # own-family units: does the unit's own 13 h model have the term its quick run wants?
    hits = [
        (f, r["unit"], k, k in r.get("terms_13h", []))
        for f in fams
        for r in data[f]
        for k in (r["membership"].get("wanted_terms") or {})
    ]
    has = "; ".join(
        f"{f} {u} {k}: {'in' if ok else 'not in'} its 13 h model" for f, u, k, ok in hits
    )
    return (
        "The rare-term test (a term fewer than half the fleet uses, which the run's data "
        "wants: posterior odds of the term's slab against the prior > 1; "
        f"docs/compensation.md) fires on ({', '.join(fams)}): "
        + "; ".join(parts)
        + (f". The term wanted by an own-family unit — {has}." if hits else ".")
    )


#: thresholds of the detector's p-value the rates are measured at
P_LEVELS = (0.5, 0.1, 0.05, 1e-2, 1e-3, 1e-4)


def detector_rows(data: dict[str, list[dict[str, Any]]]) -> list[str]:
    """The out-of-prior detector's measured rates at each threshold in :data:`P_LEVELS`:
    false alarms (a unit of the family, against its leave-unit-out prior) and detections
    (the unit with its slope and curvature reversed; the unit against the other family's
    prior), per family and pooled."""
    from gyrolab.compensation.prior import P_OUT

    fams = list(data)
    kinds = (
        ("membership", "false alarms: own-family units refused"),
        ("other_part_membership", "another part number (slope, curvature reversed) refused"),
        ("foreign_membership", "units against the other family's prior refused"),
    )
    head = "| p threshold | nominal false alarms (p × units) | " + " | ".join(
        f"{lab} ({', '.join(fams)}; all)" for _, lab in kinds
    )
    L = [head + " |", "| ---: | ---: |" + " ---: |" * len(kinds)]
    total = sum(len(data[f]) for f in fams)
    for lvl in sorted({*P_LEVELS, P_OUT}, reverse=True):
        cells = [f"{lvl * total:.2g} of {total}"]
        for key, _ in kinds:
            per = [sum(r[key]["p_value"] < lvl for r in data[f]) for f in fams]
            n = [len(data[f]) for f in fams]
            cells.append(
                " / ".join(f"{a}/{b}" for a, b in zip(per, n, strict=True))
                + f"; {100.0 * sum(per) / sum(n):.0f} %"
            )
        mark = " (gyrolab's)" if lvl == P_OUT else ""
        L.append(f"| {lvl:g}{mark} | " + " | ".join(cells) + " |")
    return L


def calibration_line(data: dict[str, list[dict[str, Any]]]) -> str:
    """The in-family null against χ²: the median of d² / (χ² median) over own-family
    units (1 when calibrated) and the median p-value (0.5)."""
    from scipy import stats as st

    m = [r["membership"] for f in data for r in data[f]]
    ratio = [x["mahalanobis_d2"] / st.chi2.median(x["dof"]) for x in m if x["dof"]]
    return (
        f"Own-family units (leave-unit-out, both families, {len(m)}): d² ÷ the χ² median "
        f"of its degrees of freedom, median {np.median(ratio):.2f} (1 when the null holds); "
        f"median p-value {np.median([x['p_value'] for x in m]):.2f} (0.5); degrees of "
        f"freedom {min(x['dof'] for x in m)} … {max(x['dof'] for x in m)}."
    )


def tables(data: dict[str, list[dict[str, Any]]], meta: dict[str, Any]) -> str:
    fams = list(data)
    n = {f: len(data[f]) for f in fams}
    held = {f: list(data[f][0]["runs"]) for f in fams}
    L = [
        f"`python benchmarks/prior_suite.py` — {meta['date']}, {meta['machine']}; "
        + "; ".join(
            f"{f}: {n[f]} units × {len(held[f])} held-out runs ({', '.join(held[f])})" for f in fams
        )
        + (
            f"; prior learned from a fleet of {meta['fleet']} units a family (leave-unit-out)"
            if meta.get("fleet", 0) > len(next(iter(data.values())))
            else ""
        )
        + (
            "; temperature input: the unit's die thermometer (both calibrations)"
            if meta.get("temperature") == "internal"
            else ""
        )
        + f"; wall clock {meta['wall_s']:.0f} s with {meta['workers']} workers, load average "
        f"{meta['load_before']} before, {meta['load_after']} after (shared machine).",
        "",
        "| family | calibration | chamber h | bias stability ÷ 13 h (median) | worst | ÷ oracle "
        "(median) | 100 s p-p cut (median) | Δ cut vs 13 h, points (median / worst) |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    st = {}
    for f in fams:
        rows, st[f] = family_table(f, data[f])
        L += rows
    L += ["", "| target (issue 30) | measured | verdict |", "| --- | --- | --- |"]
    for f in fams:
        s = st[f]
        L.append(
            f"| {f}: quick + prior bias stability ≤ 1.1 × the unit's 13 h (median over units "
            f"× runs) | {s['median']:.3f} × | {_pass(s['median'] <= 1.1)} |"
        )
        L.append(f"| {f}: worst ≤ 1.3 × | {s['worst']:.3f} × | {_pass(s['worst'] <= 1.3)} |")
        L.append(
            f"| {f}, refused units recalibrated on 13 h (mean {s['sys_hours']:.2f} h): median "
            f"/ worst | {s['sys_median']:.3f} / {s['sys_worst']:.3f} × | "
            f"{_pass(s['sys_median'] <= 1.1)} / {_pass(s['sys_worst'] <= 1.3)} |"
        )
        L.append(
            f"| {f}, refused units on 13 h: 100 s p-p cut within 5 points of the 13 h "
            f"calibration (worst) | {s['sys_dcut_worst']:+.1f} points | "
            f"{_pass(s['sys_dcut_worst'] <= 5)} |"
        )
        L.append(
            f"| {f}: worst ≤ 1.3 × on the {s['in_n']} held-out runs inside the quick run's "
            f"case range (gyrolab's range guard silent; refused units left out); their p-p "
            f"cut (worst) | {s['in_worst']:.3f} ×; {s['in_dcut_worst']:+.1f} points | "
            f"{_pass(s['in_worst'] <= 1.3)} / {_pass(s['in_dcut_worst'] <= 5)} |"
        )
        sv = np.array([w for *_, w in s["severe"]])
        sev = (
            f"{sv.size} of {s['n_runs']} runs; on them median {np.median(sv):.3f} ×, worst "
            f"{s['severe_worst'][0]:.3f} × (unit {s['severe_worst'][1]}, "
            f"{s['severe_worst'][2]})"
            if sv.size
            else "none"
        )
        L.append(
            f"| {f}: worst ≤ 1.3 × on the {s['trusted_n']} held-out runs whose expected error "
            f"gyrolab does not grade severe (refused units left out); their p-p cut (worst) "
            f"| {s['trusted_worst']:.3f} ×; {s['trusted_dcut_worst']:+.1f} points | "
            f"{_pass(s['trusted_worst'] <= 1.3)} / {_pass(s['trusted_dcut_worst'] <= 5)} |"
        )
        L.append(
            f"| {f}: runs graded severe (the tool reports an expected error > 2× its "
            f"calibrated one: recalibrate over the range) | {sev} | flagged |"
        )
        if s["flag_worst"]:
            w, uu, rn, bq, b13 = s["flag_worst"]
            L.append(
                f"| {f}: the worst of the {s['flag_n']} runs the range guard flags "
                f"(extrapolated: the tool warns) | {w:.3f} × (unit {uu}, {rn}: {bq:.0f} °C "
                f"beyond the quick run's case range, {b13:.0f} °C beyond the 13 h run's) "
                f"| flagged |"
            )
        L.append(
            f"| {f}: 100 s p-p cut within 5 points of the 13 h calibration (median / worst) "
            f"| {s['dcut_median']:+.1f} / {s['dcut_worst']:+.1f} points | "
            f"{_pass(s['dcut_median'] <= 5)} (median), {_pass(s['dcut_worst'] <= 5)} (worst) |"
        )
    for f in fams:
        other = [g for g in fams if g != f]
        det = sum(not r["foreign_membership"]["belongs"] for r in data[f])
        odet = sum(not r["other_part_membership"]["belongs"] for r in data[f])
        fa = sum(not r["membership"]["belongs"] for r in data[f])
        d2 = [r["other_part_membership"]["mahalanobis_d2"] for r in data[f]]
        L.append(
            f"| a unit of another part number is detected: {f} units with their temperature "
            f"slope and curvature reversed, against the family's leave-unit-out prior | "
            f"{odet} of {n[f]} refused (d² {min(d2):.0f} … {max(d2):.0f}) | "
            f"{_pass(odet == n[f])} |"
        )
        if other:
            L.append(
                f"| (harder) {f} units against the {other[0]} family's prior — the two "
                f"families are drawn around the same nominal part | {det} of {n[f]} refused "
                f"| — |"
            )
        L.append(
            f"| {f}: own-family units refused (false alarms, leave-unit-out) | {fa} of {n[f]} | — |"
        )
    L += [
        "",
        "The out-of-prior detector measured (the unit's quick run: its own estimate's "
        "distance d² from the prior, jackknife covariance, over the directions the run "
        "informs, against χ² — each count is of units whose p-value is below the "
        "threshold; under a calibrated null the own-family counts follow the nominal "
        "column):",
        "",
        *detector_rows(data),
        "",
        calibration_line(data),
        "",
        wanted_line(data),
    ]
    L += [
        "",
        "Per unit (quick + prior against the unit's own 13 h fit; the detector's distance "
        "d² of the unit's own quick-run estimate from its leave-unit-out prior, and from "
        "the other family's prior; up/down hysteresis width, heating − cooling branch at "
        "the middle of the range, °/h — the family's truth where it has one number, the "
        "13 h fit, the quick + prior fit with its low … high end):",
        "",
        "| unit | ÷ 13 h median | worst (run) | d² / dof, own family | d², other family | "
        "true hyst. °/h | 13 h | quick + prior |",
        "| --- | ---: | ---: | --- | --- | ---: | ---: | ---: |",
    ]
    for f in fams:
        L += unit_rows(f, data[f], st[f])
    return "\n".join(L)


# ------------------------------------------------------------------------------ main


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--units", type=int, default=8)
    ap.add_argument(
        "--temperature",
        choices=("pt100", "internal"),
        default="pt100",
        help="the models' temperature input: the case PT100, or the unit's die thermometer "
        "(both calibrations; results-…-internal)",
    )
    ap.add_argument(
        "--fleet",
        type=int,
        default=0,
        help="units 0..N-1 of each family make the fleet the prior is learned from "
        "(leave-unit-out; default --units); the first --units of them are evaluated. "
        "Other than --units its results go to results-fleet<N>",
    )
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--families", default="validation,break")
    ap.add_argument("--held", type=int, default=5, help="held-out runs per unit (of 5)")
    ap.add_argument("--out", default=str(REPO / "docs" / "results.md"), help="'' to skip")
    ap.add_argument("--tables-only", action="store_true")
    ap.add_argument(
        "--white", action="store_true", help="MAP data weight without the n_eff inflation"
    )
    ap.add_argument(
        "--quick",
        default="quick",
        help="the short profile: quick, a TOML, or design[:WEIGHT[:SETPOINT_MAX]] (per unit, "
        "from its leave-unit-out prior); other than quick its results go to "
        "results-quick-<tag>",
    )
    args = ap.parse_args(argv)
    fams = args.families.split(",")
    stem = CACHE / ("results-white" if args.white else "results")
    if args.quick != "quick":
        stem = CACHE / ("results-quick-" + Path(args.quick).stem.replace(":", "-"))
    use_temperature(args.temperature)
    if TEMP == "internal":
        stem = stem.with_name(stem.name + "-internal")
    fleet = max(args.fleet or args.units, args.units)
    if fleet != args.units:
        stem = stem.with_name(stem.name + f"-fleet{fleet}")
    if args.tables_only:
        d = load(stem)
        body = tables(d["data"], d["meta"])
    else:
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        os.environ.setdefault("GYROLAB_NO_PROGRESS", "1")
        load_before = "{:.1f} {:.1f} {:.1f}".format(*os.getloadavg())
        t0 = time.perf_counter()
        from concurrent.futures import ProcessPoolExecutor

        units = list(range(args.units))
        members = list(range(fleet))
        with ProcessPoolExecutor(
            args.workers, initializer=use_temperature, initargs=(TEMP,)
        ) as ex:
            s1 = {f: list(ex.map(stage1, [f] * fleet, members)) for f in fams}
            futs = {
                f: [
                    ex.submit(
                        stage2,
                        f,
                        u,
                        s1[f],
                        s1[[g for g in fams if g != f][0]] if len(fams) > 1 else s1[f],
                        args.held,
                        not args.white,
                        args.quick,
                    )
                    for u in units
                ]
                for f in fams
            }
            data = {f: [x.result() for x in futs[f]] for f in fams}
        meta = {
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "machine": f"{platform.machine()} {os.cpu_count()} cores, Python "
            f"{platform.python_version()}",
            "workers": args.workers,
            "fleet": fleet,
            "temperature": TEMP,
            "wall_s": time.perf_counter() - t0,
            "load_before": load_before,
            "load_after": "{:.1f} {:.1f} {:.1f}".format(*os.getloadavg()),
        }
        save(stem, {"meta": meta, "data": data}, default=str)
        body = tables(data, meta)
    print(body)
    if args.out:
        write_section(Path(args.out), "prior_suite", body)
    return 0


if __name__ == "__main__":
    sys.exit(main())
