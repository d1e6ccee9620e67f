"""Genetic particle swarm optimisation (GPSO), as in the paper's section 3.2.3.

Each generation is one particle swarm step followed by the genetic operators:

    V_i <- w V_i + c1 r1 (P_i - X_i) + c2 r2 (G - X_i)                      (eq. 9)
    X_i <- X_i + V_i                                                         (eq. 10)
    X_i, X_j <- b1 X_i + (1 - b1) X_j, (1 - b1) X_i + b1 X_j   with prob. Pc (eq. 11)
    V_i, V_j <- b2 V_i + (1 - b2) V_j, (1 - b2) V_i + b2 V_j   with prob. Pc (eq. 12)
    X_id <- X_id + (X_max,d - X_id) h(g)   if r1 >= 0.5                      (eq. 13)
            X_id + (X_min,d - X_id) h(g)   otherwise,          with prob. Pm
    h(g) = r2 (1 - g / G_max)                                                (eq. 14)

then the new swarm is evaluated (as one batch: the fitness takes all positions at once)
and the personal bests ``P_i`` and the global best ``G`` are updated. The search
minimises. Integer dimensions (the number of VMD modes K) are rounded after every move,
so every evaluated position is a valid candidate and the recorded history shows exactly
what was evaluated.

Choices the paper leaves open, made here and exposed as parameters: inertia falling
linearly from 0.9 to 0.4, c1 = c2 = 1.5, velocity limit 20 % of each range, Pc = 0.6,
Pm = 0.1 per coordinate, partners for crossover drawn by a random pairing. The paper's
eq. (13) as printed reads ``X_id + (X_id - X_max) h`` in the first branch, which moves
*down* in both branches; ``mutation="paper"`` does exactly that, the default
``"nonuniform"`` uses the standard non-uniform mutation it was meant to be (Michalewicz:
towards the upper bound in the first branch).

References
----------
The paper in ``shared/paper``: section 3.2, eqs. (9)-(14), and section 4.2 (population
50, K in 3..11, alpha in 50..5000).
Z. Michalewicz, "Genetic Algorithms + Data Structures = Evolution Programs", 1996
(non-uniform mutation).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from gyrolab.progress import progress

__all__ = ["GPSOResult", "gpso"]

Fitness = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class GPSOResult:
    """Outcome and full history of a search.

    Attributes
    ----------
    best_position : ndarray, shape (D,)
        Best position found (integer dimensions hold integral values).
    best_fitness : float
        Its fitness.
    best_history : ndarray, shape (G + 1,)
        Global best fitness after the initial swarm and after each generation.
    best_position_history : ndarray, shape (G + 1, D)
        Global best position at the same moments.
    positions : ndarray, shape (G + 1, P, D)
        Every evaluated position, per generation (generation 0 is the initial swarm).
    fitness : ndarray, shape (G + 1, P)
        Their fitness values.
    n_evaluations : int
        Fitness evaluations actually run (repeated positions are served from a cache).
    seed : int or None
        Seed of the run.
    """

    best_position: np.ndarray
    best_fitness: float
    best_history: np.ndarray
    best_position_history: np.ndarray
    positions: np.ndarray
    fitness: np.ndarray
    n_evaluations: int
    seed: int | None


def _snap(x: np.ndarray, lo: np.ndarray, hi: np.ndarray, integer: np.ndarray) -> np.ndarray:
    x = np.clip(x, lo, hi)
    x[:, integer] = np.rint(x[:, integer]) + 0.0  # + 0.0: no -0.0, so cache keys match
    return x


def gpso(
    fitness: Fitness,
    bounds: Sequence[tuple[float, float]],
    *,
    integer: Sequence[bool] | None = None,
    population: int = 50,
    generations: int = 30,
    inertia: tuple[float, float] = (0.9, 0.4),
    c1: float = 1.5,
    c2: float = 1.5,
    pc: float = 0.6,
    pm: float = 0.1,
    vmax_fraction: float = 0.2,
    mutation: str = "nonuniform",
    seed: int | None = 0,
    cache: bool = True,
    desc: str = "GPSO",
) -> GPSOResult:
    """Minimise ``fitness`` over a box by GPSO (paper section 3.2.3, eqs. 9-14).

    Parameters
    ----------
    fitness : callable
        ``fitness(X) -> f`` with X of shape (B, D) and f of shape (B,); called once per
        generation with the positions not evaluated before. Must be deterministic.
    bounds : sequence of (low, high)
        Search box, one pair per dimension.
    integer : sequence of bool, optional
        Which dimensions take integer values (rounded after every move).
    population : int, optional
        Number of particles N (paper: 50).
    generations : int, optional
        Generations after the initial swarm, G_max; fitness runs on ``G_max + 1`` swarms.
    inertia : (float, float), optional
        Inertia weight w at the first and last generation (linear in between).
    c1, c2 : float, optional
        Learning factors of eq. (9).
    pc : float, optional
        Probability that a pair of particles is crossed (eqs. 11-12).
    pm : float, optional
        Probability that one coordinate of a particle is mutated (eqs. 13-14).
    vmax_fraction : float, optional
        Velocity limit as a fraction of each dimension's range.
    mutation : {"nonuniform", "paper"}, optional
        Eq. (13) as intended (default) or as printed (see the module notes).
    seed : int or None, optional
        Seed of the random generator; the same seed gives the same search.
    cache : bool, optional
        Serve repeated positions from memory instead of calling ``fitness`` again.
    desc : str, optional
        Progress bar label.

    Returns
    -------
    GPSOResult
    """
    lo, hi = (np.asarray(b, dtype=np.float64) for b in zip(*bounds, strict=True))
    D = lo.size
    if np.any(hi < lo):
        raise ValueError("gpso: every bound needs low <= high")
    integer = np.zeros(D, dtype=bool) if integer is None else np.asarray(integer, dtype=bool)
    if integer.shape != (D,):
        raise ValueError("gpso: 'integer' needs one flag per dimension")
    if population < 2 or generations < 0:
        raise ValueError("gpso: population must be >= 2 and generations >= 0")
    if mutation not in ("nonuniform", "paper"):
        raise ValueError(f"gpso: unknown mutation {mutation!r}")
    rng = np.random.default_rng(seed)
    P = int(population)
    vmax = vmax_fraction * (hi - lo)
    memo: dict[bytes, float] = {}
    n_eval = 0

    def evaluate(X: np.ndarray) -> np.ndarray:
        nonlocal n_eval
        if not cache:
            n_eval += len(X)
            return np.asarray(fitness(X), dtype=np.float64).reshape(len(X))
        keys = [row.tobytes() for row in X]
        todo = {k: i for i, k in enumerate(keys) if k not in memo}
        if todo:
            idx = np.fromiter(todo.values(), dtype=np.int64, count=len(todo))
            vals = np.asarray(fitness(X[idx]), dtype=np.float64).reshape(idx.size)
            n_eval += idx.size
            for i, v in zip(idx, vals, strict=True):
                memo[keys[i]] = float(v)
        return np.array([memo[k] for k in keys])

    # step 1: random swarm inside the box and the velocity interval
    X = _snap(lo + rng.random((P, D)) * (hi - lo), lo, hi, integer)
    V = (2.0 * rng.random((P, D)) - 1.0) * vmax
    f = evaluate(X)
    pbest, pbest_f = X.copy(), f.copy()
    g = int(np.argmin(f))
    gbest, gbest_f = X[g].copy(), float(f[g])

    hist_pos = [X.copy()]
    hist_f = [f.copy()]
    hist_best = [gbest_f]
    hist_best_pos = [gbest.copy()]
    with progress(total=generations, desc=desc, unit="gen") as bar:
        for gen in range(1, generations + 1):
            w = inertia[0] + (inertia[1] - inertia[0]) * (gen - 1) / max(generations - 1, 1)
            # step 3: swarm update, eqs. (9)-(10)
            r1, r2 = rng.random((P, D)), rng.random((P, D))
            V = w * V + c1 * r1 * (pbest - X) + c2 * r2 * (gbest - X)
            V = np.clip(V, -vmax, vmax)
            X = _snap(X + V, lo, hi, integer)
            # step 4: crossover of positions and velocities, eqs. (11)-(12)
            perm = rng.permutation(P)
            pairs = perm[: P - P % 2].reshape(-1, 2)
            cross = rng.random(len(pairs)) < pc
            b1 = rng.random(len(pairs))[:, None]
            b2 = rng.random(len(pairs))[:, None]
            i, j = pairs[cross, 0], pairs[cross, 1]
            b1, b2 = b1[cross], b2[cross]
            Xi, Xj, Vi, Vj = X[i], X[j], V[i], V[j]
            X[i], X[j] = b1 * Xi + (1 - b1) * Xj, (1 - b1) * Xi + b1 * Xj
            V[i], V[j] = b2 * Vi + (1 - b2) * Vj, (1 - b2) * Vi + b2 * Vj
            # ... then non-uniform mutation, eqs. (13)-(14)
            mut = rng.random((P, D)) < pm
            up = rng.random((P, D)) >= 0.5
            h = rng.random((P, D)) * (1.0 - gen / generations)
            toward_hi = (X - hi) if mutation == "paper" else (hi - X)
            X = np.where(mut, np.where(up, X + toward_hi * h, X + (lo - X) * h), X)
            X = _snap(X, lo, hi, integer)
            # step 5: evaluate the new swarm as one batch, update the bests
            f = evaluate(X)
            better = f < pbest_f
            pbest[better], pbest_f[better] = X[better], f[better]
            g = int(np.argmin(pbest_f))
            if pbest_f[g] < gbest_f:
                gbest, gbest_f = pbest[g].copy(), float(pbest_f[g])
            hist_pos.append(X.copy())
            hist_f.append(f.copy())
            hist_best.append(gbest_f)
            hist_best_pos.append(gbest.copy())
            bar.update(1)
            bar.set_postfix(best=f"{gbest_f:.6g}")
    return GPSOResult(
        best_position=gbest,
        best_fitness=gbest_f,
        best_history=np.array(hist_best),
        best_position_history=np.array(hist_best_pos),
        positions=np.array(hist_pos),
        fitness=np.array(hist_f),
        n_evaluations=n_eval,
        seed=seed,
    )
