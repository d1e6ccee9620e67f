"""Honest baselines for the temperature-drift model.

* :class:`PolyDriftModel` — drift = Σ_{i=0}^{p} c_i P_i(u) (+ k · dT/dt when asked), a
  Legendre series in the temperature scaled to u ∈ [−1, 1] over the calibration range
  (numerically the same as a power series, but well conditioned at order 6–8). The order
  ``p`` is the one with the lowest held-out error under *blocked* k-fold cross-validation
  in time (:func:`blocked_folds`): the run is cut into contiguous blocks, every k-th block
  forms a fold, so held-out samples are never the immediate neighbours of training ones
  (neighbouring samples share slow noise and would reward over-fitting).
* plain BP — the eq. 15–17 network of :mod:`gyrolab.compensation.gabp`, same training,
  random (Xavier) initial weights instead of the GA: :func:`fit_plain_bp`.

Both take the same feature matrix as GA-BP: column 0 temperature (°C), optionally column 1
dT/dt (°C/s); the target is in °/s.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.polynomial import legendre

from gyrolab.compensation.gabp import BPConfig, MLPDriftModel, fit_mlp


def blocked_folds(n: int, k: int = 5, n_blocks: int = 20) -> list[np.ndarray]:
    """Boolean held-out masks for blocked k-fold CV in time: ``n_blocks`` contiguous blocks,
    block ``b`` belongs to fold ``b mod k``."""
    if n < n_blocks:
        n_blocks = max(k, n)
    block = np.minimum((np.arange(n) * n_blocks) // n, n_blocks - 1)
    return [(block % k) == f for f in range(k)]


@dataclass
class PolyDriftModel:
    """Legendre-series drift model in temperature, optional linear dT/dt term."""

    coef: np.ndarray
    t_lo: float
    t_hi: float
    rate_coef: float | None = None
    order: int = 0
    cv_rmse: dict[int, float] = field(default_factory=dict)

    def _u(self, temp: np.ndarray) -> np.ndarray:
        return (2.0 * temp - (self.t_lo + self.t_hi)) / (self.t_hi - self.t_lo)

    def predict(self, X: np.ndarray) -> np.ndarray:
        X = np.asarray(X, dtype=float)
        X = X[:, None] if X.ndim == 1 else X
        y = legendre.legval(self._u(X[:, 0]), self.coef)
        if self.rate_coef is not None:
            y = y + self.rate_coef * X[:, 1]
        return y

    def spec(self, inputs: list[str], window_s: float | None) -> dict[str, Any]:
        """The exported form (``legendre``, :mod:`gyrolab.compensation.regressors`);
        ``window_s``: the dT/dt window of the rate term (``inputs``: T, dT/dt)."""
        return {
            "kind": "legendre",
            "coef": np.asarray(self.coef, dtype=float).tolist(),
            "t_lo": float(self.t_lo),
            "t_hi": float(self.t_hi),
            "rate_coef": self.rate_coef,
            "dtdt_window_s": window_s if self.rate_coef is not None else None,
        }

    def to_state(self, prefix: str) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        meta = {
            "kind": "poly",
            "order": self.order,
            "t_lo": self.t_lo,
            "t_hi": self.t_hi,
            "rate_coef": self.rate_coef,
            "cv_rmse": {str(k): v for k, v in self.cv_rmse.items()},
        }
        return meta, {f"{prefix}coef": self.coef}

    @classmethod
    def from_state(
        cls, meta: dict[str, Any], arrays: dict[str, np.ndarray], prefix: str
    ) -> PolyDriftModel:
        return cls(
            coef=np.asarray(arrays[f"{prefix}coef"], dtype=float),
            t_lo=float(meta["t_lo"]),
            t_hi=float(meta["t_hi"]),
            rate_coef=None if meta.get("rate_coef") is None else float(meta["rate_coef"]),
            order=int(meta["order"]),
            cv_rmse={int(k): float(v) for k, v in meta.get("cv_rmse", {}).items()},
        )


def _design(u: np.ndarray, order: int, rate: np.ndarray | None) -> np.ndarray:
    A = legendre.legvander(u, order)
    return A if rate is None else np.column_stack([A, rate])


def _lstsq(A: np.ndarray, y: np.ndarray) -> np.ndarray:
    # column scaling keeps the dT/dt column (~1e-3 °C/s) comparable to the Legendre ones
    s = np.sqrt(np.mean(A * A, axis=0))
    s = np.where(s > 0, s, 1.0)
    c, *_ = np.linalg.lstsq(A / s, y, rcond=None)
    return c / s


def fit_poly(
    X: np.ndarray,
    y: np.ndarray,
    *,
    orders: range | list[int] = range(1, 9),
    k: int = 5,
    n_blocks: int = 20,
) -> PolyDriftModel:
    """Fit the polynomial baseline, choosing the order by blocked k-fold CV (RMSE)."""
    X = np.asarray(X, dtype=float)
    X = X[:, None] if X.ndim == 1 else X
    y = np.asarray(y, dtype=float).ravel()
    temp = X[:, 0]
    rate = X[:, 1] if X.shape[1] > 1 else None
    t_lo, t_hi = float(temp.min()), float(temp.max())
    if not t_hi > t_lo:
        raise ValueError("temperature does not vary: a temperature model cannot be fitted")
    u = (2.0 * temp - (t_lo + t_hi)) / (t_hi - t_lo)
    folds = blocked_folds(len(y), k, n_blocks)
    cv: dict[int, float] = {}
    for p in orders:
        sq, cnt = 0.0, 0
        for held in folds:
            tr = ~held
            if tr.sum() <= p + 2 or held.sum() == 0:
                continue
            c = _lstsq(_design(u[tr], p, None if rate is None else rate[tr]), y[tr])
            r = _design(u[held], p, None if rate is None else rate[held]) @ c - y[held]
            sq += float(r @ r)
            cnt += int(held.sum())
        if cnt:
            cv[int(p)] = float(np.sqrt(sq / cnt))
    best = min(cv, key=lambda p: cv[p])
    c = _lstsq(_design(u, best, rate), y)
    return PolyDriftModel(
        coef=c[: best + 1],
        t_lo=t_lo,
        t_hi=t_hi,
        rate_coef=None if rate is None else float(c[-1]),
        order=best,
        cv_rmse=cv,
    )


def fit_plain_bp(
    X: np.ndarray, y: np.ndarray, *, bp: BPConfig | None = None, seed: int = 0
) -> MLPDriftModel:
    """Plain BP: the GA-BP network and training with random initial weights, no GA."""
    return fit_mlp(X, y, init="random", bp=bp or BPConfig(), seed=seed)
