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
from scipy.linalg import lstsq as _lstsq


def _ls(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Least-squares solution by column-pivoted QR (LAPACK gelsy: faster than SVD here)."""
    return _lstsq(A, b, lapack_driver="gelsy", check_finite=False)[0]


def ar_fit(u: np.ndarray, p: int) -> np.ndarray:
    """Least-squares AR(p) coefficients ``φ_1..φ_p`` of the series ``u``."""
    if p == 0:
        return np.empty(0)
    n = u.size
    lag = np.column_stack([u[p - j : n - j] for j in range(1, p + 1)])
    return _ls(lag, u[p:])


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
    logdet: float = 0.0
    """ln det of the (unit-scale) noise covariance, when it is a known one."""

    @property
    def bic(self) -> float:
        """``n ln(RSS/n) + ln det Σ₀ + (k + p) ln n``: −2 × the Gaussian log-likelihood with
        the noise scale profiled out, plus the BIC penalty. The ``ln det`` term lets two
        different noise covariances be compared on the same data."""
        return (
            self.n * np.log(self.rss / self.n)
            + self.logdet
            + (self.k + self.phi.size) * np.log(self.n)
        )

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
        b = _ls(Xw, yw)
        e = yw - Xw @ b
        return GlsResult(b / scale, phi, float(e @ e), e.size, X.shape[1] + extra_params)
    b = _ls(Xs, y)
    ph = np.empty(0)
    for _ in range(iterations):
        ph = ar_fit(y - Xs @ b, p)
        yw, Xw = ar_whiten(y, ph), ar_whiten(Xs, ph)
        b = _ls(Xw, yw)
    e = ar_whiten(y - Xs @ b, ph)
    return GlsResult(b / scale, ph, float(e @ e), e.size, X.shape[1] + extra_params)


# ------------------------------------------------------- known-covariance GLS


def bin_noise_autocov(
    n: int,
    bin_s: float,
    n_white: float,
    b_floor: float,
    k_rrw: float = 0.0,
    gm_sigma: float = 0.0,
    gm_tau_s: float = 1.0,
) -> np.ndarray:
    """Autocovariance ``R_j`` (lags ``j·Δ``, j = 0..n−1) of Δ-second means of white +
    flicker (+ random-walk) rate noise, from their one-sided PSDs (IEEE 952 Annex C)::

        S(f) = 2N² + B²/(2 ln 2 · f) + K²/(2π² f²) + 4σ_g² T_g / (1 + (2π f T_g)²)

    weighted by the averaging window's ``sinc²(π f Δ)`` and folded into the bins' Nyquist
    band (aliasing) on a grid of ``Δf = 1/(8 n Δ)``, then ``R = irfft``. White noise only
    sets ``R_0 = N²/Δ``. The 1/f and 1/f² laws are cut at ``f = 1/(8 n Δ)``: slower
    wander is a constant over the run, which the fitted bias absorbs anyway.
    """
    m = 8 * n
    df = 1.0 / (m * bin_s)
    k = np.arange(1, 6 * m + 1)  # up to 3/Δ: the sinc² tail beyond is negligible
    f = k * df
    s = b_floor**2 / (2.0 * np.log(2.0) * f) + k_rrw**2 / (2.0 * np.pi**2 * f * f)
    if gm_sigma > 0:  # first-order Gauss–Markov: variance σ_g², correlation time T_g
        s = s + 4.0 * gm_sigma**2 * gm_tau_s / (1.0 + (2.0 * np.pi * f * gm_tau_s) ** 2)
    s *= np.sinc(f * bin_s) ** 2  # np.sinc(x) = sin(πx)/(πx)
    # fold onto 0..m/2 (bins of the length-m periodic grid), then to lags
    idx = k % m
    idx = np.where(idx > m // 2, m - idx, idx)
    folded = np.zeros(m // 2 + 1)
    np.add.at(folded, idx, s * df)
    # one-sided PSD → autocovariance: R_j = Σ S(f) cos(2π f jΔ) df
    spec = folded.copy()
    spec[1:-1] *= 0.5
    r = np.fft.irfft(spec * m, m)[:n]
    r[0] += n_white**2 / bin_s
    return r


class CovWhitener:
    """Whitening by the inverse Cholesky factor of a Toeplitz covariance, via Levinson–Durbin.

    Row ``t`` of ``L⁻¹`` is the order-``t`` one-step predictor of the series,
    ``e_t = (x_t − Σ_{j=1..t} a_{t,j} x_{t−j}) / √v_t``; the recursion gives every order
    in O(p²). Rows ``t < p`` are exact; beyond, the order-``p`` predictor is used (an AR(p)
    approximation whose memory, ``p·Δ``, covers the hour-long correlations of flicker).
    """

    def __init__(self, r: np.ndarray, p: int = 600) -> None:
        n = r.size
        p = int(min(p, n - 1))
        self.n, self.p = n, p
        self.rows: list[np.ndarray] = [np.empty(0)]
        self.v = np.empty(p + 1)
        self.v[0] = r[0]
        a = np.empty(0)
        for k in range(1, p + 1):
            acc = r[k] - (a @ r[k - 1 : 0 : -1] if k > 1 else 0.0)
            kap = acc / self.v[k - 1]
            a = np.concatenate([a - kap * a[::-1], [kap]]) if k > 1 else np.array([kap])
            self.v[k] = self.v[k - 1] * (1.0 - kap * kap)
            self.rows.append(a.copy())
        self.a = a
        # rows t < p of the inverse Cholesky factor as one lower-triangular matrix
        # (prediction coefficients on x_{t-1}, x_{t-2}, …): one product per call
        self._head = np.zeros((p, p))
        for t in range(1, p):
            self._head[t, t - 1 :: -1] = self.rows[t]
        # ln det Σ = Σ_t ln v_t (prediction-error variances; v_p for every t ≥ p)
        self.logdet = float(np.sum(np.log(self.v[:p])) + (n - p) * np.log(self.v[p]))

    def __call__(self, x: np.ndarray) -> np.ndarray:
        from scipy.signal import lfilter

        x2 = x.reshape(x.shape[0], -1)
        out = np.empty_like(x2, dtype=float)
        p = self.p
        h = min(p, x2.shape[0])
        head = x2[:h] - self._head[:h, :h] @ x2[:h]
        out[:h] = head / np.sqrt(self.v[:h])[:, None]
        if x2.shape[0] > p:
            filt = lfilter(np.concatenate([[1.0], -self.a]), [1.0], x2, axis=0)
            out[p:] = filt[p:] / np.sqrt(self.v[p])
        return out.reshape(x.shape)


def gls_cov(y: np.ndarray, X: np.ndarray, w: CovWhitener, extra_params: int = 0) -> GlsResult:
    """GLS with a known noise covariance (up to scale): OLS of ``L⁻¹y`` on ``L⁻¹X``."""
    scale = np.sqrt(np.mean(X * X, axis=0))
    scale[scale == 0] = 1.0
    yw, Xw = w(y), w(X / scale)
    b = _ls(Xw, yw)
    e = yw - Xw @ b
    return GlsResult(
        b / scale, np.empty(0), float(e @ e), e.size, X.shape[1] + extra_params, w.logdet
    )
