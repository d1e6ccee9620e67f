"""Causal drift models: the firmware state machine equals the offline evaluation; the
family selection; rotation survives the causal output; the headline metric keys."""

from __future__ import annotations

import numpy as np
import pytest

from gyrolab.compensation.causal_features import (
    CausalParams,
    features,
    initial_state,
    reading_features,
    step,
)


@pytest.mark.parametrize("tau", [0.0, 12.0, 600.0])
def test_step_equals_vectorised_features_bit_for_bit(tau: float) -> None:
    rng = np.random.default_rng(3)
    n = 3000
    T = 25.0 + np.cumsum(rng.normal(0.0, 0.05, n))
    dt = rng.uniform(0.5, 1.5, n)
    dt[0] = 0.0
    p = CausalParams(tau_s=tau, width_c=0.7, warmup_tau_s=500.0)
    X = features(T, dt, p)
    s = initial_state(T[0])
    Y = np.array([step(s, float(T[i]), float(dt[i]), p) for i in range(n)])
    assert np.array_equal(X, Y)
    # the state carried across two calls equals one call over the whole run
    s2 = initial_state(T[0])
    Z = np.vstack([features(T[:1234], dt[:1234], p, s2), features(T[1234:], dt[1234:], p, s2)])
    assert np.array_equal(X, Z)


def test_features_follow_their_equations() -> None:
    # a slow ramp: the lagged temperature trails by rate·τ, R is the rate, S the branch
    t = np.arange(0.0, 20000.0)
    T = np.where(t < 10000, 0.001 * t, 10.0 - 0.001 * (t - 10000))
    X = reading_features(t, T, CausalParams(tau_s=300.0, width_c=1.0, warmup_tau_s=600.0))
    i = 9000
    assert X[i, 0] == pytest.approx(T[i] - 0.001 * 300.0, abs=1e-3)
    assert X[i, 1] == pytest.approx(0.001, rel=3e-3)  # discrete step: Δt/2τ
    assert X[i, 2] == 1.0 and X[-1000, 2] == -1.0
    assert X[600, 3] == pytest.approx(np.exp(-1.0))
