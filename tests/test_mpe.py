"""Permutation entropy vs antropy, coarse-graining (eq. 21), MPE speed and classification."""

from __future__ import annotations

import time

import antropy
import numpy as np
import pytest
from scipy import signal

from gyrolab.compensation.mpe import (
    classify_modes,
    coarse_grain,
    mean_mpe,
    multiscale_perm_entropy,
    perm_entropy,
)
from gyrolab.errors import InputError


@pytest.mark.parametrize("order", [2, 3, 4, 5, 6, 7])
@pytest.mark.parametrize("delay", [1, 2, 5])
@pytest.mark.parametrize("length", [40, 997, 6000])
def test_matches_antropy(order: int, delay: int, length: int) -> None:
    rng = np.random.default_rng(order * 1000 + delay * 10 + length)
    x = rng.standard_normal(length)
    x[7::7] = x[6:-1:7][: x[7::7].size]  # some exact ties
    ref = antropy.perm_entropy(x, order=order, delay=delay, normalize=True)
    assert abs(perm_entropy(x, order=order, delay=delay) - ref) <= 1e-12
    ref_bits = antropy.perm_entropy(x, order=order, delay=delay, normalize=False)
    assert abs(perm_entropy(x, order, delay, normalize=False) - ref_bits) <= 1e-12


@pytest.mark.parametrize("order", [3, 4, 5])
def test_matches_antropy_heavy_ties(order: int) -> None:
    x = np.random.default_rng(1).integers(0, 3, 3000).astype(float)
    ref = antropy.perm_entropy(x, order=order, normalize=True)
    assert abs(perm_entropy(x, order=order) - ref) <= 1e-12


def test_extremes() -> None:
    assert perm_entropy(np.arange(500.0)) == 0.0  # monotonic: one pattern
    x = np.random.default_rng(0).standard_normal(200_000)
    assert perm_entropy(x, order=3) > 0.999  # white noise: all patterns equally likely


def test_coarse_grain_eq21() -> None:
    x = np.arange(10.0)
    np.testing.assert_allclose(coarse_grain(x, 3), [1.0, 4.0, 7.0])  # tail 9 dropped
    np.testing.assert_array_equal(coarse_grain(x, 1), x)


def test_multiscale_uses_coarse_grained_series() -> None:
    x = np.random.default_rng(3).standard_normal(3000)
    mpe = multiscale_perm_entropy(x, scales=12, order=4)
    assert mpe.shape == (12,)
    for s in (1, 5, 12):
        ref = antropy.perm_entropy(coarse_grain(x, s), order=4, normalize=True)
        assert mpe[s - 1] == pytest.approx(ref, abs=1e-12)
    np.testing.assert_allclose(multiscale_perm_entropy(x, scales=[2, 7]), mpe[[1, 6]])


def _band_mode(fc: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """A VMD-like narrow-band mode: white noise band-passed around fc (cycles/sample)."""
    bw = 0.3 * fc
    sos = signal.butter(2, [2 * (fc - bw / 2), 2 * (fc + bw / 2)], "bandpass", output="sos")
    return signal.sosfiltfilt(sos, rng.standard_normal(n + 4000))[2000:-2000]


def test_classification_noise_mixed_drift() -> None:
    """White noise -> noise, a slow temperature-like drift -> drift, a mid band -> mixed."""
    rng = np.random.default_rng(12)
    n = 11_000
    t = np.arange(n)
    modes = np.stack(
        [
            rng.standard_normal(n),  # white noise
            _band_mode(0.3, n, rng),  # high-frequency band: noise-like
            _band_mode(0.03, n, rng),  # mid band: mixed
            _band_mode(0.001, n, rng),  # slow band (period ~1000 samples): drift
            np.tanh((t - n / 2) / 800.0) + np.sin(2 * np.pi * t / n * 3),  # smooth drift
        ]
    )
    v = mean_mpe(modes, scales=12, order=4)
    classes = classify_modes(v)
    assert classes == {"noise": [0, 1], "mixed": [2], "drift": [3, 4]}, v
    # thresholds are configurable
    lo, hi = np.sort(v)[[1, 3]]  # thresholds are configurable: move both inwards
    assert classify_modes(v, noise_min=hi + 1e-9, drift_max=lo - 1e-9)["mixed"] == [
        int(i) for i in np.flatnonzero((v >= lo) & (v <= hi))
    ]


def test_speed_paper_size() -> None:
    """11 modes x 11 000 samples x 12 scales (the paper's run) well under a second of CPU
    (the process's CPU time, all its threads: other work on a loaded machine stretches the
    wall time, not this)."""
    modes = np.random.default_rng(5).standard_normal((11, 11_000))
    mean_mpe(modes[:1, :500])  # numba compile (cached)
    t0 = time.process_time()
    v = mean_mpe(modes)
    dt = time.process_time() - t0
    assert v.shape == (11,) and np.all(v > 0.99)
    assert dt < 0.5, dt


def test_bad_input() -> None:
    with pytest.raises(InputError, match="NaN"):
        perm_entropy([1.0, np.nan, 2.0, 3.0, 4.0])
    with pytest.raises(InputError, match="too short"):
        multiscale_perm_entropy(np.arange(30.0), scales=12, order=4)
    with pytest.raises(InputError, match="order"):
        perm_entropy(np.arange(30.0), order=1)
    with pytest.raises(InputError, match="drift_max"):
        classify_modes([0.5], noise_min=0.4, drift_max=0.6)
