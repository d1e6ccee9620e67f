"""VMD: gyrolab vs vmdpy 0.2, side by side in one process.

Per call on N = 11 000, K = 11, alpha in {50, 2000, 5000} (vmdpy's settings: tau = 0,
DC = 0, init = 1, tol = 1e-7): median wall time of ``--repeat`` calls each, the ratio,
and the peak traced memory of one call (tracemalloc; numpy's buffers are traced). Two
records: ``paper`` (synthetic drift + noise in deg/s, like the paper's; VMD's absolute
tolerance is met in a few tens of iterations) and ``unit`` (the same record scaled to unit
variance, which runs many more iterations). Then N = 1 000 000, K = 7 (ours only: vmdpy
would need 500 x 2e6 x 7 complex values of history, about 112 GB). Then the batch of 50
(K, alpha) candidates of one GPSO generation: the numba batch at 1 thread and at all
threads (after a warm-up that compiles it), and on a CUDA device the fused Triton kernel
(a sweep of tile sizes, the achieved bandwidth against the issue's estimate, the unfused
torch path); then a fleet of 32 units x 50 candidates in one call. Without CUDA the GPU
rows print "not measured".

Usage: ``python benchmarks/bench_vmd.py [--repeat 5] [--device cuda] [--skip-large]
[--batch-only] [--fleet 32]``
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
import tracemalloc

import numpy as np

os.environ.setdefault("GYROLAB_NO_PROGRESS", "1")

from gyrolab.compensation.fitness import synthetic_drift_signal  # noqa: E402
from gyrolab.compensation.vmd import vmd, vmd_batch  # noqa: E402


def timed(fn, repeat: int) -> tuple[float, object]:
    out, times = None, []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def peak_mb(fn) -> float:
    tracemalloc.start()
    tracemalloc.reset_peak()
    fn()
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return peak / 1e6


def per_call(repeat: int) -> None:
    try:
        from vmdpy import VMD
    except ImportError:  # pragma: no cover
        VMD = None
        print("vmdpy not installed: ours only")
    base = synthetic_drift_signal(11_000, seed=0)
    records = {"paper": base, "unit": (base - base.mean()) / base.std()}
    vmd(base[:200], 100.0, 2)  # JIT load outside the timings
    print(f"\nper call, N = 11 000, K = 11, median of {repeat}")
    hdr = (
        f"{'record':<6} {'alpha':>6} {'iters':>6} {'ours ms':>9} {'vmdpy ms':>9} "
        f"{'ratio':>7} {'ours MB':>8} {'vmdpy MB':>9} {'rel L2 (penult.)':>17}"
    )
    print(hdr)
    for name, x in records.items():
        for alpha in (50.0, 2000.0, 5000.0):
            t_ours, r = timed(lambda x=x, a=alpha: vmd(x, a, 11), repeat)
            m_ours = peak_mb(lambda x=x, a=alpha: vmd(x, a, 11))
            if VMD is None:
                print(f"{name:<6} {alpha:6.0f} {r.n_iter:6d} {t_ours * 1e3:9.2f}")
                continue
            t_ref, (u, _, om) = timed(lambda x=x, a=alpha: VMD(x, a, 0.0, 11, 0, 1, 1e-7), repeat)
            m_ref = peak_mb(lambda x=x, a=alpha: VMD(x, a, 0.0, 11, 0, 1, 1e-7))
            pen = vmd(x, alpha, 11, tol=0.0, max_iter=om.shape[0] - 1)
            rel = np.linalg.norm(pen.modes - u) / np.linalg.norm(u)
            print(
                f"{name:<6} {alpha:6.0f} {r.n_iter:6d} {t_ours * 1e3:9.2f} {t_ref * 1e3:9.1f} "
                f"{t_ref / t_ours:6.1f}x {m_ours:8.1f} {m_ref:9.0f} {rel:17.1e}"
            )


def large() -> None:
    rng = np.random.default_rng(1)
    n = 1_000_000
    x = np.cumsum(rng.standard_normal(n)) * 1e-3 + rng.standard_normal(n)
    t0 = time.perf_counter()
    mb = peak_mb(lambda: vmd(x, 2000.0, 7))
    dt = time.perf_counter() - t0
    t1 = time.perf_counter()
    r = vmd(x, 2000.0, 7)
    dt2 = time.perf_counter() - t1
    print(
        f"\nN = 1 000 000, K = 7, alpha = 2000: {r.n_iter} iterations, {dt2:.2f} s, "
        f"peak traced {mb:.0f} MB (the traced run took {dt:.2f} s)"
    )


def _unit_record(seed: int = 0, n: int = 11_000) -> np.ndarray:
    x = synthetic_drift_signal(n, seed=seed)
    return (x - x.mean()) / x.std()


# the issue's candidate set: 50 candidates, K 3..11, alpha 50..5000 (log-spaced)
KS = np.repeat(np.arange(3, 12), 6)[:50]
ALPHAS = np.geomspace(50, 5000, 50)
# the issue's estimate of one such batch on the GPU: ~37 GB moved, ~12 ms at ~3 TB/s (H100)
ISSUE_GB, PEAK_TBS = 37.0, 3.0


def best_of(fn, repeat: int) -> tuple[float, object]:
    out, best = None, float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def _worst_rel(res, ref) -> float:
    return max(
        float(np.linalg.norm(a.modes - b.modes) / np.linalg.norm(b.modes))
        for a, b in zip(res, ref, strict=True)
    )


def _parallel_check() -> float:
    """How well an embarrassingly parallel loop scales on all threads right now."""
    import numba

    @numba.njit(parallel=True)
    def spin(out):  # pragma: no cover
        for i in numba.prange(out.size):
            s = 0.0
            for j in range(3_000_000):
                s += np.sqrt(j + i)
            out[i] = s

    nt = numba.get_num_threads()
    out = np.zeros(2 * nt)
    spin(out)
    numba.set_num_threads(1)
    t1, _ = best_of(lambda: spin(out), 3)
    numba.set_num_threads(nt)
    tn, _ = best_of(lambda: spin(out), 3)
    return t1 / tn


def batch(repeat: int, device: str | None, fleet_units: int) -> None:
    """The 50-candidate batch (and a fleet of units x 50): numba at 1 and all threads, GPU."""
    import numba
    import torch

    nt = numba.get_num_threads()
    x = _unit_record()
    load = os.getloadavg()
    print(
        f"\nbatch of {len(ALPHAS)} candidates (K 3..11, alpha 50..5000, unit record, N = 11 000), "
        f"best of {repeat}; load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; "
        f"a perfectly parallel loop scales {_parallel_check():.2f}x on {nt} threads right now"
    )
    # warm-up: compile the numba batch kernel and run it once at each thread count
    times = {}
    for threads in sorted({1, nt}):
        numba.set_num_threads(threads)
        vmd_batch(x, ALPHAS, KS, backend="numba")
        times[threads], ref = best_of(lambda: vmd_batch(x, ALPHAS, KS, backend="numba"), repeat)
    numba.set_num_threads(nt)
    print(
        f"numba batch: 1 thread {times[1]:.3f} s, {nt} threads {times[nt]:.3f} s "
        f"({times[1] / times[nt]:.2f}x)"
    )
    gpu_ok = device is not None and device.startswith("cuda") and torch.cuda.is_available()
    if not gpu_ok:
        print("GPU (triton): not measured - no CUDA device here")
    else:
        gpu_batch(x, ref, min(times.values()), repeat, device)
    fleet(fleet_units, device if gpu_ok else None)


def gpu_batch(x, ref, t_cpu: float, repeat: int, device: str) -> None:
    import torch

    from gyrolab.compensation.vmd_triton import vmd_batch_triton

    print(f"GPU: {torch.cuda.get_device_name(0)}")
    xs, units = x[None, :], np.zeros(len(KS), dtype=np.int64)

    def run(timings=None, **kw):
        return vmd_batch_triton(
            xs, units, ALPHAS, KS, 0.0, 1e-7, 500, "uniform", False, device=device,
            timings=timings, **kw,
        )  # fmt: skip

    for block, warps in ((256, 2), (512, 4), (1024, 4), (1024, 8)):
        run(block=block, num_warps=warps)  # compile + warm-up
        t, _ = best_of(lambda b=block, w=warps: run(block=b, num_warps=w), repeat)
        print(f"  triton block {block:5d}, {warps} warps: {t * 1e3:7.2f} ms")
    run()
    t_dev, res = best_of(run, repeat)
    tm: dict = {}
    run(tm)
    gbs = tm["traffic_bytes"] / tm["admm_s"] / 1e9
    print(
        f"triton (default block): {t_dev * 1e3:.2f} ms per batch, {t_cpu / t_dev:.1f}x the numba "
        f"batch at its best thread count; worst rel. difference from numba "
        f"{_worst_rel(res, ref):.1e}"
    )
    print(
        f"  ADMM loop {tm['admm_s'] * 1e3:.2f} ms over {tm['launches']} launches, "
        f"{tm['traffic_bytes'] / 1e9:.1f} GB moved (issue's estimate {ISSUE_GB:.0f} GB): "
        f"{gbs:.0f} GB/s achieved, {gbs / (PEAK_TBS * 1e3):.0%} of {PEAK_TBS:.0f} TB/s; "
        f"the estimate's {tm['traffic_bytes'] / (PEAK_TBS * 1e12) * 1e3:.1f} ms is "
        f"{t_dev / (tm['traffic_bytes'] / (PEAK_TBS * 1e12)):.1f}x below the whole call"
    )
    vmd_batch(x, ALPHAS[:2], KS[:2], backend="torch", device=device)  # warm-up
    t_torch, _ = best_of(lambda: vmd_batch(x, ALPHAS, KS, backend="torch", device=device), 1)
    print(f"torch (unfused) on {device}: {t_torch * 1e3:.1f} ms")


def fleet(n_units: int, device: str | None) -> None:
    import numba

    if n_units <= 0:
        return
    xs = np.stack([_unit_record(seed=s) for s in range(n_units)])
    Ks, alphas = np.tile(KS, n_units), np.tile(ALPHAS, n_units)
    units = np.repeat(np.arange(n_units), len(KS))
    nt = numba.get_num_threads()
    t_cpu, ref = best_of(lambda: vmd_batch(xs, alphas, Ks, units=units, backend="numba"), 1)
    line = f"fleet {n_units} units x {len(KS)} candidates, one call: numba {nt} threads "
    line += f"{t_cpu:.2f} s"
    if device is None:
        print(line + "; GPU (triton): not measured - no CUDA device here")
        return
    run = lambda: vmd_batch(xs, alphas, Ks, units=units, backend="triton", device=device)  # noqa: E731
    run()
    t_dev, res = best_of(run, 3)
    print(
        f"{line}; triton {t_dev * 1e3:.1f} ms ({t_cpu / t_dev:.1f}x), worst rel. difference "
        f"{_worst_rel(res, ref):.1e}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description="VMD: gyrolab vs vmdpy")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument(
        "--device", default=None, help="GPU for the batch rows (default: cuda when present)"
    )
    ap.add_argument("--skip-large", action="store_true", help="skip N = 1 000 000")
    ap.add_argument("--batch-only", action="store_true", help="only the batch and fleet rows")
    ap.add_argument("--fleet", type=int, default=32, help="units in the fleet row (0: skip)")
    args = ap.parse_args()
    sys.stdout.reconfigure(line_buffering=True)  # progress visible when piped
    import numba

    print(
        f"{platform.node()} {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} CPUs, numba threads {numba.get_num_threads()}, "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}"
    )
    if not args.batch_only:
        per_call(args.repeat)
        if not args.skip_large:
            large()
    device = args.device
    if device is None:
        import torch

        device = "cuda" if torch.cuda.is_available() else None
    batch(args.repeat, device, args.fleet)


if __name__ == "__main__":
    main()
