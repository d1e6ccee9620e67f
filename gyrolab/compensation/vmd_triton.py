"""VMD's ADMM for a whole batch of candidates as one fused Triton kernel per iteration.

This is the GPU path of :func:`gyrolab.compensation.vmd.vmd_batch` (``backend="triton"``,
chosen automatically on CUDA when Triton is installed). It runs exactly the iteration of
the numba kernel :func:`gyrolab.compensation.vmd._admm_one` (real DCT spectra, modes
updated in order inside each frequency bin, the "sum of the other modes" kept as a running
total ``S``), but for every mode of every candidate of every unit at once:

    u_k(w) <- (f(w) - (S(w) - u_k(w)) - lambda(w) / 2) / (1 + alpha (w - omega_k)^2)
    S(w)   <- S(w) - u_k^old(w) + u_k(w)                        k = 1..K in order
    omega_k <- sum_w w u_k(w)^2 / sum_w u_k(w)^2                (paper eq. 6)
    lambda <- lambda + tau (S - f)                              (paper eq. 7)
    stop when eps + (1/T) sum_k sum_w (u_k - u_k^old)^2 <= tol  (reference form of eq. 8)

One launch is one ADMM iteration for the batch. Program ``(c, j)`` owns frequency tile j
(``BLOCK`` bins) of active candidate c: it keeps that tile of ``f``, ``S`` and ``lambda``
in registers while it walks through the candidate's K modes (one read and one write of
each mode tile), and writes per-tile partial sums of ``w u_k^2``, ``u_k^2`` and the
update energy. The reductions of eq. 6 and eq. 8 are finished by the *next* launch: every
program of a candidate sums the (few) tile partials of the previous iteration, so it
derives the same ``omega`` and the same stop decision without a grid-wide barrier and
without atomics (the sums are deterministic). Partial sums and ``omega`` are double
buffered by iteration parity, so a launch only reads what the previous one wrote.

Per-candidate convergence: a candidate whose stopping rule holds is marked done by its
tile-0 program (iteration count, converged flag, final ``omega``); from then on each of
its programs costs one load and returns, and every ``sync_every`` launches the host drops
finished candidates from the grid (the only host synchronisation). float64 throughout.

On the CPU (``device="cpu"``) the same kernel runs in Triton's interpreter, which executes
the kernel body with NumPy one program at a time: that is how the tests check this
kernel's algorithm against the numba path on machines without a GPU. (Why Triton and not a
CUDA C kernel through CuPy or a torch extension: those cannot run at all without a GPU, so
CI could never execute them.)

Memory traffic per iteration and candidate (float64, N bins): read and write each of the
K mode arrays and ``S``, read ``f`` (and read and write ``lambda`` when ``tau > 0``):
``8 N (2 K + 3 + 2 [tau > 0])`` bytes; :func:`admm_traffic_bytes` sums it over a run.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.fft

from gyrolab.compensation.vmd_base import EPS, VMDResult, initial_omega

try:  # optional: the `gpu` extra
    import triton
    import triton.language as tl
except ImportError:  # pragma: no cover - exercised where Triton is absent
    triton = None
    tl = None

__all__ = ["admm_traffic_bytes", "vmd_batch_triton"]

# tl.sum without its dtype logic (a no-op for float64): under the interpreter every call
# of a jit function costs ~1 ms, tl.sum is one, tl.reduce with this combiner is a builtin
_ADD = tl.standard._sum_combine if tl is not None else None


def admm_step(
    fd_ptr, unit_ptr, k_ptr, alpha_ptr, row_ptr, cand_ptr,
    u_ptr, s_ptr, lam_ptr, pnum_ptr, pden_ptr, pdiff_ptr, omega_ptr, done_ptr, niter_ptr,
    par_ptr, L, B, M, NB, max_iter,
    KMAX: tl.constexpr, KMAX_P2: tl.constexpr, BLOCK: tl.constexpr, NB_P2: tl.constexpr,
    USE_LAM: tl.constexpr, DC: tl.constexpr,
):  # fmt: skip
    """Iteration ``L + 1`` of every active candidate (grid: active candidates x tiles).

    ``par`` = (tau, tol, 1/T, eps) as float64 (Python floats would reach the kernel as
    float32). Buffers indexed ``[parity, candidate, ...]``: parity ``L % 2`` is written,
    ``(L + 1) % 2`` (the previous launch's) is read.
    """
    c = tl.program_id(0)
    j = tl.program_id(1)
    b = tl.load(cand_ptr + c)
    if tl.load(done_ptr + b) == 0:  # a finished candidate costs this one load
        tau = tl.load(par_ptr)
        tol = tl.load(par_ptr + 1)
        inv_t = tl.load(par_ptr + 2)
        eps = tl.load(par_ptr + 3)
        K = tl.load(k_ptr + b)
        alpha = tl.load(alpha_ptr + b)
        row0 = tl.load(row_ptr + b)
        unit = tl.load(unit_ptr + b)
        rd = (L + 1) % 2
        wr = L % 2
        # stopping rule on the previous iteration's update energy (eq. 8)
        t = tl.arange(0, NB_P2)
        tm = t < NB
        diff = tl.reduce(tl.load(pdiff_ptr + (rd * B + b) * NB + t, mask=tm, other=0.0), 0, _ADD)
        udiff = eps + diff * inv_t
        conv = (L > 0) & (udiff <= tol)
        go = (L < max_iter) & ((L == 0) | (udiff > tol))
        offs = j * BLOCK + tl.arange(0, BLOCK)
        m = offs < tl.where(go, M, 0)  # (a scalar & block mask trips the interpreter)
        fr = offs.to(tl.float64) * inv_t  # w_m = m / T, as the numba kernel computes it
        fd = tl.load(fd_ptr + unit * M + offs, mask=m, other=0.0)
        S = tl.load(s_ptr + b * M + offs, mask=m, other=0.0)
        if USE_LAM:
            lam = tl.load(lam_ptr + b * M + offs, mask=m, other=0.0)
        # omega after the previous iteration (eq. 6), all modes at once from its partials
        kk = tl.arange(0, KMAX_P2)
        pr = ((rd * B + b) * KMAX + kk[:, None]) * NB + t[None, :]
        pm = (kk[:, None] < K) & tm[None, :]
        num = tl.reduce(tl.load(pnum_ptr + pr, mask=pm, other=0.0), 1, _ADD)
        den = tl.reduce(tl.load(pden_ptr + pr, mask=pm, other=0.0), 1, _ADD)
        upd = den > 0.0
        if DC:
            upd = upd & (kk != 0)
        ow = (rd * B + b) * KMAX + kk
        w_old = tl.load(omega_ptr + ow, mask=kk < K, other=0.0)
        W = tl.where(upd, num / tl.where(upd, den, 1.0), w_old)
        tl.store(omega_ptr + (wr * B + b) * KMAX + kk, W, mask=kk < tl.where(j == 0, K, 0))
        dsum = tl.zeros([BLOCK], dtype=tl.float64)
        # a constexpr bound, modes past K skipped: Triton 3.6's interpreter cannot iterate
        # to a loaded K under NumPy 2.5 (int() of a 1-element array); on the GPU it is a branch
        for k in range(0, KMAX):
            if k < K:
                w = tl.reduce(tl.where(kk == k, W, 0.0), 0, _ADD)
                # the Wiener update of mode k on this tile (eq. 5)
                uk = u_ptr + (row0 + k) * M + offs
                old = tl.load(uk, mask=m, other=0.0)
                d = fr - w
                oth = S - old
                if USE_LAM:
                    new = (fd - oth - 0.5 * lam) / (1.0 + alpha * d * d)
                else:
                    new = (fd - oth) / (1.0 + alpha * d * d)
                tl.store(uk, new, mask=m)
                S = oth + new
                p = new * new
                e = new - old
                dsum += e * e
                pw = ((wr * B + b) * KMAX + k) * NB + j
                tl.store(pnum_ptr + pw, tl.reduce(fr * p, 0, _ADD), mask=go)
                tl.store(pden_ptr + pw, tl.reduce(p, 0, _ADD), mask=go)
        tl.store(s_ptr + b * M + offs, S, mask=m)
        if USE_LAM:
            tl.store(lam_ptr + b * M + offs, lam + tau * (S - fd), mask=m)
        tl.store(pdiff_ptr + (wr * B + b) * NB + j, tl.reduce(dsum, 0, _ADD), mask=go)
        # tile 0 records the end: 2 = converged, 1 = stopped at max_iter
        last = ((L >= max_iter) | conv) & (j == 0)
        tl.store(done_ptr + b, tl.where(conv, 2, 1).to(tl.int32), mask=last)
        tl.store(niter_ptr + b, L, mask=last)


_KERNEL = None


def _kernel(interpret: bool):
    """The kernel: compiled for CUDA, or run by Triton's interpreter on the CPU.

    The interpreter has to be chosen before Triton is imported (its standard library,
    ``tl.sum`` included, is built for one mode at import), so the CPU path needs
    ``TRITON_INTERPRET=1`` in the environment of the whole process.
    """
    global _KERNEL
    if triton is None:
        raise ImportError("vmd_batch(backend='triton') needs Triton: pip install 'gyrolab[gpu]'")
    from triton.runtime.interpreter import InterpretedFunction

    interpreted = isinstance(tl.sum, InterpretedFunction)
    if interpret and not interpreted:
        raise RuntimeError(
            "vmd_batch(backend='triton', device='cpu') runs Triton's interpreter: set "
            "TRITON_INTERPRET=1 in the environment before Python starts"
        )
    if not interpret and interpreted:
        raise RuntimeError("TRITON_INTERPRET=1 is set: the triton backend runs on the CPU only")
    if _KERNEL is None:
        # L changes every launch: no specialisation on its value (one compiled variant)
        _KERNEL = triton.jit(admm_step, do_not_specialize=["L"])
    return _KERNEL


def admm_traffic_bytes(Ks, n_iter, n: int, tau: float = 0.0) -> float:
    """Bytes the kernel moves for candidates with ``Ks`` modes run ``n_iter`` iterations.

    Per iteration and candidate ``8 n (2 K + 3 + 2 [tau > 0])``: each mode tile and ``S``
    read and written once, ``f`` read (``lambda`` read and written when ``tau > 0``); the
    tile partial sums are negligible. Used for the achieved bandwidth in the benchmark.
    """
    Ks = np.asarray(Ks, dtype=np.float64)
    n_iter = np.asarray(n_iter, dtype=np.float64)
    return float(np.sum(n_iter * 8.0 * n * (2 * Ks + 3 + (2 if tau != 0.0 else 0))))


def _idct2_rows(u, n: int):
    """scipy's ``idct(type=2)`` along the last axis, by one complex FFT of length 2 n.

    x_t = (1 / 2n) [u_0 + 2 sum_(m>=1) u_m cos(pi m (2t + 1) / 2n)]
        = Re ifft_(2n)(z)_t,  z_m = (1 if m == 0 else 2) u_m exp(i pi m / 2n).
    """
    import torch

    m = torch.arange(n, device=u.device, dtype=torch.float64)
    tw = torch.exp(1j * np.pi * m / (2 * n))
    tw[1:] *= 2.0
    return torch.fft.ifft(u * tw, n=2 * n, dim=-1).real[..., :n]


def _modes_from_real_torch(u, n: int, rows: int = 1024):
    """:func:`gyrolab.compensation.vmd._modes_from_real` on the device, ``rows`` at a time."""
    import torch

    h = n // 2
    sign = torch.where((torch.arange(n, device=u.device) + h) % 2 == 0, 1.0, -1.0).to(torch.float64)
    cst = np.cos(np.pi * (n - 1) * (0.5 - h) / n) / (2.0 * n)
    out = torch.empty_like(u)
    for r0 in range(0, u.shape[0], rows):
        blk = u[r0 : r0 + rows]
        out[r0 : r0 + rows] = _idct2_rows(blk, n) + (cst * blk[:, n - 1])[:, None] * sign
    return out


def vmd_batch_triton(
    xs: np.ndarray,
    units: np.ndarray,
    alphas: np.ndarray,
    Ks: np.ndarray,
    tau: float,
    tol: float,
    max_iter: int,
    init: str,
    dc: bool,
    *,
    device: str = "cuda",
    chunk: int | None = None,
    block: int | None = None,
    num_warps: int = 4,
    sync_every: int = 8,
    timings: dict | None = None,
) -> list[VMDResult]:
    """Run the batch through :func:`admm_step`; arguments as validated by ``vmd_batch``.

    Parameters
    ----------
    xs : ndarray, shape (U, N)
        The records; candidate b decomposes ``xs[units[b]]``.
    device : str
        "cuda[:i]" (compiled kernel) or "cpu" (Triton interpreter; slow, for tests).
    chunk : int, optional
        Candidates per kernel batch (default all; device memory is about
        ``8 N (sum K + 2 B)`` bytes for a batch of B candidates).
    block : int, optional
        Frequency bins per program (a power of two; default 512 on CUDA, 256 on the CPU).
        At 512 bins and 4 warps ptxas reports 118 registers per thread and no spills for
        sm_90 (4 programs per SM); the benchmark on a GPU sweeps block and warps.
    num_warps : int
        Warps per program (CUDA).
    sync_every : int
        Launches between compactions of the active set (each is one host synchronisation).
    timings : dict, optional
        Filled with ``admm_s`` (the iteration loop, synchronised), ``launches``,
        ``traffic_bytes`` (:func:`admm_traffic_bytes`) and ``total_s``.
    """
    import torch

    t_start = time.perf_counter()
    dev = torch.device(device)
    interpret = dev.type == "cpu"
    kernel = _kernel(interpret)
    f64 = torch.float64
    U, n = xs.shape
    B = alphas.size
    block = int(block or (256 if interpret else 512))
    nb = -(-n // block)
    nb_p2 = 1 << max(nb - 1, 0).bit_length()
    chunk = B if chunk is None else max(int(chunk), 1)
    fd = torch.as_tensor(scipy.fft.dct(xs, type=2, axis=-1), device=dev)
    par = torch.tensor([tau, tol, 1.0 / (2.0 * n), EPS], dtype=f64, device=dev)
    order = np.lexsort((alphas, -Ks))  # similar candidates side by side
    out: list[VMDResult | None] = [None] * B
    admm_s = 0.0
    launches = 0
    all_iters = np.zeros(B, dtype=np.int64)
    for start in range(0, B, chunk):
        ids = order[start : start + chunk]
        nc = ids.size
        k_c = Ks[ids]
        kmax = int(k_c.max())
        rows = np.concatenate(([0], np.cumsum(k_c)[:-1])).astype(np.int64)
        om0 = np.zeros((2, nc, kmax))
        for i, k in enumerate(k_c):  # iteration 0 reads parity 1
            om0[1, i, :k] = initial_omega(int(k), init, n)
            if dc:
                om0[1, i, 0] = 0.0
        u = torch.zeros((int(k_c.sum()), n), dtype=f64, device=dev)
        S = torch.zeros((nc, n), dtype=f64, device=dev)
        lam = torch.zeros((nc, n), dtype=f64, device=dev) if tau != 0.0 else S
        pnum = torch.zeros((2, nc, kmax, nb), dtype=f64, device=dev)
        pden = torch.zeros_like(pnum)
        pdiff = torch.zeros((2, nc, nb), dtype=f64, device=dev)
        omega = torch.as_tensor(om0, device=dev)
        done = torch.zeros(nc, dtype=torch.int32, device=dev)
        niter = torch.zeros(nc, dtype=torch.int32, device=dev)
        t_unit = torch.as_tensor(units[ids], device=dev)
        t_k = torch.as_tensor(k_c.astype(np.int32), device=dev)
        t_alpha = torch.as_tensor(alphas[ids], device=dev)
        t_row = torch.as_tensor(rows, device=dev)
        active = torch.arange(nc, dtype=torch.int64, device=dev)
        if dev.type == "cuda":
            torch.cuda.synchronize(dev)
        t0 = time.perf_counter()
        L = 0
        while active.numel() and L <= max_iter:
            for _ in range(min(sync_every, max_iter + 1 - L)):
                kernel[(int(active.numel()), nb)](
                    fd, t_unit, t_k, t_alpha, t_row, active,
                    u, S, lam, pnum, pden, pdiff, omega, done, niter,
                    par, L, nc, n, nb, int(max_iter),
                    KMAX=kmax, KMAX_P2=1 << (kmax - 1).bit_length(), BLOCK=block, NB_P2=nb_p2,
                    USE_LAM=tau != 0.0, DC=bool(dc), num_warps=num_warps, enable_fp_fusion=True,
                )  # fmt: skip
                L += 1
                launches += 1
            active = active[done[active] == 0]  # the host synchronises here
        if dev.type == "cuda":
            torch.cuda.synchronize(dev)
        admm_s += time.perf_counter() - t0
        n_it = niter.cpu().numpy().astype(np.int64)
        ok = done.cpu().numpy() == 2
        om = omega.cpu().numpy()
        modes = _modes_from_real_torch(u, n).cpu().numpy()
        for i, cid in enumerate(ids):
            k, r0 = int(k_c[i]), int(rows[i])
            all_iters[cid] = n_it[i]
            out[cid] = VMDResult(
                modes[r0 : r0 + k], om[n_it[i] % 2, i, :k].copy(), int(n_it[i]), bool(ok[i]),
                float(alphas[cid]), k,
            )  # fmt: skip
    if timings is not None:
        timings.update(
            admm_s=admm_s,
            launches=launches,
            traffic_bytes=admm_traffic_bytes(Ks, all_iters, n, tau),
            total_s=time.perf_counter() - t_start,
        )
    return out  # type: ignore[return-value]
