"""Least squares with autoregressive noise, scored by the Bayesian information criterion.

The low-frequency gyro output is ``y = X β + u`` where ``u`` (flicker + white rate noise
averaged into bins) is strongly correlated, so ordinary least squares would call almost any
extra regressor "significant". The noise is modelled as AR(p)::

    u_t = Σ_{j=1..p} φ_j u_{t−j} + e_t,   e_t white with variance σ²

and fitted by feasible GLS (Cochrane–Orcutt iterations): OLS for β → AR fit of the
residual → OLS of the whitened ``ỹ_t = y_t − Σ φ_j y_{t−j}`` on the whitened columns → …
A model is scored by::

    BIC = n_e ln(RSS_e / n_e) + (k + p) ln n_e

with ``RSS_e`` the whitened (innovation) residual sum of squares over ``n_e = n − p``
samples and ``k`` the number of fitted parameters (linear columns plus nonlinear ones such
as a time constant). A signal that the regressors miss is partly "explained" by the AR part
of the base model, but only at the cost of larger innovations, so the comparison stays fair.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def ar_fit(u: np.ndarray, p: int) -> np.ndarray:
    """Least-squares AR(p) coefficients ``φ_1..φ_p`` of the series ``u``."""
    if p == 0:
        return np.empty(0)
    n = u.size
    lag = np.column_stack([u[p - j : n - j] for j in range(1, p + 1)])
    phi, *_ = np.linalg.lstsq(lag, u[p:], rcond=None)
    return phi


def ar_whiten(x: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Innovations ``x_t − Σ φ_j x_{t−j}`` for ``t ≥ p`` (rows of a 2-D ``x`` likewise)."""
    p = phi.size
    if p == 0:
        return x
    n = x.shape[0]
    out = x[p:].copy()
    for j in range(1, p + 1):
        out -= phi[j - 1] * x[p - j : n - j]
    return out


@dataclass
class GlsResult:
    """A fitted linear model with AR(p) noise."""

    beta: np.ndarray
    phi: np.ndarray
    rss: float
    n: int
    k: int

    @property
    def bic(self) -> float:
        return self.n * np.log(self.rss / self.n) + (self.k + self.phi.size) * np.log(self.n)

    @property
    def sigma(self) -> float:
        """Innovation standard deviation."""
        return float(np.sqrt(self.rss / self.n))


def gls_ar(
    y: np.ndarray,
    X: np.ndarray,
    p: int = 4,
    iterations: int = 3,
    extra_params: int = 0,
    phi: np.ndarray | None = None,
) -> GlsResult:
    """Feasible-GLS fit of ``y ≈ X β`` with AR(``p``) noise (module docstring).

    ``extra_params`` counts nonlinear parameters chosen outside (for the BIC). With ``phi``
    given, the noise model is held fixed (one whitened OLS: a fast scan of a grid).
    """
    scale = np.sqrt(np.mean(X * X, axis=0))
    scale[scale == 0] = 1.0
    Xs = X / scale
    if phi is not None:
        yw, Xw = ar_whiten(y, phi), ar_whiten(Xs, phi)
        b, *_ = np.linalg.lstsq(Xw, yw, rcond=None)
        e = yw - Xw @ b
        return GlsResult(b / scale, phi, float(e @ e), e.size, X.shape[1] + extra_params)
    b, *_ = np.linalg.lstsq(Xs, y, rcond=None)
    ph = np.empty(0)
    for _ in range(iterations):
        ph = ar_fit(y - Xs @ b, p)
        yw, Xw = ar_whiten(y, ph), ar_whiten(Xs, ph)
        b, *_ = np.linalg.lstsq(Xw, yw, rcond=None)
    e = ar_whiten(y - Xs @ b, ph)
    return GlsResult(b / scale, ph, float(e @ e), e.size, X.shape[1] + extra_params)
