"""Forward linear prediction (FLP) filter for the "mixed" modes (paper §3.5, step 2).

The filter output is the one-step forward prediction of the mode from its own past::

    y[n] = mu + sum_{k=1}^{p} c_k (x[n-k] - mu)

with ``c_k = -a_k`` the coefficients of the order-``p`` autoregressive model
``x[n] - mu = -sum_k a_k (x[n-k] - mu) + e[n]``. For a mode ``x = s + w`` made of a
predictable component ``s`` and white noise ``w``, ``y[n]`` is the linear least-squares
estimate of ``s[n]`` from past observations only (``w[n]`` is independent of the past), so
the output keeps the predictable part and drops the innovation: its variance is the input
variance minus the prediction-error variance. The filter is an FIR in the *past* samples,
hence causal: ``y[n]`` never depends on ``x[m]`` for ``m >= n``, it runs sample by sample or
block by block on a live stream with the last ``p`` inputs as its state, and it costs a
one-sample look-back delay plus the smoothing of its FIR response (see
:meth:`ForwardLinearPredictor.bandwidth_hz`).

Fitting: Burg's method (maximum-entropy lattice; always gives a stable, minimum-phase model)
on calibration data, order chosen by minimising an information criterion over
``1..max_order`` with the Burg prediction-error power ``E_p`` on ``N`` samples::

    AIC(p) = N ln E_p + 2 p          (Akaike 1974)
    MDL(p) = N ln E_p + p ln N       (Rissanen 1978; more parsimonious on long records)

Yule-Walker (autocorrelation method, Levinson-Durbin) is available as ``method="yule-walker"``.
References: S. M. Kay, *Modern Spectral Estimation* (1988) ch. 7; P. Stoica & R. Moses,
*Spectral Analysis of Signals* (2005) §3.9.
"""

from __future__ import annotations

import math
from typing import Any, Literal

import numpy as np

from gyrolab.errors import InputError

__all__ = ["ForwardLinearPredictor", "burg", "flp_filter", "yule_walker"]


def burg(x: np.ndarray, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Burg AR estimates of every order up to ``order`` for zero-mean ``x``.

    Returns ``(a_all, err)``: ``a_all[p]`` is the prediction-error filter
    ``[1, a_1, ..., a_p]`` padded with zeros to ``order + 1``, ``err[p]`` its error power.
    """
    x = np.asarray(x, dtype=float)
    f = x[1:].copy()  # forward errors
    b = x[:-1].copy()  # backward errors
    a = np.zeros(order + 1)
    a[0] = 1.0
    a_all = np.zeros((order + 1, order + 1))
    a_all[0, 0] = 1.0
    err = np.empty(order + 1)
    err[0] = float(np.dot(x, x)) / x.size
    for k in range(1, order + 1):
        den = float(np.dot(f, f) + np.dot(b, b))
        refl = -2.0 * float(np.dot(f, b)) / den if den > 0 else 0.0
        a[: k + 1] = a[: k + 1] + refl * a[k::-1]
        err[k] = err[k - 1] * (1.0 - refl * refl)
        a_all[k] = a
        f, b = (f + refl * b)[1:], (b + refl * f)[:-1]
    return a_all, err


def yule_walker(x: np.ndarray, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Yule-Walker (biased autocorrelation + Levinson-Durbin) estimates up to ``order``.

    Same return convention as :func:`burg`.
    """
    x = np.asarray(x, dtype=float)
    n = x.size
    r = np.array([np.dot(x[: n - k], x[k:]) / n for k in range(order + 1)])
    a = np.zeros(order + 1)
    a[0] = 1.0
    a_all = np.zeros((order + 1, order + 1))
    a_all[0, 0] = 1.0
    err = np.empty(order + 1)
    err[0] = r[0]
    for k in range(1, order + 1):
        acc = float(np.dot(a[:k], r[k:0:-1]))
        refl = -acc / err[k - 1] if err[k - 1] > 0 else 0.0
        a[: k + 1] = a[: k + 1] + refl * a[k::-1]
        err[k] = err[k - 1] * (1.0 - refl * refl)
        a_all[k] = a
    return a_all, err


def flp_filter(
    x: np.ndarray, coef: np.ndarray, mean: float = 0.0, zi: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Apply the causal predictor ``y[n] = mean + sum_k coef[k-1] (x[n-k] - mean)``.

    ``zi``: the previous ``p`` inputs, oldest first (``None``: all equal to ``mean``, i.e. a
    stream that starts at its mean). Returns ``(y, zf)`` with ``zf`` the last ``p`` inputs,
    to pass as ``zi`` for the next block (scipy.signal.lfilter style).
    """
    c = np.asarray(coef, dtype=float)
    p = c.size
    xin = np.asarray(x, dtype=float)
    if zi is None:
        zi = np.full(p, mean)
    zi = np.asarray(zi, dtype=float)
    if zi.size != p:
        raise InputError(None, f"FLP state has {zi.size} samples, the filter needs {p}")
    ext = np.concatenate([zi, xin]) - mean
    n = xin.size
    if p == 0:
        return np.full(n, mean), zi.copy()
    kernel = np.concatenate([[0.0], c])  # y[n] uses x[n-1] ... x[n-p] only
    y = mean + np.convolve(ext, kernel)[p : p + n]
    zf = (ext[-p:] + mean).copy()
    return y, zf


class ForwardLinearPredictor:
    """Causal FLP filter: fit on calibration data, then filter any data or a live stream.

    >>> flp = ForwardLinearPredictor(max_order=20).fit(calibration_mode)
    >>> y = flp.filter(block)           # uses and advances ``flp.state``
    >>> flp.reset(); y_all = flp.filter(whole_series)   # same numbers as block by block
    """

    def __init__(
        self,
        order: int | None = None,
        max_order: int = 32,
        criterion: Literal["aic", "mdl"] = "aic",
        method: Literal["burg", "yule-walker"] = "burg",
    ) -> None:
        if order is not None and order < 1:
            raise InputError(None, f"FLP order must be >= 1, got {order}")
        if max_order < 1:
            raise InputError(None, f"FLP max_order must be >= 1, got {max_order}")
        if criterion not in ("aic", "mdl"):
            raise InputError(None, f"unknown FLP order criterion {criterion!r} (aic or mdl)")
        if method not in ("burg", "yule-walker"):
            raise InputError(None, f"unknown FLP method {method!r} (burg or yule-walker)")
        self.order_request = order
        self.max_order = max_order
        self.criterion = criterion
        self.method = method
        self.coef: np.ndarray = np.zeros(0)  #: c_1..c_p, y[n] = mu + sum c_k (x[n-k] - mu)
        self.mean: float = 0.0  #: mu, the calibration mean
        self.error_variance: float = float("nan")  #: prediction-error power E_p
        self.criterion_values: np.ndarray = np.zeros(0)  #: IC(p) for p = 1..max_order
        self.state: np.ndarray = np.zeros(0)  #: last p inputs, oldest first

    @property
    def order(self) -> int:
        return int(self.coef.size)

    def fit(self, x: np.ndarray) -> ForwardLinearPredictor:
        """Fit the AR model on calibration data ``x`` and reset the stream state."""
        a = np.asarray(x, dtype=float)
        if a.ndim != 1:
            raise InputError(None, f"FLP needs a 1-D series, got shape {a.shape}")
        if not np.all(np.isfinite(a)):
            raise InputError(None, "FLP calibration series contains NaN or infinite values")
        pmax = self.order_request if self.order_request is not None else self.max_order
        if a.size < 2 * pmax + 2:
            raise InputError(
                None, f"FLP calibration series of {a.size} samples too short for order {pmax}"
            )
        mu = float(a.mean())
        z = a - mu
        if not np.any(z):
            raise InputError(None, "FLP calibration series is constant")
        fit = burg if self.method == "burg" else yule_walker
        a_all, err = fit(z, pmax)
        n = z.size
        errp = np.maximum(err[1:], np.finfo(float).tiny)
        ks = np.arange(1, pmax + 1)
        penalty = 2.0 * ks if self.criterion == "aic" else ks * math.log(n)
        self.criterion_values = n * np.log(errp) + penalty
        p = pmax if self.order_request is not None else int(ks[np.argmin(self.criterion_values)])
        self.coef = -a_all[p, 1 : p + 1].copy()
        self.mean = mu
        self.error_variance = float(err[p])
        self.reset()
        return self

    def reset(self, state: np.ndarray | None = None) -> None:
        """Restart the stream: previous inputs = ``state`` (oldest first) or the mean."""
        self.state = np.full(self.order, self.mean) if state is None else np.array(state, float)

    def filter(self, x: np.ndarray) -> np.ndarray:
        """Causal prediction for the block ``x``; continues from and updates ``state``."""
        if self.order == 0:
            raise InputError(None, "FLP filter used before fit")
        y, self.state = flp_filter(x, self.coef, self.mean, self.state)
        return y

    def step(self, sample: float) -> float:
        """One live sample in, one output out (the prediction made before ``sample``)."""
        y = self.mean + float(np.dot(self.coef, self.state[::-1] - self.mean))
        self.state = np.concatenate([self.state[1:], [float(sample)]])
        return y

    def frequency_response(self, rate_hz: float, n: int = 8192) -> tuple[np.ndarray, np.ndarray]:
        """(f in Hz, complex H(f)) for 0..rate_hz/2 of the FIR ``sum c_k z^-k`` (``rate_hz``:
        the series' sample rate)."""
        f = np.linspace(0.0, rate_hz / 2.0, n)
        k = np.arange(1, self.order + 1)
        h = np.exp(-2j * np.pi * np.outer(f / rate_hz, k)) @ self.coef
        return f, h

    def passband_hz(self, rate_hz: float, n: int = 8192) -> tuple[float, float]:
        """Edges of the -3 dB band around the peak of |H| (low edge 0 for a low-pass)."""
        f, h = self.frequency_response(rate_hz, n)
        g = np.abs(h)
        ipk = int(np.argmax(g))
        above = g >= g[ipk] / math.sqrt(2.0)
        lo = ipk
        while lo > 0 and above[lo - 1]:
            lo -= 1
        hi = ipk
        while hi < g.size - 1 and above[hi + 1]:
            hi += 1
        return float(f[lo]), float(f[hi])

    def bandwidth_hz(self, rate_hz: float, n: int = 8192) -> float:
        """Upper -3 dB frequency (Hz) of the filter's passband, relative to its peak gain:
        content above it is attenuated by more than 3 dB, i.e. what the filtering costs."""
        return self.passband_hz(rate_hz, n)[1]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready parameters (for a saved model directory)."""
        return {
            "coef": [float(c) for c in self.coef],
            "mean": self.mean,
            "error_variance": self.error_variance,
            "criterion": self.criterion,
            "method": self.method,
            "max_order": self.max_order,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ForwardLinearPredictor:
        obj = cls(
            max_order=int(d.get("max_order", 32)),
            criterion=d.get("criterion", "aic"),
            method=d.get("method", "burg"),
        )
        obj.coef = np.asarray(d["coef"], dtype=float)
        obj.mean = float(d["mean"])
        obj.error_variance = float(d.get("error_variance", float("nan")))
        obj.reset()
        return obj
