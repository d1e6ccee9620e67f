"""VMD fitness criteria, the GPSO-VMD search glue and the synthetic drift record."""

from __future__ import annotations

import numpy as np
import pytest

from gyrolab.compensation.fitness import (
    CRITERIA,
    VMDFitness,
    drift_separation,
    envelope_entropy,
    orthogonality,
    search_vmd_parameters,
    synthetic_drift_signal,
)
from gyrolab.compensation.vmd import VMDResult, vmd, vmd_batch


def _fake(modes: np.ndarray, omega: list[float]) -> VMDResult:
    return VMDResult(np.asarray(modes), np.asarray(omega), 1, True, 1.0, len(omega))


def test_envelope_entropy_bounds() -> None:
    n = 4096
    t = np.arange(n)
    flat = np.cos(2 * np.pi * 64 * t / n)  # whole number of cycles: constant envelope
    burst = flat * np.exp(-0.5 * ((t - n / 2) / 50.0) ** 2)
    e = envelope_entropy(np.vstack([flat, burst]))
    assert e[0] == pytest.approx(np.log(n), abs=1e-6)
    assert e[1] < np.log(n) - 2.0  # a concentrated envelope has far lower entropy


def test_orthogonality_index_and_energy_loss() -> None:
    n = 1000
    t = np.arange(n)
    a, b = np.sin(2 * np.pi * 5 * t / n), np.sin(2 * np.pi * 40 * t / n)
    x = a + b
    assert orthogonality(x, _fake(np.vstack([a, b]), [0.005, 0.04])) < 1e-12
    # two identical halves: IO = 2 <x/2, x/2> / <x, x> = 0.5, nothing lost
    assert orthogonality(x, _fake(np.vstack([x / 2, x / 2]), [0.0, 0.0])) == pytest.approx(0.5)
    # one mode only: no overlap, but b's energy (half) is missing
    assert orthogonality(x, _fake(a[None, :], [0.005])) == pytest.approx(0.5, rel=1e-3)


def test_drift_separation_scores_a_perfect_split_near_zero() -> None:
    x, drift, noise, _ = synthetic_drift_signal(n=5000, seed=1, return_parts=True)
    perfect = _fake(np.vstack([drift, noise]), [0.0, 0.2])
    all_in_drift = _fake(np.vstack([x, np.zeros_like(x)]), [0.0, 0.2])
    nothing_in_drift = _fake(np.vstack([np.zeros_like(x), x]), [0.0, 0.2])
    assert drift_separation(x, perfect) < 0.02
    assert drift_separation(x, all_in_drift) > 0.9
    assert drift_separation(x, nothing_in_drift) > 0.9
    # the drift mode is the one with the lowest centre frequency, whatever its index
    swapped = _fake(np.vstack([noise, drift]), [0.2, 0.0])
    assert drift_separation(x, swapped) == pytest.approx(drift_separation(x, perfect))


@pytest.mark.parametrize("seed", [0, 3])
def test_drift_separation_ranks_like_the_true_drift_error(seed: int) -> None:
    """On the corners of the paper's box, the criterion orders the decompositions as the
    (in practice unknown) error of the drift mode against the true drift does."""
    x, drift, _, _ = synthetic_drift_signal(seed=seed, return_parts=True)
    Ks, alphas = [3, 3, 11, 11], [50.0, 5000.0, 50.0, 5000.0]
    res = vmd_batch(x, alphas, Ks)
    crit = [drift_separation(x, r) for r in res]
    truth = [np.linalg.norm(r.modes[np.argmin(r.omega)] - drift) for r in res]
    assert list(np.argsort(crit)) == list(np.argsort(truth))


def test_synthetic_signal_matches_the_paper_scale() -> None:
    x, drift, noise, case = synthetic_drift_signal(seed=0, return_parts=True)
    assert x.shape == (11_000,)
    assert np.ptp(drift) == pytest.approx(0.0287)
    assert 50 < case.max() < 60 and -40 < case.min() < -30
    assert np.std(np.diff(noise)) / np.sqrt(2) == pytest.approx(4.6e-4, rel=0.1)
    np.testing.assert_array_equal(x, synthetic_drift_signal(seed=0))
    assert not np.array_equal(x, synthetic_drift_signal(seed=1))


def test_vmd_fitness_is_the_criterion_of_each_candidate() -> None:
    x = synthetic_drift_signal(n=2000, seed=2)
    X = np.array([[3.0, 100.0], [5.0, 2000.0], [4.0, 700.0]])
    for name, fn in CRITERIA.items():
        got = VMDFitness(x, name)(X)
        want = [fn(x, vmd(x, a, int(k))) for k, a in X]
        np.testing.assert_allclose(got, want, rtol=1e-10)
        one_at_a_time = VMDFitness(x, name, {"fitness_chunk": 1})(X)
        np.testing.assert_array_equal(one_at_a_time, got)
    with pytest.raises(ValueError, match="unknown fitness"):
        VMDFitness(x, "kurtosis")


def test_search_is_reproducible_and_inside_the_box() -> None:
    x = synthetic_drift_signal(n=2000, seed=4)
    kw = {"population": 8, "generations": 4, "seed": 7}
    a = search_vmd_parameters(x, **kw)
    b = search_vmd_parameters(x, **kw)
    assert (a.K, a.alpha, a.fitness) == (b.K, b.alpha, b.fitness)
    assert 3 <= a.K <= 11 and 50.0 <= a.alpha <= 5000.0
    assert a.gpso.positions.shape == (5, 8, 2)
    assert a.fitness == pytest.approx(drift_separation(x, vmd(x, a.alpha, a.K)))
    custom = search_vmd_parameters(x, criterion=orthogonality, **kw)
    assert custom.criterion == "orthogonality"


def test_fleet_search_equals_each_units_own_search() -> None:
    xs = np.stack([synthetic_drift_signal(n=1200, seed=s) for s in (5, 6, 7)])
    kw = {"population": 6, "generations": 3, "seed": 3}
    calls: list[int] = []
    real = vmd_batch

    def counting(*args, **kwargs):
        calls.append(len(args[1]))
        return real(*args, **kwargs)

    import gyrolab.compensation.fitness as fitness_mod

    fitness_mod.vmd_batch = counting
    try:
        fleet = fitness_mod.search_vmd_parameters_fleet(xs, **kw)
    finally:
        fitness_mod.vmd_batch = real
    # one batched call per generation for the whole fleet (initial swarm + 3 generations)
    assert len(calls) <= 4 and calls[0] == 3 * 6
    for x, got in zip(xs, fleet, strict=True):
        own = search_vmd_parameters(x, **kw)
        assert (got.K, got.alpha, got.fitness) == (own.K, own.alpha, own.fitness)
        np.testing.assert_array_equal(got.gpso.fitness, own.gpso.fitness)
    with pytest.raises(ValueError, match=r"\(U, N\)"):
        fitness_mod.search_vmd_parameters_fleet(xs[0], **kw)
