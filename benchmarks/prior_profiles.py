"""Short profiles compared paired over the quick run's noise (issue 30): each unit of a
family calibrated on each candidate short profile with its leave-unit-out fleet prior,
for several noise seeds of the short run, scored on the same held-out runs against the
same 13 h calibration as ``benchmarks/prior_suite.py``.

    python benchmarks/prior_profiles.py --profiles quick,design:soaks,P.toml
                                        [--seeds 6] [--units 12] [--families validation,break]
                                        [--fleet 12]

``prior_suite.py`` runs each unit's short run once (seed ``1000 u + 99``): its worst case
is one draw of the short run's noise. Here seed ``k`` is ``1000 u + 99 + k`` (``k = 0`` is
the suite's run; ``k`` from ``--first-seed``), the held-out runs, the 13 h models
(prior_suite's cache) and the priors are shared by every profile and seed, so the profiles
are compared on the same draws.
``13h`` in ``--profiles`` is the control: the unit recalibrated on its own 13 h profile
(no prior) on another draw of that run's noise (seed ``1000 u + 500 + k``) — what the
ratio to *one* 13 h calibration is when the short run is no shorter, the metric's own
noise floor.
A unit the prior refuses (``membership.belongs`` false) is counted as the lab runs it:
recalibrated on the 13 h profile, ratio 1, 13 h more chamber time. Printed per family and
profile: over seeds, the worst ratio (bias stability ÷ the unit's 13 h, over units ×
held-out runs), the median ratio, the worst 100 s p-p gap (points) and the mean chamber
hours, each as the median (and range) over seeds; and each unit's median over seeds of
its worst run.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import prior_suite as ps  # noqa: E402
from breakfam.score import score  # noqa: E402

#: the control "profile": the 13 h calibration again, on another noise draw (docstring)
RECAL = "13h"


def _score(o: dict[str, np.ndarray], k: int, u: int, e, held, base, raw) -> None:  # noqa: ANN001
    """Seed ``k``, unit ``u``: model entry ``e``'s bias-stability ratio to the unit's 13 h
    fit and its 100 s p-p gap (points of raw) on each held-out run."""
    for j, r in enumerate(held):
        s = score(r.raw - ps._drift(e, r))
        o["ratio"][k, u, j] = s[ps.BS] / base[j][ps.BS]
        o["dcut"][k, u, j] = 100.0 * (s[ps.PP] - base[j][ps.PP]) / raw[j][ps.PP]


def family(
    fam: str, units: int, profiles: list[str], seeds: int, fleet: int = 12, first: int = 0
) -> dict[str, dict[str, np.ndarray]]:
    """Per profile: bias-stability ratio and p-p gap, seeds × units × runs, and refusals,
    seeds × units — units ``0 … units − 1``, each against the other ``fleet − 1``."""
    from gyrolab.compensation.prior import fit_map, learn_prior
    from gyrolab.profiles.profile import BUILTIN

    s1 = [ps.stage1(fam, u) for u in range(max(fleet, units))]
    names = list(ps.HELD[fam])
    out = {
        p: {
            "ratio": np.zeros((seeds, units, len(names))),
            "dcut": np.zeros((seeds, units, len(names))),
            "refused": np.zeros((seeds, units), dtype=bool),
        }
        for p in profiles
    }
    for u in range(units):
        mine = ps._entry("13h", s1[u]["model"])
        prior = learn_prior(
            [ps._entry(f"{fam}{o['unit']}", o["model"]) for o in s1 if o["unit"] != u]
        )
        held = [ps.simulate(fam, u, n, seed=1000 * u + 2 + i) for i, n in enumerate(names)]
        raw = [score(r.raw) for r in held]
        base = [score(r.raw - ps._drift(mine, r)) for r in held]
        for p in profiles:
            if p == RECAL:
                for k in range(seeds):
                    q = ps.simulate(fam, u, ps.CAL[fam], seed=1000 * u + 500 + first + k)
                    e = ps._entry("13h", ps._pair(ps.select(q)))
                    _score(out[p], k, u, e, held, base, raw)
                continue
            qp = BUILTIN["quick"] if p == "quick" else ps.quick_profile(p, prior)
            for k in range(seeds):
                q = ps.simulate(fam, u, "quick", seed=1000 * u + 99 + first + k, quick=qp)
                fit = fit_map(ps.calibration(q), prior)
                e = ps._entry("prior", ps._pair(fit.model))
                _score(out[p], k, u, e, held, base, raw)
                out[p]["refused"][k, u] = not fit.membership.belongs
        print(f"{fam} unit {u} done", file=sys.stderr, flush=True)
    return out


def report(fam: str, res: dict[str, dict[str, np.ndarray]]) -> list[str]:
    def mr(x: np.ndarray, f: str = ".3f") -> str:
        return f"{np.median(x):{f}} ({x.min():{f}} … {x.max():{f}})"

    L = []
    for p, d in res.items():
        ref = d["refused"][:, :, None]
        ratio = np.where(ref, 1.0, d["ratio"])
        dcut = np.where(ref, 0.0, d["dcut"])
        worst = ratio.max(axis=(1, 2))
        med = np.median(ratio.reshape(ratio.shape[0], -1), axis=1)
        gap = dcut.max(axis=(1, 2))
        hours = (13.0 if p == RECAL else 3.25) + 13.0 * d["refused"].mean(axis=1)
        unit_worst = np.median(ratio.max(axis=2), axis=0)
        print(f"{fam} {p} worst per seed: " + " ".join(f"{w:.3f}" for w in worst), file=sys.stderr)
        L.append(
            f"| {fam} | {p} | {mr(worst)} | {(worst <= 1.3).sum()} of {worst.size} | "
            f"{mr(med)} | {mr(gap, '+.1f')} | {mr(hours, '.2f')} | "
            + " ".join(f"{x:.2f}" for x in unit_worst)
            + " |"
        )
    return L


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--profiles", default="quick,design:soaks")
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--units", type=int, default=12)
    ap.add_argument("--families", default="validation,break")
    ap.add_argument("--first-seed", type=int, default=0, help="k of the first seed")
    ap.add_argument("--save", default="", help="an .npz of every ratio, gap and refusal")
    ap.add_argument(
        "--fleet", type=int, default=12, help="the fleet each unit's prior is learned from"
    )
    ap.add_argument("--temperature", choices=("pt100", "internal"), default="pt100")
    args = ap.parse_args(argv)
    ps.use_temperature(args.temperature)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    os.environ.setdefault("GYROLAB_NO_PROGRESS", "1")
    t0 = time.perf_counter()
    profiles = args.profiles.split(",")
    L = [
        f"`python benchmarks/prior_profiles.py --profiles {args.profiles} --seeds {args.seeds}"
        f" --first-seed {args.first_seed} --fleet {args.fleet}"
        f" --temperature {args.temperature}`"
        f" — {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, load "
        "{:.1f} {:.1f} {:.1f} before".format(*os.getloadavg()),
        "",
        "| family | short profile | worst ÷ 13 h: median over seeds (range) | seeds with "
        "worst ≤ 1.3 | median ÷ 13 h | worst p-p gap, points | chamber h (mean) | "
        "per unit: median over seeds of its worst run |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    saved = {}
    for fam in args.families.split(","):
        res = family(
            fam, args.units, profiles, args.seeds, fleet=args.fleet, first=args.first_seed
        )
        L += report(fam, res)
        saved.update({f"{fam}|{p}|{k}": v for p, d in res.items() for k, v in d.items()})
    if args.save:
        np.savez_compressed(args.save, **saved)
    L.append(
        f"\n{args.units} units × {args.seeds} seeds; wall clock {time.perf_counter() - t0:.0f} s"
    )
    print("\n".join(L))
    return 0


if __name__ == "__main__":
    sys.exit(main())
