"""GA-BP (paper §3.3): network equations, GA operators, training, persistence."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from gyrolab.compensation.gabp import (
    BPConfig,
    GAConfig,
    MLPDriftModel,
    _nonuniform,
    fit_gabp,
    forward,
    genetic_init,
    n_weights,
)

torch.set_num_threads(1)

SMALL_GA = GAConfig(population=20, generations=15, fitness_points=500)
SMALL_BP = BPConfig(hidden=6, max_iter=200)


def _drift(temp: np.ndarray) -> np.ndarray:
    """A smooth nonlinear bias(T) curve in °/s (the shape a MEMS gyro shows)."""
    d = temp - 25.0
    return 4e-3 + 2e-4 * d - 3e-6 * d**2 + 1e-7 * d**3


def test_forward_is_eqs_15_to_17_and_matches_torch() -> None:
    rng = np.random.default_rng(0)
    n_in, hidden = 2, 5
    theta = rng.normal(size=n_weights(n_in, hidden))
    X = rng.normal(size=(50, n_in))
    W = theta[: n_in * hidden].reshape(n_in, hidden)
    a = theta[n_in * hidden : n_in * hidden + hidden]
    w = theta[n_in * hidden + hidden : -1]
    by_hand = (1.0 / (1.0 + np.exp(-(X @ W + a)))) @ w + theta[-1]
    np.testing.assert_allclose(forward(theta, X, n_in, hidden), by_hand, rtol=1e-12)
    m = MLPDriftModel(theta, n_in, hidden, np.zeros(n_in), np.ones(n_in), 0.0, 1.0)
    net = torch.nn.Sequential(
        torch.nn.Linear(n_in, hidden), torch.nn.Sigmoid(), torch.nn.Linear(hidden, 1)
    ).double()
    net.load_state_dict(m.torch_state_dict())
    with torch.no_grad():
        tout = net(torch.tensor(X)).numpy().ravel()
    np.testing.assert_allclose(tout, by_hand, rtol=1e-10)
    # a population evaluates row by row
    pop = rng.normal(size=(3, theta.size))
    np.testing.assert_allclose(forward(pop, X, n_in, hidden)[1], forward(pop[1], X, n_in, hidden))


@settings(max_examples=50, deadline=None)
@given(
    x=st.floats(-4, 4),
    gen=st.integers(0, 40),
    seed=st.integers(0, 2**31),
)
def test_nonuniform_mutation_stays_in_bounds_and_shrinks(x: float, gen: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    xs = np.full(200, x)
    out = _nonuniform(xs, gen, 40, -4.0, 4.0, 2.0, rng)
    assert np.all(out >= -4.0) and np.all(out <= 4.0)
    # at the last generation the step is zero: the GA only fine-tunes by then
    last = _nonuniform(xs, 40, 40, -4.0, 4.0, 2.0, np.random.default_rng(seed))
    np.testing.assert_allclose(last, xs)


def test_ga_best_never_gets_worse_and_improves() -> None:
    rng = np.random.default_rng(1)
    T = rng.uniform(-35, 55, 400)  # ≤ fitness_points: fitness sees every sample
    y = _drift(T)
    Xs = ((T - T.mean()) / T.std())[:, None]
    ys = (y - y.mean()) / y.std()
    res = genetic_init(Xs, ys, hidden=6, cfg=SMALL_GA, seed=3)
    h = np.array(res.best_history)
    assert np.all(np.diff(h) <= 1e-15), "elitism keeps the best individual"
    assert h[-1] < 0.5 * h[0]
    mse = np.mean((forward(res.best, Xs, 1, 6) - ys) ** 2)
    assert mse == pytest.approx(h[-1], rel=1e-9, abs=1e-12)


def test_gabp_learns_nonlinear_drift_and_is_reproducible() -> None:
    rng = np.random.default_rng(2)
    T = np.sort(rng.uniform(-35, 55, 3000))
    noise = 2e-4
    y = _drift(T) + rng.normal(0, noise, T.size)
    m1 = fit_gabp(T[:, None], y, ga=SMALL_GA, bp=SMALL_BP, seed=5)
    m2 = fit_gabp(T[:, None], y, ga=SMALL_GA, bp=SMALL_BP, seed=5)
    np.testing.assert_array_equal(m1.theta, m2.theta)
    Tt = np.linspace(-30, 50, 200)
    err = m1.predict(Tt[:, None]) - _drift(Tt)
    # the curve spans ~0.03 °/s; the fit must come within a fraction of the noise
    assert np.sqrt(np.mean(err**2)) < 0.3 * noise
    assert m1.ga_best_history and m1.bp_loss_history[-1] <= m1.bp_loss_history[0]


def test_state_round_trip_predicts_identically() -> None:
    rng = np.random.default_rng(3)
    X = np.column_stack([rng.uniform(-30, 50, 500), rng.normal(0, 1e-3, 500)])
    y = _drift(X[:, 0]) + 0.5 * X[:, 1]
    m = fit_gabp(X, y, ga=SMALL_GA, bp=SMALL_BP, seed=0)
    meta, arrays = m.to_state("gabp.")
    back = MLPDriftModel.from_state(meta, arrays, "gabp.")
    np.testing.assert_array_equal(back.predict(X), m.predict(X))
    assert back.n_in == 2 and back.init == "ga"


def test_bad_training_data_is_rejected() -> None:
    with pytest.raises(ValueError, match="finite"):
        fit_gabp(np.array([[1.0], [np.nan], [2.0], [3.0]]), np.ones(4), ga=SMALL_GA)


def test_outside_the_training_range_the_network_continues_linearly() -> None:
    rng = np.random.default_rng(4)
    T = rng.uniform(-20, 40, 1500)
    m = fit_gabp(T[:, None], _drift(T), ga=SMALL_GA, bp=SMALL_BP, seed=1)
    hi = m.x_max[0]
    eps = 1e-4
    slope = (m.predict(np.array([[hi]])) - m.predict(np.array([[hi - eps]]))) / eps
    beyond = hi + np.array([1.0, 5.0, 10.0])
    expect = m.predict(np.array([[hi]])) + slope * (beyond - hi)
    np.testing.assert_allclose(m.predict(beyond[:, None]), expect, rtol=1e-4, atol=1e-9)
    # continuous at the edge, and inside the range the plain network is untouched
    assert m.predict(np.array([[hi + 1e-9]]))[0] == pytest.approx(m.predict(np.array([[hi]]))[0])
    inside = np.linspace(-19, 39, 50)[:, None]
    Xs = (inside - m.x_mean) / m.x_std
    np.testing.assert_allclose(
        m.predict(inside), forward(m.theta, Xs, 1, m.hidden) * m.y_std + m.y_mean, rtol=1e-12
    )
