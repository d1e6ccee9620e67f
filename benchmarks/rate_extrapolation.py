"""The rate terms beyond the calibrated rates (issue 23's worst case): the selected
structured model evaluated with its rate columns saturated at the calibration run's rate
range, or with its poorly identified rate coefficients shrunk, beside the model as fitted.

    python benchmarks/rate_extrapolation.py [--family break|validation]
                                            [--protocol staircase] [--units 12]
                                            [--lag-criterion profile] [--out docs/results.md]
                                            [--tables-only]

The units, runs and seeds of ``break_suite.py`` (``--family break``: calibrated on
``--protocol``, evaluated on the other five trajectories) or of ``family_check.py``
(``--family validation``: gyrolab's own simulator, calibrated on ``paper``), the causal
selection of ``--families`` with ``--lag-criterion``, one worker. For each unit whose
selected model is a structured one (:class:`~gyrolab.compensation.structured.StructuredModel`)
every held-out run is scored (``breakfam.score``: bias stability ÷ the oracle's) with:

* ``as fitted`` — the model (R|R| continued along its tangent beyond the calibrated rates);
* ``hold all`` — R held at the edge of the calibration run's range ``[min R, max R]`` in
  every rate column (``k R``, ``kp max(R, 0)``, ``k2 R|R|``): the terms stay bounded;
* ``hold asym`` — the same for the heating-only term and R|R| only (``k R`` continues);
* ``hold asym q99`` — the same with the range's 1 % and 99 % quantiles as edges;
* ``R|R| free`` — R|R| without its tangent continuation (as fitted before it was bounded);
* ``shrink`` — the heating-only and R|R| coefficients multiplied by ``t²/(1 + t²)`` (``t``
  their delete-one-segment jackknife t, :func:`~gyrolab.compensation.structured.jackknife_t`;
  the posterior mean of a coefficient under a normal prior whose variance is estimated by
  its own square), the other coefficients refitted on the calibration run with those
  contributions held.

None of these is in the package; the results decide whether one should be
(docs/results.md, "The rate terms beyond the calibrated rates"). Per-unit results are
cached in ``benchmarks/results/rate_extrapolation/<family>-<protocol>-<lag>.json.gz``.
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

from breakfam.score import score  # noqa: E402
from docsections import write_section  # noqa: E402
from machine import load as load_now  # noqa: E402
from machine import run_meta  # noqa: E402
from runcache import load, save  # noqa: E402

from gyrolab.compensation.baselines import blocked_folds  # noqa: E402
from gyrolab.compensation.causal import (  # noqa: E402
    CV_FOLDS,
    CV_SEGMENTS,
    CausalCalibration,
    fit_causal,
)
from gyrolab.compensation.causal_features import hold, reading_features  # noqa: E402
from gyrolab.compensation.config import PipelineConfig  # noqa: E402
from gyrolab.compensation.structured import (  # noqa: E402
    LAG_CRITERIA,
    StructuredModel,
    block_features,
    design,
    jackknife_t,
    lstsq,
    model_from_coef,
)
from gyrolab.numerics.averaging import block_average  # noqa: E402

CACHE = REPO / "benchmarks" / "results" / "rate_extrapolation"
BS = "bias_stability_deg_per_h"
SHRUNK = ("rate_pos", "rate_sq")  # the terms a cooling staircase sees heat once
VARIANTS = ("as fitted", "hold all", "hold asym", "hold asym q99", "R|R| free", "shrink")


def held_rate(m: StructuredModel, X: np.ndarray, lo: float, hi: float, lin: bool) -> np.ndarray:
    """``m`` on feature rows ``X`` with R held at ``[lo, hi]`` (°C/s) in its heating-only
    and R|R| columns, and in its linear rate column too when ``lin``."""
    R = X[:, 1]
    Rc = np.clip(R, lo, hi)
    # the model without its rate columns (they are 0 at R = 0), then those columns held
    base = m.predict(np.column_stack([X[:, 0], np.zeros_like(R), X[:, 2], X[:, 3]]))
    return base + m.k * (Rc if lin else R) + m.kp * np.maximum(Rc, 0.0) + m.k2 * Rc * np.abs(Rc)


def shrunk(m: StructuredModel, X: np.ndarray, y: np.ndarray, folds: list[np.ndarray]):
    """The ``shrink`` variant (module docstring) of ``m`` fitted on block rows ``X``,
    target ``y``; and the (jackknife t, factor) of each shrunk term."""
    terms, order = m.terms, m.order
    jt = jackknife_t(X, y, order, terms, folds)
    A = design(X, order, terms, float(X[:, 0].min()), float(X[:, 0].max()))
    c = lstsq(A, y)
    fac = {t: (jt[t], jt[t] ** 2 / (1.0 + jt[t] ** 2)) for t in terms if t in SHRUNK}
    if not fac:
        return m, {}
    held = [order + 1 + terms.index(t) for t in fac]
    for j, t in zip(held, fac, strict=True):
        c[j] *= fac[t][1]
    free = [j for j in range(A.shape[1]) if j not in held]
    c[free] = lstsq(A[:, free], y - A[:, held] @ c[held])
    out = model_from_coef(c, X, order, terms)
    return replace(out, r_lo=m.r_lo, r_hi=m.r_hi), fac


def break_runs(u: int, protocol: str) -> tuple[Any, dict[str, Any]]:
    """A break-family unit's calibration run and held-out runs (break_suite's seeds), as
    ``(t, raw, drift, pt_t, pt_c)`` records."""
    from breakfam.family import simulate_run, units
    from breakfam.realnoise import DATA
    from breakfam.trajectories import NAMES

    unit = units(u + 1)[u]
    runs = {
        n: simulate_run(unit, n, seed=100 * u + i + 1, noise_path=str(DATA))
        for i, n in enumerate(NAMES)
    }
    rec = {n: (r.t, r.raw, r.drift, r.pt_t, r.pt_c) for n, r in runs.items()}
    return rec.pop(protocol), rec


def validation_runs(u: int) -> tuple[Any, dict[str, Any]]:
    """A unit of gyrolab's own validation family (family_check's seeds)."""
    import validation_suite as vs

    model, _ = vs.unit_model(u)
    rec = {}
    for i, n in enumerate(vs.TRAJECTORIES):
        r = vs.simulate(model, vs.trajectory(n, u), 10.0, seed=1000 * u + i + 1)
        rec[n] = (r["t"], r["raw"], r["drift"], r["pt_t"], r["pt_c"])
    return rec.pop(vs.CALIBRATION), rec


def run_unit(u: int, family: str, protocol: str, fams: tuple[str, ...], lag: str):
    """Fit unit ``u``'s causal selection, score every variant on its held-out runs."""
    t0 = time.perf_counter()
    cal, runs = break_runs(u, protocol) if family == "break" else validation_runs(u)
    t, raw, _, pt_t, pt_c = cal
    tb, xb, _ = block_average(t, raw, 3.6, 0.1)  # both families run at 10 Hz
    cc = CausalCalibration(t=tb, rate=xb, pt_t=pt_t, pt_c=pt_c)
    cfg = PipelineConfig(causal_lag_criterion=lag)
    # the seeds break_suite and family_check fit with (only the networks use one)
    cm = fit_causal(cc, families=fams, config=cfg, seed=u if family == "break" else 0)
    res: dict[str, Any] = {"unit": u, "winner": cm.family, "runs": {}}
    m = cm.model
    if not isinstance(m, StructuredModel):
        return res
    Xb = block_features(cc, cm.params)
    Rb = Xb[:, 1]
    folds = blocked_folds(xb.size, CV_FOLDS, CV_SEGMENTS)
    ms, fac = shrunk(m, Xb, xb, folds)
    lo, hi = float(Rb.min()), float(Rb.max())
    qlo, qhi = (float(v) for v in np.quantile(Rb, [0.01, 0.99]))
    res.update(
        terms=list(m.terms),
        coef={"k": m.k, "kp": m.kp, "k2": m.k2, "h": m.h},
        tau_s=cm.params.tau_s,
        cal_rate_c_per_min=[60.0 * lo, 60.0 * hi],
        shrink={k: {"jackknife_t": a, "factor": b} for k, (a, b) in fac.items()},
    )
    free = replace(m, r_lo=-np.inf, r_hi=np.inf)
    for n, (t, raw, drift, pt_t, pt_c) in runs.items():
        X = reading_features(pt_t, pt_c, cm.params)
        preds = {
            "as fitted": m.predict(X),
            "hold all": held_rate(m, X, lo, hi, True),
            "hold asym": held_rate(m, X, lo, hi, False),
            "hold asym q99": held_rate(m, X, qlo, qhi, False),
            "R|R| free": free.predict(X),
            "shrink": ms.predict(X),
        }
        ob = score(raw - drift)[BS]
        rr: dict[str, Any] = {v: score(raw - hold(t, pt_t, d))[BS] / ob for v, d in preds.items()}
        rr["_rate_c_per_min"] = [60.0 * float(X[:, 1].min()), 60.0 * float(X[:, 1].max())]
        res["runs"][n] = rr
    print(
        f"unit {u:2d}: {cm.family:<16} terms {','.join(m.terms):<36} "
        + " ".join(f"{v}={np.mean([r[v] for r in res['runs'].values()]):.3f}" for v in VARIANTS)
        + f" ({time.perf_counter() - t0:.0f} s)",
        file=sys.stderr,
        flush=True,
    )
    return res


def tables(results: list[dict[str, Any]], meta: dict[str, Any]) -> str:
    """The markdown section: each variant's causal ÷ oracle and its paired change."""
    rs = [r for r in results if r["runs"]]
    held = list(rs[0]["runs"])
    a = {v: np.array([[r["runs"][n][v] for n in held] for r in rs]) for v in VARIANTS}
    crit = meta["lag_criterion"]
    proto = f" --protocol {meta['protocol']}" if meta["family"] == "break" else ""
    L = [
        f"`python benchmarks/rate_extrapolation.py --family {meta['family']}{proto} "
        f"--lag-criterion {crit}` (families {','.join(meta['families'])}) — "
        f"{meta['date']}, {meta['machine']}, {len(rs)} of {len(results)} units with a "
        f"structured model × {len(held)} held-out runs; wall clock {meta['wall_s']:.0f} s, "
        f"load average {meta['load']}.",
        "",
        "| variant | causal ÷ oracle median, worst | worst run | per unit Δ causal ÷ oracle "
        "(variant − as fitted, mean over its runs) | units better / worse |",
        "| --- | ---: | --- | ---: | ---: |",
    ]
    for v in VARIANTS:
        x = a[v]
        i, j = np.unravel_index(np.argmax(x), x.shape)
        d = (x - a["as fitted"]).mean(axis=1)
        sd = float(np.std(d, ddof=1)) if d.size > 1 else 0.0
        label = v.replace("|", "\\|")  # a pipe inside a table cell
        L.append(
            f"| {label} | {np.median(x):.3f}, {x.max():.2f} | unit {rs[i]['unit']} {held[j]} | "
            f"{d.mean():+.4f} ± {sd:.4f} | {int(np.sum(d < -1e-4))} / {int(np.sum(d > 1e-4))} |"
        )
    cal = np.array([r["cal_rate_c_per_min"] for r in rs])
    run = np.array([[r["runs"][n]["_rate_c_per_min"] for n in held] for r in rs])
    L += [
        "",
        f"Die-rate estimate R of the calibration runs: {cal[:, 0].min():.2f} … "
        f"{cal[:, 0].max():.2f} °C/min at its most negative, {cal[:, 1].min():.2f} … "
        f"{cal[:, 1].max():.2f} at its most positive (over units); of the held-out runs "
        f"{run[..., 0].min():.2f} … {run[..., 0].max():.2f} and {run[..., 1].min():.2f} … "
        f"{run[..., 1].max():.2f}.",
    ]
    return "\n".join(L)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--family", default="break", choices=("break", "validation"))
    ap.add_argument("--protocol", default="staircase", help="break family: calibration run")
    ap.add_argument("--units", type=int, default=12)
    ap.add_argument("--families", default="poly,structured,structured_rate")
    ap.add_argument("--lag-criterion", default="profile", choices=LAG_CRITERIA)
    ap.add_argument("--out", default="", help="docs page to write the section into")
    ap.add_argument("--tables-only", action="store_true")
    args = ap.parse_args(argv)
    proto = args.protocol if args.family == "break" else "paper"
    name = f"{args.family}-{proto}-{args.lag_criterion}"
    if args.tables_only:
        d = load(CACHE / name)
        results, meta = d["units"], d["meta"]
    else:
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        os.environ.setdefault("GYROLAB_NO_PROGRESS", "1")
        import torch

        torch.set_num_threads(1)
        t0 = time.perf_counter()
        la = load_now()
        fams = tuple(args.families.split(","))
        results = [
            run_unit(u, args.family, proto, fams, args.lag_criterion) for u in range(args.units)
        ]
        meta = {
            "family": args.family,
            "protocol": proto,
            "families": list(fams),
            "lag_criterion": args.lag_criterion,
            **run_meta(t0, la),
        }
        save(CACHE / name, {"meta": meta, "units": results})
    body = tables(results, meta)
    print(body)
    if args.out:
        write_section(Path(args.out), f"rate_extrapolation_{name}", body)
    return 0


if __name__ == "__main__":
    sys.exit(main())
