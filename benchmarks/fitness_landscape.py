"""Fitness landscapes of VMD's (K, alpha) on a synthetic drift-plus-noise gyro record.

For each criterion in ``gyrolab.compensation.fitness.CRITERIA`` and for the true error of
the drift mode (known here because the record is synthetic) this evaluates the paper's box
(K 3..11, alpha 50..5000) on a grid, for several noise seeds, finds each seed's grid
optimum, runs the GPSO search for each criterion and seed, and draws

* ``docs/img/fitness_landscape.png`` - the four landscapes (seed 0) with every seed's
  optimum marked;
* ``docs/img/fitness_gpso.png`` - a Fig. 10-style view of one search: best fitness per
  generation and every particle per generation.

Usage: ``python benchmarks/fitness_landscape.py [--seeds 5] [--gpso-seeds 3] [--out docs/img]``
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("GYROLAB_NO_PROGRESS", "1")

import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.colors import LogNorm  # noqa: E402

from gyrolab.compensation.fitness import (  # noqa: E402
    CRITERIA,
    search_vmd_parameters,
    synthetic_drift_signal,
)
from gyrolab.compensation.vmd import vmd_batch  # noqa: E402

TITLES = {
    "envelope_entropy": "min envelope entropy (nats)",
    "orthogonality": "orthogonality index + energy loss",
    "drift_separation": "drift separation (default)",
    "oracle": "true drift error ||d - drift|| / ||drift - mean||",
}


def landscape(seed: int, Ks: np.ndarray, alphas: np.ndarray) -> dict[str, np.ndarray]:
    x, drift, _, _ = synthetic_drift_signal(seed=seed, return_parts=True)
    KK, AA = np.meshgrid(Ks, alphas, indexing="ij")
    res = vmd_batch(x, AA.ravel(), KK.ravel())
    out = {n: np.array([f(x, r) for r in res]).reshape(KK.shape) for n, f in CRITERIA.items()}
    scale = np.linalg.norm(drift - drift.mean())
    out["oracle"] = np.array(
        [np.linalg.norm(r.modes[np.argmin(r.omega)] - drift) / scale for r in res]
    ).reshape(KK.shape)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5, help="noise seeds for the grid study")
    ap.add_argument("--gpso-seeds", type=int, default=3, help="seeds for the GPSO searches")
    ap.add_argument("--n-alpha", type=int, default=20, help="grid points along alpha")
    ap.add_argument("--out", type=Path, default=Path("docs/img"))
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)

    Ks = np.arange(3, 12)
    alphas = np.geomspace(50, 5000, args.n_alpha)
    maps = []
    t0 = time.perf_counter()
    for s in range(args.seeds):
        maps.append(landscape(s, Ks, alphas))
    print(
        f"grid: {len(Ks)} x {len(alphas)} x {args.seeds} seeds in {time.perf_counter() - t0:.1f} s"
    )

    names = [*CRITERIA, "oracle"]
    print("\ngrid optimum per seed (K, alpha) and the true drift error there")
    print(f"{'criterion':<18} " + " ".join(f"{'seed ' + str(s):>18}" for s in range(args.seeds)))
    for n in names:
        cells = []
        for m in maps:
            i, j = np.unravel_index(np.argmin(m[n]), m[n].shape)
            cells.append(f"({Ks[i]:2d},{alphas[j]:5.0f}) {m['oracle'][i, j]:.4f}")
        print(f"{n:<18} " + " ".join(f"{c:>18}" for c in cells))
    print("\nrange over the box (seed 0):")
    for n in names:
        print(f"  {n:<18} {maps[0][n].min():.6g} .. {maps[0][n].max():.6g}")

    # ---- landscapes
    fig, axes = plt.subplots(2, 2, figsize=(11, 8), constrained_layout=True)
    markers = "o^sDv*xP"
    for ax, n in zip(axes.ravel(), names, strict=True):
        z = maps[0][n]
        norm = LogNorm(z.min(), z.max()) if n != "envelope_entropy" else None
        pc = ax.pcolormesh(alphas, Ks, z, shading="nearest", norm=norm, cmap="viridis")
        fig.colorbar(pc, ax=ax)
        for s, m in enumerate(maps):
            i, j = np.unravel_index(np.argmin(m[n]), m[n].shape)
            ax.plot(alphas[j], Ks[i], markers[s % len(markers)], mfc="none", mec="red", ms=11,
                    mew=1.6, label=f"optimum, seed {s}")  # fmt: skip
        ax.set_xscale("log")
        ax.set_xlabel("alpha")
        ax.set_ylabel("K")
        ax.set_title(TITLES[n])
    axes[0, 0].legend(fontsize=7, loc="lower left")
    fig.suptitle("VMD fitness over the paper's box, synthetic drift + noise record (N = 11 000)")
    fig.savefig(args.out / "fitness_landscape.png", dpi=110)
    plt.close(fig)

    # ---- GPSO searches
    print("\nGPSO (50 particles x 30 generations) per criterion and seed: K, alpha, time")
    x0 = synthetic_drift_signal(seed=0)
    keep = None
    for n in CRITERIA:
        row = []
        for s in range(args.gpso_seeds):
            t0 = time.perf_counter()
            r = search_vmd_parameters(x0, criterion=n, seed=s)
            dt = time.perf_counter() - t0
            row.append(f"({r.K:2d},{r.alpha:6.0f}) {dt:5.1f}s")
            if n == "drift_separation" and s == 0:
                keep = r
        print(f"{n:<18} " + "  ".join(row))

    # ---- Fig. 10-style view of one search
    g = keep.gpso
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    gen_axis = np.arange(len(g.best_history))
    a1.plot(gen_axis, g.best_history, "o-", label="global best")
    a1.plot(gen_axis, np.median(g.fitness, axis=1), "s--", ms=4, label="swarm median")
    a1.set_xlabel("generation")
    a1.set_ylabel("fitness (drift separation)")
    a1.set_yscale("log")
    a1.set_title("convergence")
    a1.legend()
    gens = np.repeat(np.arange(g.positions.shape[0]), g.positions.shape[1])
    sc = a2.scatter(g.positions[..., 1].ravel(), g.positions[..., 0].ravel()
                    + 0.25 * (np.random.default_rng(0).random(gens.size) - 0.5),
                    c=gens, s=9, cmap="plasma")  # fmt: skip
    a2.plot(keep.alpha, keep.K, "k*", ms=16, label=f"best: K = {keep.K}, alpha = {keep.alpha:.0f}")
    fig.colorbar(sc, ax=a2, label="generation")
    a2.set_xscale("log")
    a2.set_xlabel("alpha")
    a2.set_ylabel("K (jittered)")
    a2.set_title("particles per generation")
    a2.legend(loc="lower left")
    fig.savefig(args.out / "fitness_gpso.png", dpi=110)
    plt.close(fig)
    print(f"\nwrote {args.out / 'fitness_landscape.png'} and {args.out / 'fitness_gpso.png'}")


if __name__ == "__main__":
    main()
