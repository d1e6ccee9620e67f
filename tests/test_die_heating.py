"""The die's own self-heating δ_d (issue 23): chosen by profile least squares where the
drift follows a die that warms above its case after power-on, never where it does not."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gyrolab.compensation.causal_features import CausalParams, reading_features
from gyrolab.compensation.structured import _die_heating, design, fit_structured

TERMS = ("rate", "hyst")


def _run(start_c: float, ramp_first: bool) -> tuple[np.ndarray, np.ndarray]:
    """PT100 readings at 1 Hz: powered on at ``start_c``; with ``ramp_first`` a 1 °C/min
    ramp at once (the die warms while the case moves), then ramps through −40 … 60 °C."""
    legs = [np.full(1800, start_c)] if not ramp_first else []
    for a, b in ((start_c, 60.0), (60.0, -40.0), (-40.0, 25.0)):
        legs += [np.linspace(a, b, int(abs(b - a) * 60)), np.full(1800, b)]
    T = np.concatenate(legs)
    return np.arange(T.size, dtype=float), T


def _drift(X: np.ndarray) -> np.ndarray:
    """A strongly curved bias in the die temperature (column 0) and a rate term, °/s."""
    u = (X[:, 0] - 10.0) / 50.0
    return 1e-3 * (2.0 * u + 3.0 * u**2 - 4.0 * u**4) + 0.2 * X[:, 1]


@pytest.mark.parametrize("die", [0.0, 3.0])
def test_die_heating_found_where_the_die_has_it(die: float) -> None:
    rng = np.random.default_rng(7)
    truth = CausalParams(tau_s=300.0, width_c=1.0, warmup_tau_s=600.0, die_heating_c=die)
    t, T = _run(25.0, ramp_first=True)
    y = _drift(reading_features(t, T, truth)) + rng.normal(0.0, 2e-5, t.size)
    start = replace(truth, die_heating_c=0.0)

    def feature(p: CausalParams) -> np.ndarray:
        return reading_features(t, T, p)

    p, terms, log = _die_heating(feature, y, start, 4, TERMS)
    if not die:  # nothing to find: the step keeps the choice it was given
        assert p == start and terms == TERMS and log["die_heating_c"] == 0.0
        return
    assert p.die_heating_c == pytest.approx(die, abs=1.0)
    assert "warmup" in terms and log["rms"] < 0.99 * log["rms_without"]
    # a cold power-on: the model with δ_d predicts the die's warm-up there, the one
    # without it (an additive warm-up at the calibration's power-on) does not
    tc, Tc = _run(-35.0, ramp_first=False)
    yc = _drift(reading_features(tc, Tc, truth))
    errs = []
    for q, tt in ((p, terms), (start, TERMS + ("warmup",))):
        X = feature(q)
        m = fit_structured(X, y, 4, tt)
        assert design(X, 4, tt, m.lo, m.hi).shape[1] == 5 + len(tt)
        errs.append(float(np.sqrt(np.mean((yc - m.predict(reading_features(tc, Tc, q))) ** 2))))
    assert errs[0] < 0.5 * errs[1]
