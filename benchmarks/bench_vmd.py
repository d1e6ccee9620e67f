"""VMD: gyrolab vs vmdpy 0.2, side by side in one process.

Per call on N = 11 000, K = 11, alpha in {50, 2000, 5000} (vmdpy's settings: tau = 0,
DC = 0, init = 1, tol = 1e-7): median wall time of ``--repeat`` calls each, the ratio,
and the peak traced memory of one call (tracemalloc; numpy's buffers are traced). Two
records: ``paper`` (synthetic drift + noise in deg/s, like the paper's; VMD's absolute
tolerance is met in a few tens of iterations) and ``unit`` (the same record scaled to unit
variance, which runs many more iterations). Then N = 1 000 000, K = 7 (ours only: vmdpy
would need 500 x 2e6 x 7 complex values of history, about 112 GB). With ``--device cuda``
the batched torch path is timed on the GPU against the numba path (skipped without CUDA).

Usage: ``python benchmarks/bench_vmd.py [--repeat 5] [--device cpu|cuda] [--skip-large]``
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


def gpu(repeat: int, device: str) -> None:
    import torch

    if device.startswith("cuda") and not torch.cuda.is_available():
        print(f"\n--device {device}: CUDA is not available here, GPU timing skipped")
        return
    x = synthetic_drift_signal(11_000, seed=0)
    x = (x - x.mean()) / x.std()
    Ks = np.repeat(np.arange(3, 12), 6)[:50]
    alphas = np.geomspace(50, 5000, 50)
    vmd_batch(x, alphas[:2], Ks[:2], backend="torch", device=device)  # warm-up
    t_dev, res = timed(
        lambda: vmd_batch(x, alphas, Ks, backend="torch", device=device),
        max(1, repeat // 2),
    )
    t_cpu, ref = timed(lambda: vmd_batch(x, alphas, Ks, backend="numba"), max(1, repeat // 2))
    worst = max(
        np.linalg.norm(a.modes - b.modes) / np.linalg.norm(b.modes)
        for a, b in zip(res, ref, strict=True)
    )
    print(
        f"\nbatch of {len(alphas)} candidates (K 3..11, alpha 50..5000, unit record): "
        f"torch on {device} "
        f"{t_dev:.2f} s, numba CPU {t_cpu:.2f} s, ratio {t_cpu / t_dev:.1f}x, "
        f"worst rel. difference {worst:.1e}"
    )
    if device.startswith("cuda"):
        print(f"GPU: {torch.cuda.get_device_name(0)}")


def main() -> None:
    ap = argparse.ArgumentParser(description="VMD: gyrolab vs vmdpy")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--device", default=None, help="also time the torch batch on this device")
    ap.add_argument("--skip-large", action="store_true", help="skip N = 1 000 000")
    args = ap.parse_args()
    sys.stdout.reconfigure(line_buffering=True)  # progress visible when piped
    import numba

    print(
        f"{platform.node()} {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} CPUs, numba threads {numba.get_num_threads()}, "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}"
    )
    per_call(args.repeat)
    if not args.skip_large:
        large()
    if args.device:
        gpu(args.repeat, args.device)


if __name__ == "__main__":
    main()
