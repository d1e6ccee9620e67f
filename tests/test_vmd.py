"""VMD: parity with vmdpy, odd lengths, batching (numba and torch), memory, validation."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from gyrolab.compensation.vmd import vmd, vmd_batch


def _signal(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(n)
    return (
        np.sin(2 * np.pi * t / 200)
        + 0.5 * np.sin(2 * np.pi * t / 13)
        + 0.2 * rng.standard_normal(n)
        + 1e-3 * t
    )


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


@pytest.mark.parametrize(
    ("K", "alpha", "n"), [(3, 2000.0, 2000), (5, 50.0, 1200), (11, 4641.0, 1000)]
)
def test_matches_vmdpy_penultimate_iterate(K: int, alpha: float, n: int) -> None:
    vmdpy = pytest.importorskip("vmdpy")
    x = _signal(n)
    u_ref, _, omega_hist = vmdpy.VMD(x, alpha, 0.0, K, 0, 1, 1e-7)
    n_ref = omega_hist.shape[0]  # vmdpy ran n_ref iterations and returns iterate n_ref - 1
    ours = vmd(x, alpha, K, tau=0.0, tol=0.0, max_iter=n_ref - 1)
    assert ours.n_iter == n_ref - 1
    assert ours.modes.shape == u_ref.shape == (K, n)
    assert _rel(ours.modes, u_ref) <= 1e-6
    np.testing.assert_allclose(ours.omega, omega_hist[-1], rtol=0, atol=1e-9)
    # the product's own stopping rule stops on the same iteration as vmdpy's (whose cap is
    # 499 iterations; ours is max_iter = 500)
    assert min(vmd(x, alpha, K).n_iter, 499) == n_ref


def test_recovers_two_tones_and_their_frequencies() -> None:
    n = 4000
    t = np.arange(n)
    low, high = np.cos(2 * np.pi * 0.01 * t), 0.5 * np.cos(2 * np.pi * 0.2 * t)
    r = vmd(low + high, 2000.0, 2, tol=1e-10)
    assert r.converged
    np.testing.assert_allclose(r.omega, [0.01, 0.2], atol=2e-4)
    inner = slice(200, n - 200)  # away from the mirror joins
    assert _rel(r.modes[0, inner], low[inner]) < 0.02
    assert _rel(r.modes[1, inner], high[inner]) < 0.02


@pytest.mark.parametrize("n", [999, 1001, 1501])
def test_odd_lengths_are_kept_whole(n: int) -> None:
    x = _signal(n, seed=n)
    r = vmd(x, 100.0, 4, tau=0.5, tol=1e-9)
    assert r.modes.shape == (4, n)
    # with tau > 0 the dual ascent enforces sum(modes) = signal, last sample included
    assert _rel(r.modes.sum(0), x) < 1e-3
    assert abs(r.modes[:, -1].sum() - x[-1]) < 0.05 * np.std(x)


def test_odd_length_agrees_with_even_neighbour_inside() -> None:
    x = _signal(2001, seed=3)
    odd = vmd(x, 2000.0, 3)
    even = vmd(x[:-1], 2000.0, 3)
    # the two tonal modes agree; the third holds only noise and wanders more
    np.testing.assert_allclose(odd.omega[:2], even.omega[:2], atol=1e-4)
    inner = slice(300, 1700)
    for k in (0, 1):
        assert _rel(odd.modes[k, inner], even.modes[k, inner]) < 0.02


def test_dc_mode_is_held_at_zero() -> None:
    r = vmd(_signal(800), 500.0, 3, dc=True)
    assert r.omega[0] == 0.0
    assert np.all(np.diff(r.omega) > 0)


def test_batch_numba_equals_single_calls() -> None:
    x = _signal(1500, seed=1)
    alphas, Ks = [2000.0, 50.0, 500.0, 3000.0, 50.0], [3, 5, 4, 2, 3]
    batch = vmd_batch(x, alphas, Ks, backend="numba", tau=0.05)
    for a, k, b in zip(alphas, Ks, batch, strict=True):
        s = vmd(x, a, k, tau=0.05)
        assert (b.K, b.alpha, b.n_iter, b.converged) == (k, a, s.n_iter, s.converged)
        assert _rel(b.modes, s.modes) < 1e-12
        np.testing.assert_allclose(b.omega, s.omega, atol=1e-12)


@pytest.mark.parametrize(("tau", "dc"), [(0.0, False), (0.1, True)])
def test_batch_torch_cpu_equals_single_calls(tau: float, dc: bool) -> None:
    pytest.importorskip("torch")
    x = _signal(1001, seed=2)
    alphas, Ks = [2000.0, 50.0, 700.0], [3, 6, 2]
    batch = vmd_batch(x, alphas, Ks, backend="torch", device="cpu", max_iter=150, tau=tau, dc=dc)
    for a, k, b in zip(alphas, Ks, batch, strict=True):
        s = vmd(x, a, k, max_iter=150, tau=tau, dc=dc)
        assert b.n_iter == s.n_iter and b.modes.shape == (k, 1001)
        assert _rel(b.modes, s.modes) < 1e-9
        np.testing.assert_allclose(b.omega, s.omega, atol=1e-9)


def test_batch_chunks_do_not_change_results() -> None:
    x = _signal(700, seed=4)
    alphas, Ks = [100.0, 900.0, 2500.0, 60.0], [4, 3, 5, 2]
    whole = vmd_batch(x, alphas, Ks, backend="numba")
    split = vmd_batch(x, alphas, Ks, backend="numba", chunk=1)
    for a, b in zip(whole, split, strict=True):
        np.testing.assert_array_equal(a.modes, b.modes)


@pytest.mark.skipif(
    not pytest.importorskip("torch").cuda.is_available(), reason="needs a CUDA device"
)
def test_cuda_batch_matches_cpu() -> None:
    x = _signal(11000, seed=5)
    alphas, Ks = [50.0, 2000.0, 5000.0], [11, 7, 3]
    gpu = vmd_batch(x, alphas, Ks, backend="torch", device="cuda")
    cpu = vmd_batch(x, alphas, Ks, backend="numba")
    for g, c in zip(gpu, cpu, strict=True):
        assert g.n_iter == c.n_iter
        assert _rel(g.modes, c.modes) < 1e-9


def test_memory_has_no_iteration_history() -> None:
    n, K = 50_000, 5
    x = _signal(n, seed=6)
    vmd(x[:100], 100.0, 2)  # compile outside the measurement
    tracemalloc.start()
    vmd(x, 2000.0, K, max_iter=30)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    # modes + spectra + a few work vectors; 500 iterations of history would be ~2 GB
    assert peak < (3 * K + 12) * n * 8


@pytest.mark.parametrize(
    ("args", "match"),
    [
        ((np.ones((3, 3)), 100.0, 2), "one-dimensional"),
        ((np.ones(3), 100.0, 2), "at least 4"),
        ((np.array([1.0, np.nan, 2.0, 3.0, 4.0]), 100.0, 2), "NaN"),
        ((np.ones(10), -1.0, 2), "alpha"),
        ((np.ones(10), 100.0, 0), "K"),
        ((np.ones(10), 100.0, 2.5), "K"),
    ],
)
def test_bad_arguments_are_rejected(args: tuple, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        vmd(*args)


def test_zero_signal_gives_zero_modes() -> None:
    r = vmd(np.zeros(64), 100.0, 3)
    assert np.all(r.modes == 0) and np.all(np.isfinite(r.omega))


def test_batch_over_units_equals_single_calls() -> None:
    xs = np.stack([_signal(900, seed=s) for s in (7, 8)])
    alphas, Ks, units = [300.0, 2000.0, 300.0, 60.0], [4, 3, 4, 2], [0, 1, 1, 0]
    batch = vmd_batch(xs, alphas, Ks, units=units, backend="numba", tau=0.02)
    for a, k, u, b in zip(alphas, Ks, units, batch, strict=True):
        s = vmd(xs[u], a, k, tau=0.02)
        assert b.n_iter == s.n_iter
        np.testing.assert_array_equal(b.modes, s.modes)
    with pytest.raises(ValueError, match="units"):
        vmd_batch(xs, alphas, Ks)
    with pytest.raises(ValueError, match="units"):
        vmd_batch(xs, alphas, Ks, units=[0, 1, 2, 0])
