"""Baselines: polynomial in temperature (order by blocked CV) and plain BP."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from gyrolab.compensation.baselines import (
    PolyDriftModel,
    blocked_folds,
    fit_plain_bp,
    fit_poly,
)
from gyrolab.compensation.gabp import BPConfig

torch.set_num_threads(1)


def test_blocked_folds_partition_time_into_contiguous_blocks() -> None:
    folds = blocked_folds(1000, k=5, n_blocks=20)
    cover = np.sum(folds, axis=0)
    assert np.all(cover == 1), "every sample is held out exactly once"
    for f in folds:
        runs = np.flatnonzero(np.diff(f.astype(int)) == 1)
        assert len(runs) <= 4 and f.sum() == 200  # 4 blocks of 50 per fold


def test_poly_order_chosen_by_held_out_error() -> None:
    rng = np.random.default_rng(0)
    # staircase-like temperature history, cubic bias
    T = np.repeat(np.linspace(55, -33, 10), 400) + rng.normal(0, 0.3, 4000)
    T = np.convolve(T, np.ones(50) / 50, mode="same")
    d = T - 25
    y = 1e-3 + 2e-4 * d - 3e-6 * d**2 + 1e-7 * d**3 + rng.normal(0, 1e-4, T.size)
    m = fit_poly(T, y)
    assert 3 <= m.order <= 5
    assert m.cv_rmse[m.order] < 0.5 * m.cv_rmse[1]
    truth = 1e-3 + 2e-4 * d - 3e-6 * d**2 + 1e-7 * d**3
    assert np.std(m.predict(T) - truth) < 2e-5


def test_poly_recovers_rate_term_and_round_trips() -> None:
    rng = np.random.default_rng(1)
    n = 3000
    T = 20 + 30 * np.sin(np.linspace(0, 6, n))
    dTdt = np.gradient(T, 3.6)
    y = 1e-3 + 1e-4 * (T - 25) + 0.2 * dTdt + rng.normal(0, 1e-5, n)
    X = np.column_stack([T, dTdt])
    m = fit_poly(X, y)
    assert m.rate_coef == pytest.approx(0.2, rel=0.05)
    meta, arrays = m.to_state("poly.")
    back = PolyDriftModel.from_state(meta, arrays, "poly.")
    np.testing.assert_array_equal(back.predict(X), m.predict(X))


def test_poly_rejects_constant_temperature() -> None:
    with pytest.raises(ValueError, match="does not vary"):
        fit_poly(np.full(100, 25.0), np.zeros(100))


def test_plain_bp_is_random_init_same_network() -> None:
    rng = np.random.default_rng(2)
    T = rng.uniform(-35, 55, 2000)
    y = 1e-3 * np.tanh((T - 10) / 20) + rng.normal(0, 2e-5, T.size)
    m = fit_plain_bp(T[:, None], y, bp=BPConfig(hidden=6, max_iter=300), seed=0)
    assert m.init == "random" and not m.ga_best_history
    Tt = np.linspace(-30, 50, 100)
    assert np.max(np.abs(m.predict(Tt[:, None]) - 1e-3 * np.tanh((Tt - 10) / 20))) < 3e-5
