"""The Prandtl–Ishlinskii hysteresis operator (a sum of plays) against a play sequence
worked by hand, and the ``structured_pi`` family built on it: reading by reading equals
vectorised, it saves and loads, and it says it has no firmware form; the jackknife test
that keeps the hysteresis term only where there is some (issue 23)."""

from __future__ import annotations

import numpy as np
import pytest
from test_causal import _staircase_run

from gyrolab.compensation.baselines import blocked_folds
from gyrolab.compensation.causal import causal_from_state, causal_state, fit_causal
from gyrolab.compensation.causal_features import CausalParams
from gyrolab.compensation.drift_model import NotExportable, drift_sample_by_sample
from gyrolab.compensation.hysteresis import pi_branches, pi_start, pi_step
from gyrolab.compensation.structured import T_JACK, block_features, jackknife_t, segments

F = np.array([0.0, 1.0, 3.0, 2.0, 0.5, 2.5])
WIDTHS = (1.0, 4.0)


def test_plays_follow_the_hand_computed_sequence() -> None:
    # width 1 (half 0.5): p = 0, 0.5, 2.5, 2.5, 1.0, 2.0 → S = (F − p)/0.5
    # width 4 (half 2):   p = 0, 0, 1, 1, 1, 1          → S = (F − p)/2
    want = np.array([[0.0, 0.0], [1.0, 0.5], [1.0, 1.0], [-1.0, 0.5], [-1.0, -0.25], [1.0, 0.75]])
    p = pi_start(F[0], WIDTHS)
    np.testing.assert_array_equal(pi_branches(F, WIDTHS, p), want)
    np.testing.assert_array_equal(p, [2.0, 1.0])  # the positions after the last reading
    # started 1 °C below F: the narrow play on its heating branch, the wide one halfway
    p = pi_start(F[0], WIDTHS, offset_c=1.0)
    np.testing.assert_array_equal(p, [-0.5, -1.0])
    np.testing.assert_array_equal(pi_branches(F[:1], WIDTHS, p), [[1.0, 0.5]])


def test_one_reading_at_a_time_is_bit_for_bit_the_vectorised_operator() -> None:
    rng = np.random.default_rng(3)
    f = np.cumsum(rng.normal(0.0, 0.7, 400))
    p = pi_start(f[0], (0.5, 1.5, 4.0), 0.25)
    steps = np.array([pi_step(p, float(x), (0.5, 1.5, 4.0)) for x in f])
    assert np.array_equal(
        steps, pi_branches(f, (0.5, 1.5, 4.0), pi_start(f[0], (0.5, 1.5, 4.0), 0.25))
    )
    assert np.all(np.abs(steps) <= 1.0 + 1e-12)


@pytest.fixture(scope="module")
def pi_model():
    cal = _staircase_run(tau_die=300.0, hyst=1e-3, seed=4, hours=3.0)
    m = fit_causal(cal, families=("structured_rate", "structured_pi"), seed=1)
    return cal, m.alternatives["structured_pi"]


def test_structured_pi_replaces_the_play_and_runs_like_firmware(pi_model) -> None:
    cal, m = pi_model
    assert m.family == "structured_pi"
    assert len(m.model.widths) == 3 and "hyst" not in m.model.base.terms
    # the two branches' sum, at rest in the middle of the range: the injected 1e-3 °/s
    assert sum(m.model.hw) * 2 == pytest.approx(1e-3, rel=0.3)
    pt_t, pt_c = cal.pt_t[::15], cal.pt_c[::15]
    t = np.sort(np.concatenate([pt_t, pt_t + 4.0]))
    vec = m.drift_at(t, pt_t, pt_c)
    assert np.array_equal(drift_sample_by_sample(m, t, pt_t, pt_c), vec)
    meta, arrays = causal_state(m, "causal.")
    back = causal_from_state(meta, arrays, "causal.")
    assert type(back) is type(m) and np.array_equal(back.drift_at(t, pt_t, pt_c), vec)
    with pytest.raises(NotExportable, match="structured_pi"):
        m.spec()


@pytest.mark.parametrize(("hyst", "kept"), [(0.0, False), (2e-3, True)])
def test_the_jackknife_keeps_hysteresis_only_where_there_is_some(hyst, kept) -> None:
    cal = _staircase_run(tau_die=300.0, hyst=hyst, seed=7, hours=3.0)
    X = block_features(cal, CausalParams(tau_s=300.0))
    folds = blocked_folds(cal.rate.size, 5, 10)
    assert len(segments(folds)) == 10
    t = jackknife_t(X, cal.rate, 2, ("rate", "hyst"), folds)
    assert (t["hyst"] >= T_JACK) is kept
