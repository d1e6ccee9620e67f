"""GPSO: finds a known optimum with an integer axis, is reproducible, records its history."""

from __future__ import annotations

import numpy as np
import pytest

from gyrolab.compensation.gpso import gpso

K_OPT, X_OPT = 7, 1.234
BOUNDS = [(0.0, 20.0), (-5.12 + X_OPT, 5.12 + X_OPT)]


def shifted_rastrigin(X: np.ndarray) -> np.ndarray:
    """Rastrigin shifted to (7, 1.234); on the integer axis every odd step is a ridge."""
    z1 = 0.5 * (X[:, 0] - K_OPT)  # integer axis: minima at even offsets, maxima at odd
    z2 = X[:, 1] - X_OPT
    return 20 + z1**2 - 10 * np.cos(2 * np.pi * z1) + z2**2 - 10 * np.cos(2 * np.pi * z2)


@pytest.mark.parametrize("mutation", ["nonuniform", "paper"])
def test_finds_shifted_rastrigin_optimum_in_95_percent_of_seeds(mutation: str) -> None:
    hits = 0
    for seed in range(20):
        r = gpso(shifted_rastrigin, BOUNDS, integer=[True, False], seed=seed, mutation=mutation)
        hits += r.best_position[0] == K_OPT and abs(r.best_position[1] - X_OPT) < 0.01
    assert hits >= 19


def test_same_seed_same_search_other_seed_other_search() -> None:
    a = gpso(shifted_rastrigin, BOUNDS, integer=[True, False], seed=11)
    b = gpso(shifted_rastrigin, BOUNDS, integer=[True, False], seed=11)
    c = gpso(shifted_rastrigin, BOUNDS, integer=[True, False], seed=12)
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.best_history, b.best_history)
    assert a.best_fitness == b.best_fitness
    assert not np.array_equal(a.positions, c.positions)


def test_history_shapes_bounds_and_integrality() -> None:
    calls: list[int] = []

    def f(X: np.ndarray) -> np.ndarray:
        assert X.ndim == 2 and X.shape[1] == 2
        calls.append(len(X))
        return shifted_rastrigin(X)

    r = gpso(f, BOUNDS, integer=[True, False], population=30, generations=12, seed=3)
    assert r.positions.shape == (13, 30, 2) and r.fitness.shape == (13, 30)
    assert r.best_history.shape == (13,) and r.best_position_history.shape == (13, 2)
    assert np.all(np.diff(r.best_history) <= 0)  # the global best never gets worse
    assert np.all(r.positions[..., 0] == np.rint(r.positions[..., 0]))
    assert np.all(r.positions[..., 0] >= 0) and np.all(r.positions[..., 0] <= 20)
    lo, hi = BOUNDS[1]
    assert np.all((r.positions[..., 1] >= lo) & (r.positions[..., 1] <= hi))
    # one batch per generation; the recorded fitness is the fitness of the recorded positions
    assert len(calls) <= 13 and sum(calls) == r.n_evaluations
    np.testing.assert_allclose(
        r.fitness, shifted_rastrigin(r.positions.reshape(-1, 2)).reshape(13, 30)
    )
    assert r.best_fitness == r.fitness.min()


def test_cache_only_skips_repeats() -> None:
    cached = gpso(shifted_rastrigin, BOUNDS, integer=[True, True], seed=5, generations=20)
    plain = gpso(
        shifted_rastrigin, BOUNDS, integer=[True, True], seed=5, generations=20, cache=False
    )
    np.testing.assert_array_equal(cached.positions, plain.positions)
    assert plain.n_evaluations == 50 * 21
    # on an all-integer box the swarm revisits points: the cache must save calls
    assert cached.n_evaluations < plain.n_evaluations
    assert cached.n_evaluations == len(np.unique(cached.positions.reshape(-1, 2), axis=0))


def test_mutation_moves_towards_the_bounds() -> None:
    """With Pm = 1 and no swarm pull, eq. (13) sends coordinates to both sides.

    (h(g) = r2 (1 - g / G_max) is zero in the last generation: look at the first.)
    """
    flat = lambda X: np.zeros(len(X))  # noqa: E731 - every position is as good
    r = gpso(flat, [(0.0, 1.0)], population=200, generations=2, pm=1.0, pc=0.0, c1=0, c2=0,
             inertia=(0.0, 0.0), seed=1)  # fmt: skip
    moved = r.positions[1, :, 0] - r.positions[0, :, 0]
    assert (moved > 0).mean() > 0.3 and (moved < 0).mean() > 0.3
    # the printed eq. (13) moves down in both branches
    p = gpso(flat, [(0.0, 1.0)], population=200, generations=2, pm=1.0, pc=0.0, c1=0, c2=0,
             inertia=(0.0, 0.0), seed=1, mutation="paper")  # fmt: skip
    assert np.all(p.positions[1, :, 0] <= p.positions[0, :, 0])


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"bounds": [(1.0, 0.0)]}, "low <= high"),
        ({"bounds": [(0.0, 1.0)], "integer": [True, False]}, "one flag"),
        ({"bounds": [(0.0, 1.0)], "population": 1}, "population"),
        ({"bounds": [(0.0, 1.0)], "mutation": "gauss"}, "mutation"),
    ],
)
def test_bad_arguments(kw: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        gpso(lambda X: X[:, 0], **kw)
