"""Fitness criteria for choosing VMD's (K, alpha), and the GPSO search that uses them.

The paper (section 4.2) searches K in 3..11 and alpha in 50..5000 with GPSO but does not
say which fitness it minimised. Criteria here, all "smaller is better":

``"envelope_entropy"``
    Minimum envelope entropy, the usual choice in PSO-VMD papers: for each mode the
    envelope ``a = |hilbert(u_k)|`` is normalised to ``p = a / sum(a)`` and
    ``E_k = -sum p ln p`` (nats); the fitness is ``min_k E_k``. On a drift-plus-noise gyro
    record every mode is noise-like, ``E_k`` sits within 0.1 % of ``ln N`` everywhere in
    the box, and its minimum is decided by the noise realisation (see docs/vmd-gpso.md).
``"orthogonality"``
    Decomposition quality: index of orthogonality plus energy not captured,
    ``IO = sum_(i != j) |<u_i, u_j>| / ||x||^2`` and ``L = ||x - sum_k u_k||^2 / ||x||^2``
    (both dimensionless), fitness ``IO + L``. Low alpha or many modes overlap (IO up),
    high alpha with few modes leaves gaps in the spectrum (L up).
``"drift_separation"``
    How cleanly the lowest-frequency mode (the one the MPE step will call drift) separates
    from the noise. The drift estimate ``d`` is that mode, the rest is ``r = x - d``:
    ``J = ||diff(d)||^2 / ||diff(x)||^2  +  ||S_W r||^2 / ||S_W x||^2``, where ``diff`` is
    the first difference (it keeps the white noise and discards the slow drift: the first
    term is the share of noise the drift mode absorbed) and ``S_W`` a moving average over
    ``W = N / 100`` samples (it keeps the drift and averages the noise away: the second
    term is the share of slow variation left outside the drift mode). Dimensionless,
    0 for a perfect split, about 1 for a useless one.

References
----------
The paper in ``shared/paper``, sections 3.1-3.2 and 4.2. Envelope entropy: e.g.
X. Zhang et al., Measurement 91 (2016) 347 (PSO-VMD with minimum envelope entropy).
Orthogonality index: N. E. Huang et al., Proc. R. Soc. A 454 (1998) 903, eq. (6.5).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numba
import numpy as np
import scipy.signal

from gyrolab.compensation.gpso import GPSOResult, gpso
from gyrolab.compensation.vmd import BATCH_BYTES, VMDResult, pick_backend, vmd_batch

__all__ = [
    "CRITERIA",
    "DEFAULT_CRITERION",
    "VMDFitness",
    "VMDSearch",
    "drift_separation",
    "envelope_entropy",
    "min_envelope_entropy",
    "orthogonality",
    "search_vmd_parameters",
    "search_vmd_parameters_fleet",
    "synthetic_drift_signal",
]

K_BOUNDS = (3, 11)
ALPHA_BOUNDS = (50.0, 5000.0)


# --------------------------------------------------------------------------- criteria


def envelope_entropy(modes: np.ndarray) -> np.ndarray:
    """Envelope (Shannon) entropy of each mode, nats.

    ``E_k = -sum_t p_k(t) ln p_k(t)`` with ``p_k = a_k / sum_t a_k`` and ``a_k`` the
    Hilbert envelope of mode k. ``ln N`` is the maximum (a flat envelope).
    """
    modes = np.atleast_2d(modes)
    a = np.abs(scipy.signal.hilbert(modes, axis=-1))
    p = a / np.maximum(a.sum(axis=-1, keepdims=True), np.finfo(float).tiny)
    with np.errstate(divide="ignore", invalid="ignore"):
        return -np.sum(np.where(p > 0, p * np.log(p), 0.0), axis=-1)


def min_envelope_entropy(signal: np.ndarray, result: VMDResult) -> float:
    """Minimum envelope entropy over the modes (nats); the PSO-VMD literature's fitness."""
    return float(envelope_entropy(result.modes).min())


def orthogonality(signal: np.ndarray, result: VMDResult) -> float:
    """Index of orthogonality plus unexplained energy (dimensionless), see module notes."""
    x = np.asarray(signal, dtype=np.float64)
    u = result.modes
    ex = float(x @ x)
    if ex == 0.0:
        return 0.0
    gram = u @ u.T
    io = (np.abs(gram).sum() - np.abs(np.diag(gram)).sum()) / ex
    resid = x - u.sum(axis=0)
    return float(io + (resid @ resid) / ex)


def _moving_average(x: np.ndarray, w: int) -> np.ndarray:
    c = np.cumsum(np.concatenate(([0.0], x)))
    return (c[w:] - c[:-w]) / w


def drift_separation(signal: np.ndarray, result: VMDResult, window: int | None = None) -> float:
    """Noise absorbed by the drift mode plus slow variation left outside it (see notes).

    Parameters
    ----------
    signal : ndarray, shape (N,)
    result : VMDResult
    window : int, optional
        Moving-average length W in samples; default ``max(N // 100, 2)``.
    """
    x = np.asarray(signal, dtype=np.float64)
    d = result.modes[int(np.argmin(result.omega))]
    w = max(x.size // 100, 2) if window is None else int(window)
    dx = np.diff(x)
    noise_in = float(np.sum(np.diff(d) ** 2) / max(dx @ dx, np.finfo(float).tiny))
    sx = _moving_average(x - x.mean(), w)
    sr = _moving_average(x - d - (x - d).mean(), w)
    drift_out = float((sr @ sr) / max(sx @ sx, np.finfo(float).tiny))
    return noise_in + drift_out


Criterion = Callable[[np.ndarray, VMDResult], float]
CRITERIA: dict[str, Criterion] = {
    "envelope_entropy": min_envelope_entropy,
    "orthogonality": orthogonality,
    "drift_separation": drift_separation,
}
DEFAULT_CRITERION = "drift_separation"


# --------------------------------------------------------------------------- GPSO glue


@dataclass
class VMDFitness:
    """Batch fitness for :func:`gyrolab.compensation.gpso.gpso` over ``(K, alpha)``.

    ``VMDFitness(signal)(X)`` decomposes ``signal`` with every row ``(K, alpha)`` of X by
    :func:`vmd_batch` and returns the criterion of each. Candidates go a slice at a time
    (``vmd_kwargs["fitness_chunk"]``; default on the CPU as many as keep 256 MB of modes,
    so a generation of 50 on a 11 000-sample record is one call; all at once on a GPU),
    which bounds the memory held; the criterion is "smaller is better".
    Other ``vmd_kwargs`` go to :func:`vmd_batch`.
    """

    signal: np.ndarray
    criterion: str | Criterion = DEFAULT_CRITERION
    vmd_kwargs: dict | None = None

    def __post_init__(self) -> None:
        self.signal = np.asarray(self.signal, dtype=np.float64)
        if isinstance(self.criterion, str):
            if self.criterion not in CRITERIA:
                raise ValueError(
                    f"unknown fitness criterion {self.criterion!r} (one of {', '.join(CRITERIA)})"
                )
            self._fn = CRITERIA[self.criterion]
        else:
            self._fn = self.criterion

    def __call__(self, X: np.ndarray) -> np.ndarray:
        return self.score(X)

    def score(self, X: np.ndarray, units: np.ndarray | None = None) -> np.ndarray:
        """Criterion of each row ``(K, alpha)`` of X; ``units`` picks rows of a 2-D signal."""
        X = np.atleast_2d(X)
        sig = np.atleast_2d(self.signal)
        units = np.zeros(len(X), dtype=np.int64) if units is None else np.asarray(units)
        kw = dict(self.vmd_kwargs or {})
        # score a slice of candidates at a time so only that slice's modes are ever held
        # (50 candidates x 11 modes of a 1e6-sample record would be 4.4 GB)
        backend, _ = pick_backend(kw.get("backend", "auto"), kw.get("device"))
        default = len(X)
        if backend == "numba":  # as many as fit the numba batch's memory bound: one call
            k_max = max(int(np.rint(X[:, 0]).max()), 1) if len(X) else 1
            per_call = BATCH_BYTES // (8 * sig.shape[1] * k_max)
            default = max(2 * numba.get_num_threads(), per_call)
        step = max(int(kw.pop("fitness_chunk", default)), 1)
        out = np.empty(len(X))
        for i in range(0, len(X), step):
            sl = slice(i, i + step)
            Ks = np.rint(X[sl, 0]).astype(int)
            res = vmd_batch(sig, X[sl, 1], Ks, units=units[sl], **kw)
            out[sl] = [self._fn(sig[u], r) for u, r in zip(units[sl], res, strict=True)]
        return out


class _FleetBatcher:
    """Joins the fitness calls of U concurrent GPSO searches into one batch per generation.

    Each search runs in its own thread and calls :meth:`evaluate` once per generation; the
    call blocks until every search still running has asked (or finished), and the last to
    ask scores all of their positions with one :meth:`VMDFitness.score` (one
    :func:`vmd_batch` call over (unit, K, alpha) when it fits the memory bound).
    """

    def __init__(self, fitness: VMDFitness, n_units: int) -> None:
        self.fitness = fitness
        self.cv = threading.Condition()
        self.live = n_units
        self.pending: dict[int, np.ndarray] = {}
        self.done: dict[int, np.ndarray | BaseException] = {}

    def _run(self) -> None:
        units = sorted(self.pending)
        X = np.concatenate([self.pending[u] for u in units])
        idx = np.concatenate([np.full(len(self.pending[u]), u) for u in units])
        try:
            f = self.fitness.score(X, idx)
            for u in units:
                self.done[u] = f[idx == u]
        except BaseException as exc:  # every waiting search re-raises it
            for u in units:
                self.done[u] = exc
        self.pending.clear()
        self.cv.notify_all()

    def evaluate(self, unit: int, X: np.ndarray) -> np.ndarray:
        with self.cv:
            self.pending[unit] = np.atleast_2d(X)
            if len(self.pending) == self.live:
                self._run()
            while unit not in self.done:
                self.cv.wait()
            out = self.done.pop(unit)
        if isinstance(out, BaseException):
            raise out
        return out

    def finish(self) -> None:
        with self.cv:
            self.live -= 1
            if self.pending and len(self.pending) == self.live:
                self._run()


@dataclass(frozen=True)
class VMDSearch:
    """Result of :func:`search_vmd_parameters`: the choice and the swarm's history."""

    K: int
    alpha: float
    fitness: float
    criterion: str
    gpso: GPSOResult


def search_vmd_parameters(
    signal: np.ndarray | Sequence[float],
    *,
    criterion: str | Criterion = DEFAULT_CRITERION,
    K_bounds: tuple[int, int] = K_BOUNDS,
    alpha_bounds: tuple[float, float] = ALPHA_BOUNDS,
    population: int = 50,
    generations: int = 30,
    seed: int | None = 0,
    vmd_kwargs: dict | None = None,
    fitness: Callable[[np.ndarray], np.ndarray] | None = None,
    **gpso_kwargs,
) -> VMDSearch:
    """GPSO search for VMD's ``(K, alpha)`` (paper section 4.2 defaults).

    Parameters
    ----------
    signal : array_like, shape (N,)
        The record to decompose (e.g. gyro rate, deg/s).
    criterion : str or callable, optional
        A name in :data:`CRITERIA` or ``f(signal, VMDResult) -> float``.
    K_bounds, alpha_bounds : tuple, optional
        Search box (paper: K 3..11, alpha 50..5000).
    population, generations, seed : optional
        GPSO settings (paper: population 50).
    vmd_kwargs : dict, optional
        Passed to :func:`vmd_batch` (e.g. ``device="cuda"``; by default the fused Triton
        kernel on a GPU when one is present and Triton is installed, numba otherwise).
    fitness : callable, optional
        Replaces the batch fitness built from ``signal``, ``criterion`` and
        ``vmd_kwargs`` (used by :func:`search_vmd_parameters_fleet`).
    **gpso_kwargs
        Passed to :func:`gpso`.
    """
    fit = fitness or VMDFitness(np.asarray(signal, dtype=np.float64), criterion, vmd_kwargs)
    res = gpso(
        fit,
        [tuple(map(float, K_bounds)), tuple(map(float, alpha_bounds))],
        integer=[True, False],
        population=population,
        generations=generations,
        seed=seed,
        desc="GPSO-VMD",
        **gpso_kwargs,
    )
    name = criterion if isinstance(criterion, str) else getattr(criterion, "__name__", "custom")
    return VMDSearch(
        int(res.best_position[0]), float(res.best_position[1]), res.best_fitness, name, res
    )


def search_vmd_parameters_fleet(
    signals: np.ndarray,
    *,
    criterion: str | Criterion = DEFAULT_CRITERION,
    K_bounds: tuple[int, int] = K_BOUNDS,
    alpha_bounds: tuple[float, float] = ALPHA_BOUNDS,
    population: int = 50,
    generations: int = 30,
    seed: int | None = 0,
    vmd_kwargs: dict | None = None,
    **gpso_kwargs,
) -> list[VMDSearch]:
    """:func:`search_vmd_parameters` for U equal-length records at once (a fleet of units).

    The U searches run in lockstep, and each generation of all of them is scored by one
    batched fitness call: one :func:`vmd_batch` over (unit, K, alpha) (on a GPU the whole
    fleet's generation is one batch of ``U x population`` candidates). Each unit's result
    equals its own :func:`search_vmd_parameters` call with the same arguments (exactly on
    the numba backend, whose candidates do not depend on the batch around them).

    Parameters
    ----------
    signals : array_like, shape (U, N)
        One record per unit.
    criterion, K_bounds, alpha_bounds, population, generations, seed, vmd_kwargs, **gpso_kwargs
        As for :func:`search_vmd_parameters`, shared by all units.

    Returns
    -------
    list of VMDSearch
        One per unit, in row order.
    """
    xs = np.asarray(signals, dtype=np.float64)
    if xs.ndim != 2:
        raise ValueError(f"search_vmd_parameters_fleet: signals must be (U, N), got {xs.shape}")
    batcher = _FleetBatcher(VMDFitness(xs, criterion, vmd_kwargs), xs.shape[0])
    out: list[VMDSearch | BaseException | None] = [None] * xs.shape[0]

    def one(u: int) -> None:
        try:
            out[u] = search_vmd_parameters(
                xs[u], criterion=criterion, K_bounds=K_bounds, alpha_bounds=alpha_bounds,
                population=population, generations=generations, seed=seed,
                fitness=lambda X: batcher.evaluate(u, X), **gpso_kwargs,
            )  # fmt: skip
        except BaseException as exc:
            out[u] = exc
        finally:
            batcher.finish()

    threads = [threading.Thread(target=one, args=(u,)) for u in range(xs.shape[0])]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for r in out:
        if isinstance(r, BaseException):
            raise r
    return out  # type: ignore[return-value]


# --------------------------------------------------------------------------- test signal


def synthetic_drift_signal(
    n: int = 11_000,
    seed: int = 0,
    *,
    drift_pp: float = 0.0287,
    white_sigma: float = 4.6e-4,
    flicker_sigma: float = 1.0e-4,
    return_parts: bool = False,
):
    """A paper-like gyro record: temperature-staircase drift + white + flicker noise (deg/s).

    The oven holds 25 degC for 1/11 of the record, climbs to 60 degC, then steps down by
    10 degC to -40 degC; the case follows with a first-order lag of 1/40 of the record.
    The drift is a quadratic in case temperature scaled to ``drift_pp`` peak to peak (the
    paper's 0.0287 deg/s); ``white_sigma`` is the per-sample white noise (the paper's
    0.0523 deg/sqrt(h) at 1000 samples/h is about 4.6e-4 deg/s) and ``flicker_sigma`` the
    standard deviation of an added 1/f component. Independent of ``gyrolab.sim``, so the
    VMD/GPSO study runs on its own.

    Returns
    -------
    x : ndarray, shape (n,)
        The record; with ``return_parts`` also ``(drift, noise, case_temperature)``.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n) / n
    knots_t = [0.0, 1 / 11, 1.5 / 11, 2 / 11]
    knots_T = [25.0, 25.0, 60.0, 60.0]
    step = (10.0 - 1.0) / 11 / 10  # ten 10-degC steps over the rest, the last held longer
    for i in range(10):
        t0 = 2 / 11 + i * step
        knots_t += [t0 + 0.1 * step, t0 + step]
        knots_T += [50.0 - 10 * i, 50.0 - 10 * i]
    knots_t += [1.0]
    knots_T += [-40.0]
    oven = np.interp(t, knots_t, knots_T)
    # first-order lag of the case behind the oven air (exact discretisation)
    a = np.exp(-1.0 / (n / 40))
    case = scipy.signal.lfilter([1 - a], [1, -a], oven, zi=[a * oven[0]])[0]
    dT = case - 25.0
    drift = 3.0e-4 * dT + 2.0e-6 * dT**2
    drift *= drift_pp / np.ptp(drift)
    white = white_sigma * rng.standard_normal(n)
    # 1/f noise: white noise shaped by 1/sqrt(f) in the frequency domain
    spec = np.fft.rfft(rng.standard_normal(n))
    f = np.fft.rfftfreq(n)
    spec[1:] /= np.sqrt(f[1:] * n)
    spec[0] = 0.0
    flick = np.fft.irfft(spec, n)
    flick *= flicker_sigma / np.std(flick)
    noise = white + flick
    x = drift + noise
    if return_parts:
        return x, drift, noise, case
    return x
