"""The break family's floor: its *true* drift form fitted on the calibration run (issue 23).

    python benchmarks/true_form.py --protocol staircase [--first-unit 0 --units 12]
                                   [--draws 16] [--save F.npz]

What the worst case of ``break_suite.py`` can be, from the calibration run alone, for
any model: each unit's calibration run is fitted by least squares on the exact
regressors of its own simulated physics (``breakfam/physics.drift``: the quartic in the
true die temperature D, each play operator with its true width law, the heating-only,
cooling-only and Ḋ|Ḋ| rate terms of the true Ḋ, the die–package gradient D − P and the
aging log) — the effects the unit has, with their nonlinear parameters (time constants,
widths, κ) known. Only the linear coefficients are estimated, on the same 3.6 s means of
the same noisy run as gyrolab's models. This estimator has every advantage gyrolab's
models lack; what it misses on the held-out runs is the calibration run's noise and what
the run does not excite (the rates of the fast ramp on a staircase), not model form.
Scored like the suite: bias stability ÷ the oracle's and the 100 s p-p cut's gap to the
oracle's, per held-out run, over ``--draws`` draws of the calibration run's noise (seed
as ``break_suite.py --cal-draw K``, K = 0 … draws − 1).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from breakfam.family import DAY_OF, RATE_HZ, simulate_run, units  # noqa: E402
from breakfam.physics import DT, air_temperature, plays, thermal  # noqa: E402
from breakfam.score import BLOCK, means, score  # noqa: E402
from breakfam.trajectories import CALIBRATIONS, NAMES, trajectory  # noqa: E402

BS, PP = "bias_stability_deg_per_h", "pp_100s_deg_per_s"


def regressors(unit, name: str, seed: int) -> np.ndarray:  # noqa: ANN001
    """The true drift's regressors (1 Hz rows) of the unit's run ``name``: the columns of
    ``breakfam.physics.drift`` for the effects the unit has, each without its coefficient."""
    sp, rest = trajectory(name, seed)
    P, D = thermal(unit, air_temperature(sp, rest), rest)
    u = (D - 25.0) / 50.0
    cols = [u**k for k in range(5 if unit.c[4] else 4)]
    if any(unit.h):
        dp, half = plays(unit, D)
        cols += [dp[:, j] / half[:, j] for j in range(dp.shape[1]) if unit.h[j]]
    if unit.k_pos or unit.k_neg or unit.k2:
        rate = np.gradient(D, DT) * 60.0
        cols += [np.maximum(rate, 0.0), np.minimum(rate, 0.0), rate * np.abs(rate)]
    if unit.g:
        cols.append(D - P)
    if unit.age_a:
        t = DAY_OF.get(name, 0.0) * 86400.0 + DT * np.arange(D.size)
        cols.append(np.log1p(t / unit.age_tau_s))
    return np.stack(cols, axis=1)


def _at_rate(X1: np.ndarray, n: int) -> np.ndarray:
    """1 Hz rows linearly interpolated to the run's ``n`` samples (as the drift is)."""
    t1 = np.arange(X1.shape[0], dtype=float)
    t = np.arange(n) / RATE_HZ
    return np.stack([np.interp(t, t1, X1[:, j]) for j in range(X1.shape[1])], axis=1)


def unit_floor(u: int, protocol: str, draws: int) -> dict[str, np.ndarray]:
    """Ratios to the oracle and p-p gaps (draws × held-out runs) of unit ``u``."""
    unit = units(u + 1)[u]
    names = list(NAMES)
    base = CALIBRATIONS.get(protocol, protocol)
    held = [n for n in names if n != base]
    hx, hs = [], []
    for n in held:
        seed = 100 * u + names.index(n) + 1
        r = simulate_run(unit, n, seed=seed)
        hx.append((r, _at_rate(regressors(unit, n, seed), r.raw.size)))
        hs.append((score(r.raw), score(r.raw - r.drift)))
    ratio = np.zeros((draws, len(held)))
    gap = np.zeros((draws, len(held)))
    for k in range(draws):
        seed = 100 * u + names.index(base) + 1 + 100_000 * k
        c = simulate_run(unit, protocol, seed=seed)
        X = _at_rate(regressors(unit, protocol, seed), c.raw.size)
        Xb = np.stack([means(X[:, j], BLOCK) for j in range(X.shape[1])], axis=1)
        beta = np.linalg.lstsq(Xb, means(c.raw, BLOCK), rcond=None)[0]
        for j, ((r, Xh), (raw, orc)) in enumerate(zip(hx, hs, strict=True)):
            s = score(r.raw - Xh @ beta)
            ratio[k, j] = s[BS] / orc[BS]
            gap[k, j] = 100.0 * (s[PP] - orc[PP]) / raw[PP]
    return {"ratio": ratio, "gap": gap, "held": np.array(held)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--protocol", default="staircase")
    ap.add_argument("--first-unit", type=int, default=0)
    ap.add_argument("--units", type=int, default=12)
    ap.add_argument("--draws", type=int, default=16)
    ap.add_argument("--save", default="")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    us = range(args.first_unit, args.first_unit + args.units)
    res = {u: unit_floor(u, args.protocol, args.draws) for u in us}
    R = np.stack([res[u]["ratio"] for u in us], axis=1)  # draws × units × runs
    G = np.stack([res[u]["gap"] for u in us], axis=1)
    worst = R.max(axis=(1, 2))
    med = np.median(R.reshape(R.shape[0], -1), axis=1)
    gw = G.max(axis=(1, 2))
    gm = np.median(G.reshape(G.shape[0], -1), axis=1)
    ok = (med <= 1.15) & (worst <= 1.4) & (gm <= 5) & (gw <= 10)
    print(
        f"true form, {args.protocol}, units {us.start}-{us.stop - 1}, {args.draws} draws: "
        f"median {np.median(med):.3f}, worst {np.median(worst):.3f} "
        f"({worst.min():.2f} … {worst.max():.2f}; ≤ 1.4 on {(worst <= 1.4).sum()}), "
        f"p-p gap median {np.median(gm):+.1f}, worst {np.median(gw):+.1f} "
        f"({gw.min():+.1f} … {gw.max():+.1f}; ≤ 10 on {(gw <= 10).sum()}); every target "
        f"on {ok.sum()} of {ok.size} draws; {time.perf_counter() - t0:.0f} s"
    )
    for i, u in enumerate(us):
        j = np.unravel_index(np.argmax(np.median(R[:, i], axis=0)), R.shape[2])[0]
        print(f"  unit {u}: worst run {res[u]['held'][j]} median over draws "
              f"{np.median(R[:, i, j]):.3f}")
    if args.save:
        np.savez_compressed(args.save, ratio=R, gap=G, held=res[us.start]["held"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
