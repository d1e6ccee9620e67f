"""The variants that ``benchmarks/rate_extrapolation.py`` measures (issue 23's worst case,
docs/results.md): the rate columns held at the calibrated range, and the shrinkage of the
heating-only and R|R| coefficients by their jackknife t."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from rate_extrapolation import held_rate, shrunk  # noqa: E402

from gyrolab.compensation.baselines import blocked_folds  # noqa: E402
from gyrolab.compensation.structured import StructuredModel, fit_structured  # noqa: E402


def _rows(R: np.ndarray) -> np.ndarray:
    F = np.linspace(-40.0, 60.0, R.size)
    return np.column_stack([F, R, np.sign(np.sin(F / 7.0)), np.exp(-np.arange(R.size) / 50.0)])


def test_held_rate_is_the_model_inside_the_range_and_flat_beyond() -> None:
    m = StructuredModel(
        coef=np.array([1e-3, 2e-3]), lo=-40.0, hi=60.0, k=0.5, h=2e-4, A=1e-3,
        terms=("rate", "hyst", "warmup", "rate_pos", "rate_sq"), kp=0.3, k2=40.0,
    )  # fmt: skip
    lo, hi = -0.01, 0.02
    X = _rows(np.linspace(-0.01, 0.02, 31))
    for lin in (True, False):
        np.testing.assert_allclose(held_rate(m, X, lo, hi, lin), m.predict(X), rtol=1e-12)
    X2 = _rows(np.array([0.02, 0.05, 0.1, -0.01, -0.05]))
    X2[:, 0] = 10.0
    X2[:, 2:] = 0.0
    y = held_rate(m, X2, lo, hi, True)
    assert np.all(y[:3] == y[0]) and np.all(y[3:] == y[3])  # every rate column held
    y = held_rate(m, X2, lo, hi, False)  # k R continues, the others held
    np.testing.assert_allclose(np.diff(y[:3]), m.k * np.diff(X2[:3, 1]), rtol=1e-9)


def test_shrink_keeps_a_well_identified_term_and_shrinks_a_noisy_one() -> None:
    rng = np.random.default_rng(3)
    n = 4000
    t = np.arange(n)
    R = 0.01 * np.sin(2 * np.pi * t / 800.0)
    X = _rows(R)
    X[:, 0] = 20.0 * np.sin(2 * np.pi * t / 3000.0)
    folds = blocked_folds(n, 5, 10)
    terms = ("rate", "rate_pos")
    noise = 1e-4 * rng.standard_normal(n)
    for kp, near in ((0.05, 1.0), (0.0, None)):
        y = 1e-3 * X[:, 0] / 20.0 + 0.1 * R + kp * np.maximum(R, 0.0) + noise
        m = fit_structured(X, y, 1, terms)
        ms, fac = shrunk(m, X, y, folds)
        assert set(fac) == {"rate_pos"}
        t_j, f = fac["rate_pos"]
        assert 0.0 <= f < 1.0 and abs(ms.kp) <= abs(m.kp)
        if near is not None:  # |t| large: factor ≈ 1, the fit unchanged
            assert t_j > 10 and f > 0.99 and abs(ms.kp - m.kp) < 0.01 * abs(m.kp)
    # a model without the shrunk terms is returned as it is
    m0 = fit_structured(X, y, 1, ("rate",))
    ms0, fac0 = shrunk(m0, X, y, folds)
    assert ms0 is m0 and fac0 == {}
