"""The one jackknife covariance (gyrolab.numerics.jackknife) on the textbook case, and both
of its callers on it."""

from __future__ import annotations

import numpy as np

from gyrolab.numerics.jackknife import jackknife_covariance


def test_the_jackknife_of_the_mean_is_the_sample_covariance_over_n() -> None:
    """Delete-one estimates of a mean: C = S / n exactly (Efron & Stein 1981, the case the
    (m − 1)/m factor is made for), S the unbiased sample covariance."""
    rng = np.random.default_rng(5)
    x = rng.standard_normal((40, 3)) @ np.array([[1.0, 0.3, 0.0], [0.0, 2.0, 0.5], [0, 0, 0.1]])
    n = x.shape[0]
    loo = (x.sum(axis=0) - x) / (n - 1)  # row k: the mean without sample k
    np.testing.assert_allclose(jackknife_covariance(loo), np.cov(x.T) / n, rtol=1e-12)
    assert not jackknife_covariance(loo[:1]).any()  # one group: no spread


def test_the_structured_t_and_the_prior_covariance_are_one_computation() -> None:
    """jackknife_t's standard errors are the square roots of the diagonal own_covariance
    gives for the same deletions: here the prior's contiguous blocks as the CV's segments."""
    from gyrolab.compensation.prior import own_covariance
    from gyrolab.compensation.structured import design, jackknife_t

    rng = np.random.default_rng(2)
    n, blocks = 600, 6
    temp = 40.0 + 15.0 * np.sin(np.arange(n) / 70.0) + 0.01 * np.arange(n)
    rate = np.gradient(temp)
    X = np.column_stack([temp, rate, np.tanh(np.cumsum(rate) / 5.0)])
    y = 1e-3 * temp + 0.5 * rate + 0.02 * X[:, 2] + 0.05 * rng.standard_normal(n)
    blk = (np.arange(n) * blocks) // n
    folds = [blk == k for k in range(blocks)]  # one segment per fold
    order, terms = 1, ("rate", "hyst")
    A = design(X, order, terms, float(temp.min()), float(temp.max()))
    C = own_covariance(A, y, blocks)
    c = np.linalg.lstsq(A, y, rcond=None)[0]
    t = jackknife_t(X, y, order, terms, folds)
    # the fits differ only in their solver (normal equations against QR)
    j = order + 1 + np.arange(len(terms))
    want = np.abs(c[j]) / np.sqrt(np.diag(C)[j])
    np.testing.assert_allclose([t[name] for name in terms], want, rtol=1e-8)
