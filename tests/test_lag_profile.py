"""The die lag by profile least squares (``PipelineConfig.causal_lag_criterion =
"profile"``, issue 23): the lag chosen again by the in-sample residual of the whole
run's fit finds the die's lag under a wandering bias; the option moves the lag (and
the warm-up's time constant where that term is kept) only (the CV's order, terms and
play width stay, and the families are compared at the CV's parameters), is recorded
in the selection log, and is a checked configuration key (the default; ``"cv"``
selects as before)."""

from __future__ import annotations

import numpy as np
import pytest
from test_causal import _staircase_run

from gyrolab.compensation.baselines import blocked_folds
from gyrolab.compensation.causal import CV_FOLDS, CV_SEGMENTS, fit_causal
from gyrolab.compensation.config import PipelineConfig, config_from_dict
from gyrolab.compensation.structured import LAG_CRITERIA, select_structured
from gyrolab.errors import InputError

TAU_DIE = 250.0


def _wandering_run():
    """:func:`_staircase_run` with a die lag of 250 s and a bias that wanders as a random
    walk (≈ 1e-3 °/s over the run, the scale of a MEMS gyro's 1/f and random-walk
    noise), which the blocked CV's fold fits follow."""
    cal = _staircase_run(tau_die=TAU_DIE, hyst=0.0, seed=11, hours=6.0)
    rng = np.random.default_rng(12)
    cal.rate = cal.rate + np.cumsum(rng.normal(0.0, 2.0e-5, cal.rate.size))
    return cal


def test_profile_lag_finds_the_die_lag_under_a_wandering_bias() -> None:
    cal = _wandering_run()
    folds = blocked_folds(cal.rate.size, CV_FOLDS, CV_SEGMENTS)
    p, order, terms, _err, log = select_structured(cal, folds, lag_criterion="profile")
    prof = log["lag_profile"]
    assert prof["tau_s"] == p.tau_s
    assert 0.75 * TAU_DIE < p.tau_s < 1.25 * TAU_DIE
    # the criterion is the in-sample RMS residual: its grid minimum is where the
    # refinement started, and the refined lag is no worse than it
    crit = {float(k): v for k, v in prof["criterion_by_tau"].items()}
    assert min(crit, key=crit.get) in (150.0, 300.0)
    # only the lag moves: the CV's other choices — order, terms, play, and the warm-up's
    # time constant where (as here) the warm-up term is not kept — stay
    q, order_cv, terms_cv, _, log_cv = select_structured(cal, folds)
    assert "lag_profile" not in log_cv
    assert order == order_cv and terms == terms_cv and prof["tau_plain_cv_s"] == q.tau_s
    assert (p.warmup_tau_s, p.width_c) == (q.warmup_tau_s, q.width_c)
    with pytest.raises(ValueError, match="lag_criterion"):
        select_structured(cal, folds, lag_criterion="whitened")


def test_the_families_are_compared_at_the_cv_lag_and_the_winner_ships_the_profile_lag() -> None:
    """The profile lag never changes which family wins: every family's score is the one
    the plain CV gives (at the CV's lag), and only the chosen model's τ moves — on
    gyrolab's validation unit 5 the CV at the profile lag was jagged and handed the
    selection to the polynomial (docs/results.md)."""
    cal = _wandering_run()
    fams = ("poly", "structured")
    m = fit_causal(cal, families=fams, config=PipelineConfig(), seed=0)  # the default
    c = fit_causal(cal, families=fams, config=PipelineConfig(causal_lag_criterion="cv"), seed=0)
    assert m.cv_rmse == c.cv_rmse and m.family == c.family == "structured"
    log = m.selection["structured"]
    assert m.params.tau_s == log["lag_profile"]["tau_s"] != c.params.tau_s
    assert log["lag_profile"]["tau_plain_cv_s"] == c.params.tau_s
    assert 0.75 * TAU_DIE < m.params.tau_s < 1.25 * TAU_DIE
    # the shipped model's own held-out error, at its lag, is recorded beside the score
    assert np.isfinite(log["cv_rmse_at_profile_lag"])
    assert "cv_rmse_at_profile_lag" not in c.selection["structured"]


def test_the_lag_criterion_is_a_checked_configuration_key() -> None:
    assert PipelineConfig().causal_lag_criterion == "profile"  # the default (issue 23)
    assert LAG_CRITERIA == ("cv", "profile", "profile_warmup")
    cfg, _ = config_from_dict({"causal_lag_criterion": "profile"}, path="c.toml")
    assert cfg.causal_lag_criterion == "profile"
    with pytest.raises(InputError, match="causal_lag_criterion"):
        config_from_dict({"causal_lag_criterion": "whitened"}, path="c.toml")
