"""Variational mode decomposition (VMD), fused and batched.

VMD (Dragomiretskiy & Zosso 2014; paper eqs. 1-8) splits a signal ``f`` into ``K`` modes
``u_k``, each compact around a centre frequency ``omega_k``, by ADMM on the augmented
Lagrangian (paper eq. 4). In the Fourier domain one iteration is, for k = 1..K,

    u_k^(n+1)(w) = (f(w) - sum_{i != k} u_i(w) - lambda(w) / 2) / (1 + alpha (w - omega_k)^2)
    omega_k^(n+1) = sum_{w >= 0} w |u_k(w)|^2 / sum_{w >= 0} |u_k(w)|^2
    lambda^(n+1) = lambda^n + tau (sum_k u_k^(n+1) - f)

(paper eqs. 5-7, with Zosso's reference-code conventions: ``alpha`` rather than
``2 alpha`` in the Wiener filter and ``-lambda / 2``; ``tau = 0`` gives the usual
noise-slack variant). Iteration stops when

    eps + (1/T) sum_k sum_w |u_k^(n+1)(w) - u_k^n(w)|^2 <= tol

(the reference code's absolute form of paper eq. 8; ``T`` is the mirrored length).

What this implementation does differently from the reference code (and from ``vmdpy``):

* only the non-negative half spectrum is stored (the negative half is identically zero
  for the analytic modes), and no iteration history is kept: memory is O(K N), not
  O(500 K N);
* that half spectrum is a fixed phase times a real array (the DCT-II of the signal, see
  the kernel notes), so the iteration runs in real arithmetic and the modes come back by
  inverse DCTs of length N;
* the ADMM update is one fused, tiled, vectorised pass over memory per iteration (a
  numba kernel): about 3.6 us per mode per iteration on 11 000 samples;
* odd lengths are decomposed in full (the reference code silently drops the last
  sample): the signal is mirrored to ``T = 2 N`` samples in every case;
* many ``(unit, K, alpha)`` candidates are decomposed in one call (:func:`vmd_batch`): in
  parallel over CPU threads (numba, a dynamic queue over candidates), as one fused kernel
  launch per ADMM iteration on a GPU (Triton, :mod:`gyrolab.compensation.vmd_triton`), or
  as one batched tensor program (torch, CPU or CUDA).

The returned modes are those of the last iterate (the reference code returns the
penultimate one).

References
----------
K. Dragomiretskiy and D. Zosso, "Variational Mode Decomposition", IEEE Trans. Signal
Process. 62(3), 531-544, 2014. doi:10.1109/TSP.2013.2288675.
The paper in ``shared/paper``: section 3.1, eqs. (1)-(8).
"""

from __future__ import annotations

from collections.abc import Sequence

import numba
import numpy as np
import scipy.fft
from numba import njit, prange, types
from numba.core import cgutils
from numba.core.extending import intrinsic

from gyrolab.compensation.vmd_base import EPS, VMDResult, initial_omega

__all__ = ["VMDResult", "vmd", "vmd_batch", "initial_omega"]


# --------------------------------------------------------------------------- kernels
#
# Why everything below is real: the mirrored signal is even about a half-sample point,
# so its spectrum is f(w_m) = exp(i phi_m) D_m with D the (real) DCT-II of the signal and
# a fixed phase phi_m. Every ADMM step multiplies by real filters and adds, so each mode
# spectrum is u_k(w_m) = exp(i phi_m) A_km with A real: |u_k|^2 = A_k^2, and the whole
# iteration runs on real arrays (half the memory traffic of complex ones). The modes come
# back by one inverse DCT each, of length N rather than 2 N.

_BLOCK = 512  # bins per tile: the tile of f, S, lambda stays in L1 across the K modes


@njit(cache=True, fastmath=True, nogil=True, error_model="numpy", inline="always")
def _mode_pass(fd, fr, uk, S, lam, use_lam, alpha, w):  # pragma: no cover
    """One mode's Wiener update (paper eq. 5) over a tile; returns the sums for eq. 6/8.

    The arguments are tile slices indexed from 0: only then can LLVM prove the indices
    non-negative and vectorize the loop (with offsets it stays scalar, 3x slower).
    ``use_lam`` is loop-invariant: LLVM unswitches the loop into two vectorised copies.
    """
    nk = 0.0
    dk = 0.0
    diff = 0.0
    for j in range(uk.shape[0]):
        fj = fr[j]
        d = fj - w
        old = uk[j]
        oth = S[j] - old
        g = fd[j] - oth
        if use_lam:
            g -= 0.5 * lam[j]
        new = g / (1.0 + alpha * d * d)
        uk[j] = new
        S[j] = oth + new
        p = new * new
        nk += fj * p
        dk += p
        e = new - old
        diff += e * e
    return nk, dk, diff


@njit(cache=True, fastmath=True, nogil=True, error_model="numpy")
def _admm_one(fd, alpha, K, omega, tau, tol, max_iter, dc, u):  # pragma: no cover
    """ADMM iterations for one candidate, in place on ``u`` (K, M) and ``omega`` (K,).

    ``fd`` is the real spectrum D_m, m = 0..M-1, at w_m = m / (2 M) cycles/sample.
    Mode k's update within an iteration uses omega_k from the previous iteration only, so
    the loop is tiled over bins with the modes inside: one pass over ``u`` per iteration.
    Returns the number of iterations and whether the tolerance was met.
    """
    M = fd.shape[0]
    inv_T = 1.0 / (2.0 * M)
    fr = np.arange(M) * inv_T
    S = np.zeros(M)  # running sum of all modes: "sum of the others" is S - u_k
    for k in range(K):
        for j in range(M):
            S[j] += u[k, j]
    use_lam = tau != 0.0
    lam = np.zeros(M)
    num = np.zeros(K)
    den = np.zeros(K)
    n = 0
    udiff = tol + 2.220446049250313e-16
    while udiff > tol and n < max_iter:
        num[:] = 0.0
        den[:] = 0.0
        diff = 0.0
        for j0 in range(0, M, _BLOCK):
            j1 = min(j0 + _BLOCK, M)
            fdb = fd[j0:j1]
            frb = fr[j0:j1]
            Sb = S[j0:j1]
            lb = lam[j0:j1]
            for k in range(K):
                nk, dk, ek = _mode_pass(fdb, frb, u[k, j0:j1], Sb, lb, use_lam, alpha, omega[k])
                num[k] += nk
                den[k] += dk
                diff += ek
            if use_lam:
                for j in range(j1 - j0):
                    lb[j] += tau * (Sb[j] - fdb[j])
        for k in range(K):
            if not (dc and k == 0) and den[k] > 0.0:
                omega[k] = num[k] / den[k]
        n += 1
        udiff = 2.220446049250313e-16 + diff * inv_T
    return n, udiff <= tol


@intrinsic
def _fetch_add(typingctx, counter, value):  # pragma: no cover
    """Atomically add ``value`` to ``counter[0]`` (int64 array) and return the old value."""
    sig = types.int64(counter, types.int64)

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        ptr = cgutils.get_item_pointer(
            context, builder, signature.args[0], ary, [context.get_constant(types.intp, 0)]
        )
        return builder.atomic_rmw("add", ptr, args[1], "seq_cst")

    return sig, codegen


@njit(cache=True, parallel=True, fastmath=True, nogil=True, error_model="numpy")
def _admm_batch(
    fds, units, alphas, Ks, offs, order, omega, tau, tol, max_iter, dc, u, n_iter, conv, nxt, nthr
):  # pragma: no cover  # fmt: skip
    """Independent candidates in parallel over one flat mode array.

    Candidate b owns rows ``offs[b] .. offs[b] + Ks[b]`` of ``u`` (R, M) and of ``omega``
    (R,) and decomposes ``fds[units[b]]``. One worker per thread pulls the next candidate
    of ``order`` (most expensive first) from the shared counter ``nxt`` when it is free: a
    dynamic schedule, so the threads finish together although candidates differ in K and
    in iterations (numba's own ``prange`` hands out fixed blocks of the range; with
    candidates sorted by cost, one thread would get all the heavy ones). ``nthr`` is
    the number of threads (passed in: reading it inside would defeat the disk cache).
    """
    for _ in prange(nthr):
        while True:
            i = _fetch_add(nxt, 1)
            if i >= order.shape[0]:
                break
            b = order[i]
            k0 = offs[b]
            k1 = k0 + Ks[b]
            n, c = _admm_one(
                fds[units[b]], alphas[b], Ks[b], omega[k0:k1], tau, tol, max_iter, dc, u[k0:k1]
            )
            n_iter[b] = n
            conv[b] = c


# --------------------------------------------------------------------------- helpers


def _as_signal(signal: np.ndarray | Sequence[float]) -> np.ndarray:
    x = np.asarray(signal, dtype=np.float64)
    if x.ndim != 1:
        raise ValueError(f"vmd: signal must be one-dimensional, got shape {x.shape}")
    if x.size < 4:
        raise ValueError(f"vmd: signal needs at least 4 samples, got {x.size}")
    if not np.all(np.isfinite(x)):
        raise ValueError("vmd: signal contains NaN or infinite values")
    return x


def _real_spectrum(x: np.ndarray) -> np.ndarray:
    """Real spectrum D of the mirror-extended signal (T = 2 N samples).

    The reference code mirrors ``N // 2`` samples at each end; here the front mirror
    holds ``N // 2`` and the back ``N - N // 2``, so odd lengths are kept whole (for even
    N the two are identical). Its DFT at w_m = m / T, m = 0..N-1, is ``exp(i phi_m) D_m``
    with ``D = DCT-II(x)`` and ``phi_m = pi m (1/2 - N // 2) / N``.
    """
    return scipy.fft.dct(x, type=2)


def _phase(n: int) -> np.ndarray:
    """phi_m of :func:`_real_spectrum` (radians), m = 0..n-1."""
    return np.pi * np.arange(n) * (0.5 - n // 2) / n


def _modes_from_real(u: np.ndarray, n: int, workers: int | None = None) -> np.ndarray:
    """Time-domain modes (K, n) from real spectra (K, n), mirror already cropped.

    The inverse DCT-II is exactly the reference code's ``real(ifft(...))`` of the
    Hermitian-completed half spectrum, cropped to the original span, except for one term
    it adds: it fills the Nyquist bin with the conjugate of the highest stored bin, which
    puts ``A_(N-1) cos(phi_(N-1)) (-1)^t / T`` into every mode; kept, for fidelity.
    """
    modes = scipy.fft.idct(u, type=2, axis=-1, workers=workers)
    h = n // 2
    sign = np.where((np.arange(n) + h) % 2 == 0, 1.0, -1.0)
    c = np.cos(np.pi * (n - 1) * (0.5 - h) / n) / (2.0 * n)
    modes += (c * u[:, n - 1])[:, None] * sign[None, :]
    return modes


def _check_params(alpha: float, K: int, tau: float, tol: float, max_iter: int) -> None:
    if not (np.isfinite(alpha) and alpha > 0):
        raise ValueError(f"vmd: alpha must be positive and finite, got {alpha}")
    if int(K) != K or K < 1:
        raise ValueError(f"vmd: K must be a positive integer, got {K}")
    if not (np.isfinite(tau) and tau >= 0):
        raise ValueError(f"vmd: tau must be >= 0, got {tau}")
    if not (tol >= 0):
        raise ValueError(f"vmd: tol must be >= 0, got {tol}")
    if int(max_iter) != max_iter or max_iter < 1:
        raise ValueError(f"vmd: max_iter must be a positive integer, got {max_iter}")


# --------------------------------------------------------------------------- public API


def vmd(
    signal: np.ndarray | Sequence[float],
    alpha: float,
    K: int,
    *,
    tau: float = 0.0,
    tol: float = 1e-7,
    max_iter: int = 500,
    init: str | np.ndarray = "uniform",
    dc: bool = False,
    rng=None,
    return_spectrum: bool = False,
) -> VMDResult:
    """Variational mode decomposition of a real 1-D signal.

    Parameters
    ----------
    signal : array_like, shape (N,)
        Real samples (any units; modes come back in the same units). Any N >= 4.
    alpha : float
        Bandwidth constraint (dimensionless; the reference code's ``alpha``: the mode's
        Wiener filter is ``1 / (1 + alpha (w - omega_k)^2)`` with w in cycles/sample;
        paper eq. 5 writes ``2 alpha``).
    K : int
        Number of modes.
    tau : float, optional
        Dual-ascent step (paper eq. 7); 0 (default) means no exact-reconstruction
        constraint (noise slack).
    tol : float, optional
        Convergence tolerance on ``(1/T) sum_k ||u_k^(n+1) - u_k^n||^2`` in the Fourier
        domain (the reference code's form of paper eq. 8; absolute, so it scales with the
        signal's energy: ``(1/T) ||u||_F^2`` is half the mode's time-domain sum of squares).
    max_iter : int, optional
        Most ADMM iterations to run.
    init : {"uniform", "zero", "random"} or array_like, optional
        Initial centre frequencies (see :func:`initial_omega`).
    dc : bool, optional
        Hold the first mode at 0 frequency (reference ``DC=1``).
    rng : seed or Generator, optional
        Only for ``init="random"``.
    return_spectrum : bool, optional
        Also return the mode spectra (K, N), complex, at w = m / (2 N) of the mirrored
        signal.

    Returns
    -------
    VMDResult
        ``modes`` (K, N), ``omega`` (K,) in cycles/sample, ``n_iter``, ``converged``.

    Notes
    -----
    Memory is about ``(K + 6) N`` float64 values (``2 K N`` more with
    ``return_spectrum``); work is ``n_iter K N`` fused updates plus K inverse DCTs.
    """
    x = _as_signal(signal)
    _check_params(alpha, K, tau, tol, max_iter)
    K = int(K)
    n = x.size
    fd = _real_spectrum(x)
    u = np.zeros((K, n))
    omega = initial_omega(K, init, n, rng)
    if dc:
        omega[0] = 0.0
    n_iter, conv = _admm_one(
        fd, float(alpha), K, omega, float(tau), float(tol), int(max_iter), bool(dc), u
    )
    spec = u * np.exp(1j * _phase(n)) if return_spectrum else None
    modes = _modes_from_real(u, n)
    return VMDResult(modes, omega, int(n_iter), bool(conv), float(alpha), K, spec)


def vmd_batch(
    signal: np.ndarray | Sequence[float],
    alphas: Sequence[float] | np.ndarray,
    Ks: Sequence[int] | np.ndarray,
    *,
    units: Sequence[int] | np.ndarray | None = None,
    tau: float = 0.0,
    tol: float = 1e-7,
    max_iter: int = 500,
    init: str = "uniform",
    dc: bool = False,
    backend: str = "auto",
    device: str | None = None,
    chunk: int | None = None,
) -> list[VMDResult]:
    """Decompose one signal, or a fleet of equal-length signals, with many candidates at once.

    Each candidate gives what :func:`vmd` gives with the same arguments on its own signal
    (numba: bit for bit; torch and triton: to rounding, the sums run in another order).

    Parameters
    ----------
    signal : array_like, shape (N,) or (U, N)
        One record, or U records of equal length (e.g. one per unit of a fleet); as for
        :func:`vmd` otherwise.
    alphas, Ks : array_like, shape (B,)
        One ``alpha`` and one ``K`` per candidate.
    units : array_like of int, shape (B,), optional
        Which row of a 2-D ``signal`` each candidate decomposes (default: all row 0,
        which must then be the only row). A fleet's GPSO generation is one call:
        ``units = repeat(arange(U), P)`` with the U swarms' positions stacked.
    tau, tol, max_iter, dc
        As for :func:`vmd`, shared by all candidates.
    init : {"uniform", "zero"}, optional
        As for :func:`vmd`.
    backend : {"auto", "numba", "triton", "torch"}, optional
        ``"numba"``: fused CPU kernel, candidates spread over threads. ``"triton"``: the
        fused GPU kernel of :mod:`gyrolab.compensation.vmd_triton` (one launch per ADMM
        iteration for the whole batch); on ``device="cpu"`` it runs in Triton's
        interpreter (slow: for tests). ``"torch"``: one batched tensor program (unfused).
        ``"auto"``: on CUDA (``device`` "cuda", or None and a GPU present) triton when it
        is installed, else torch; numba otherwise.
    device : str, optional
        Torch device for the triton and torch backends.
    chunk : int, optional
        Candidates decomposed together (bounds memory: about ``8 N sum(K)`` bytes for
        their modes); default: as many as fit in 256 MB of modes on numba (at least two
        per thread), all on triton and torch.

    Returns
    -------
    list of VMDResult
        In candidate order. On numba the modes of one chunk are views of one buffer.
    """
    xs, units_arr = _as_signals(signal, units, np.size(alphas))
    alphas = np.atleast_1d(np.asarray(alphas, dtype=np.float64))
    Ks_arr = np.atleast_1d(np.asarray(Ks))
    if alphas.shape != Ks_arr.shape or alphas.ndim != 1:
        raise ValueError("vmd_batch: alphas and Ks must be 1-D and of equal length")
    for a, k in zip(alphas, Ks_arr, strict=True):
        _check_params(float(a), k, tau, tol, max_iter)
    Ks_arr = Ks_arr.astype(np.int64)
    if init not in ("uniform", "zero"):
        raise ValueError("vmd_batch: init must be 'uniform' or 'zero'")
    backend, device = pick_backend(backend, device)
    args = (xs, units_arr, alphas, Ks_arr, tau, tol, max_iter, init, dc)
    if backend == "triton":
        # the optional GPU extra (Triton): imported only when asked for
        from gyrolab.compensation.vmd_triton import vmd_batch_triton

        return vmd_batch_triton(*args, device=device, chunk=chunk)
    if backend == "torch":
        return _vmd_batch_torch(*args, device, chunk)
    return _vmd_batch_numba(*args, chunk)


def _as_signals(signal, units, B: int) -> tuple[np.ndarray, np.ndarray]:
    """(U, N) float64 records and the (B,) row index of each candidate."""
    arr = np.asarray(signal, dtype=np.float64)
    if arr.ndim == 2:
        xs = np.stack([_as_signal(row) for row in arr])
    else:
        xs = _as_signal(arr)[None, :]
    if units is None:
        if xs.shape[0] != 1:
            raise ValueError("vmd_batch: a 2-D signal needs `units` (a row index per candidate)")
        return xs, np.zeros(B, dtype=np.int64)
    u = np.atleast_1d(np.asarray(units))
    if u.shape != (B,) or not np.issubdtype(u.dtype, np.integer):
        raise ValueError(f"vmd_batch: units must be {B} integers, one per candidate")
    if B and (u.min() < 0 or u.max() >= xs.shape[0]):
        raise ValueError(f"vmd_batch: units must index the {xs.shape[0]} signal rows")
    return xs, u.astype(np.int64)


_HAS_TRITON: bool | None = None


def _triton_available() -> bool:
    global _HAS_TRITON
    if _HAS_TRITON is None:
        try:
            import triton  # noqa: F401

            _HAS_TRITON = True
        except ImportError:
            _HAS_TRITON = False
    return _HAS_TRITON


def pick_backend(backend: str, device: str | None) -> tuple[str, str | None]:
    """The backend (``numba``, ``torch``, ``triton``) and device that :func:`vmd_batch` runs
    a ``backend``/``device`` request on: ``auto`` takes CUDA (Triton, else torch) when
    torch sees a GPU, else numba on the CPU."""
    if backend not in ("auto", "numba", "torch", "triton"):
        raise ValueError(f"vmd_batch: unknown backend {backend!r}")
    if backend == "numba":
        if device not in (None, "cpu"):
            raise ValueError("vmd_batch: the numba backend runs on the CPU only")
        return "numba", None
    if backend in ("torch", "triton"):
        return backend, device or ("cuda" if backend == "triton" else "cpu")
    if device is None:
        import torch

        if torch.cuda.is_available():
            device = "cuda"
    if device is not None and str(device).startswith("cuda"):
        return ("triton" if _triton_available() else "torch"), device
    return "numba", None


def _initial_block(Ks: np.ndarray, init: str, n: int, dc: bool) -> np.ndarray:
    omega = np.zeros((Ks.size, int(Ks.max())))
    for i, k in enumerate(Ks):
        w = initial_omega(int(k), init, n)
        if dc:
            w[0] = 0.0
        omega[i, :k] = w
    return omega


def _cost_order(Ks: np.ndarray, alphas: np.ndarray, units: np.ndarray) -> np.ndarray:
    """Candidates, most expensive first: many modes, then small alpha (more iterations)."""
    return np.lexsort((units, alphas, -Ks))


BATCH_BYTES = 256 * 2**20  # default bound on the modes held by one numba chunk


def _vmd_batch_numba(xs, units, alphas, Ks, tau, tol, max_iter, init, dc, chunk):
    n = xs.shape[1]
    fds = scipy.fft.dct(xs, type=2, axis=-1)
    B = alphas.size
    threads = numba.get_num_threads()
    if chunk is None:
        chunk = max(2 * threads, BATCH_BYTES // (8 * n * int(Ks.max())))
    order = _cost_order(Ks, alphas, units)
    results: list[VMDResult | None] = [None] * B
    for start in range(0, B, int(chunk)):
        idx = order[start : start + int(chunk)]
        k_c = Ks[idx]
        offs = np.concatenate(([0], np.cumsum(k_c)[:-1])).astype(np.int64)
        u = np.zeros((int(k_c.sum()), n))
        omega = np.concatenate([initial_omega(int(k), init, n) for k in k_c])
        if dc:
            omega[offs] = 0.0
        n_iter = np.zeros(idx.size, dtype=np.int64)
        conv = np.zeros(idx.size, dtype=np.bool_)
        _admm_batch(
            fds, units[idx], alphas[idx], k_c, offs, np.arange(idx.size), omega,
            float(tau), float(tol), int(max_iter), bool(dc), u, n_iter, conv,
            np.zeros(1, dtype=np.int64), threads,
        )  # fmt: skip
        modes = _modes_from_real(u, n, workers=threads)
        for i, j in enumerate(idx):
            k0, k = int(offs[i]), int(k_c[i])
            results[j] = VMDResult(
                modes[k0 : k0 + k], omega[k0 : k0 + k].copy(), int(n_iter[i]),
                bool(conv[i]), float(alphas[j]), k,
            )  # fmt: skip
    return results  # type: ignore[return-value]


def _vmd_batch_torch(xs, units, alphas, Ks, tau, tol, max_iter, init, dc, device, chunk):
    """The same ADMM as :func:`_admm_one`, as batched tensor operations over candidates.

    Candidates are sorted by K (descending), so the candidates that have a mode k form a
    prefix and each mode update works on a slice, not a mask; candidates that converge are
    written out and dropped from the working tensors, so every candidate equals its own
    :func:`vmd` call and finished ones cost nothing. Each line is still one pass over a
    (B, N) array: on the CPU this is bandwidth-bound and far slower than the fused numba
    kernel; it is meant for CUDA, where the passes are cheap.
    """
    import torch

    dev = torch.device(device)
    n = xs.shape[1]
    B = alphas.size
    chunk = B if chunk is None else int(chunk)
    f64 = torch.float64
    order = np.argsort(-Ks, kind="stable")
    out: list[VMDResult | None] = [None] * B
    with torch.no_grad():
        fd_all = torch.as_tensor(scipy.fft.dct(xs, type=2, axis=-1), device=dev)
        fr = torch.arange(n, device=dev, dtype=f64) / (2.0 * n)
        for start in range(0, B, chunk):
            ids = order[start : start + chunk]  # original indices, K descending
            k_np = Ks[ids]
            kmax = int(k_np[0])
            omega = torch.as_tensor(_initial_block(k_np, init, n, dc), device=dev)
            alpha = torch.as_tensor(alphas[ids], device=dev)[:, None]
            fd = fd_all[torch.as_tensor(units[ids], device=dev)]  # (B, n): each its unit's
            u = torch.zeros((ids.size, kmax, n), dtype=f64, device=dev)
            S = torch.zeros((ids.size, n), dtype=f64, device=dev)
            lam = torch.zeros_like(S)
            n_iter = 0
            while ids.size:
                # how many of the (sorted) candidates have a mode k, for every k
                nk = [int((k_np > k).sum()) for k in range(kmax)]
                diff = torch.zeros(ids.size, dtype=f64, device=dev)
                for k in range(kmax):
                    m = nk[k]
                    if m == 0:
                        break
                    old = u[:m, k]
                    oth = S[:m] - old
                    g = 1.0 + alpha[:m] * (fr[None, :] - omega[:m, k : k + 1]) ** 2
                    new = ((fd[:m] - oth - 0.5 * lam[:m]) if tau != 0.0 else (fd[:m] - oth)) / g
                    p = new * new
                    den = p.sum(1)
                    if not (dc and k == 0):
                        num = (fr * p).sum(1)
                        omega[:m, k] = torch.where(den > 0, num / torch.where(den > 0, den, 1.0),
                                                   omega[:m, k])  # fmt: skip
                    diff[:m] += ((new - old) ** 2).sum(1)
                    u[:m, k] = new
                    S[:m] = oth + new
                if tau != 0.0:
                    lam += tau * (S - fd)
                n_iter += 1
                ok = ((EPS + diff / (2.0 * n)) <= tol).cpu().numpy()  # one sync per iteration
                done = ok | (n_iter >= max_iter)
                if not done.any():
                    continue
                fin = np.flatnonzero(done)
                u_c, om_c = u[fin].cpu().numpy(), omega[fin].cpu().numpy()
                for i, row in enumerate(fin):
                    k = int(k_np[row])
                    out[ids[row]] = VMDResult(
                        _modes_from_real(u_c[i, :k], n), om_c[i, :k].copy(), n_iter,
                        bool(ok[row]), float(alphas[ids[row]]), k,
                    )  # fmt: skip
                keep = np.flatnonzero(~done)
                kt = torch.as_tensor(keep, device=dev)
                ids, k_np = ids[keep], k_np[keep]
                u, S, lam, fd = u[kt], S[kt], lam[kt], fd[kt]
                omega, alpha = omega[kt], alpha[kt]
                kmax = int(k_np[0]) if ids.size else 0
                u = u[:, :kmax]
                omega = omega[:, :kmax]
    return out
