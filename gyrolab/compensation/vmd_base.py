"""What every VMD backend shares: the result of one decomposition, the starting centre
frequencies and the stopping floor (:mod:`gyrolab.compensation.vmd` is the interface and
the CPU kernel, :mod:`gyrolab.compensation.vmd_triton` the GPU one; both import this).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["EPS", "VMDResult", "initial_omega"]

EPS = float(np.spacing(1.0))  # the reference code's uDiff floor


@dataclass(frozen=True)
class VMDResult:
    """One decomposition.

    Attributes
    ----------
    modes : ndarray, shape (K, N)
        The modes, same length and units as the input signal; ``modes.sum(0)``
        approximates the signal (exactly only in the limit ``tau > 0``).
    omega : ndarray, shape (K,)
        Centre frequencies in cycles/sample (0 .. 0.5), in mode order.
    n_iter : int
        ADMM iterations run.
    converged : bool
        Whether the tolerance was met before ``max_iter``.
    alpha : float
        Bandwidth constraint used.
    K : int
        Number of modes.
    """

    modes: np.ndarray
    omega: np.ndarray
    n_iter: int
    converged: bool
    alpha: float
    K: int
    spectrum: np.ndarray | None = field(default=None, repr=False)

    @property
    def frequencies(self) -> np.ndarray:
        """Alias of ``omega`` (cycles/sample)."""
        return self.omega


def initial_omega(
    K: int, init: str | np.ndarray = "uniform", n: int | None = None, rng=None
) -> np.ndarray:
    """Initial centre frequencies (cycles/sample).

    ``"uniform"``: 0.5 k / K, k = 0..K-1 (reference ``init=1``); ``"zero"``: all 0
    (``init=0``); ``"random"``: sorted log-uniform in [1/n, 0.5] (``init=2``, needs ``n``);
    or an explicit array of K values.
    """
    if isinstance(init, str):
        if init == "uniform":
            return 0.5 * np.arange(K) / K
        if init == "zero":
            return np.zeros(K)
        if init == "random":
            if n is None:
                raise ValueError("vmd: init='random' needs the signal length")
            rng = np.random.default_rng(rng)
            fs = 1.0 / n
            return np.sort(np.exp(np.log(fs) + (np.log(0.5) - np.log(fs)) * rng.random(K)))
        raise ValueError(f"vmd: unknown init {init!r} (uniform, zero, random or an array)")
    w = np.asarray(init, dtype=np.float64).reshape(-1)
    if w.size != K:
        raise ValueError(f"vmd: init has {w.size} frequencies for K = {K}")
    return w.copy()
