"""Allan-family deviations: gyrolab vs allantools, side by side (time and peak memory).

``--kind oadev`` (default) times ``allan_deviation`` against ``allantools.oadev``;
``mdev``, ``tdev``, ``hdev``, ``totdev`` time ``deviations.deviation(kind=...)`` against
``allantools.mdev``, ``tdev``, ``ohdev``, ``totdev`` (ours includes the noise
identification and EDF of its confidence intervals; allantools' error bars are 1/sqrt(n)).

Each measurement runs in a fresh subprocess so that peak RSS belongs to that call alone:
the subprocess makes the data (seeded white + random-walk rate noise, float64), records its
peak RSS, runs one warm-up on a short series (numba compile / imports), then times the full
call under ``tracemalloc`` (numpy reports its buffers to tracemalloc, so the traced peak is
the call's own array memory) and reads the peak RSS again: ``rss_delta`` is the growth of
the process peak caused by the call.

    python benchmarks/bench_allan.py [--n 40000000] [--rate 1000] [--taus octave] [--repeat 1]
        [--kind oadev|mdev|tdev|hdev|totdev]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time
import tracemalloc

import numpy as np


def _data(n: int, seed: int = 1) -> np.ndarray:
    """White rate noise 0.01 deg/s + a little rate random walk + a 0.3 deg/s bias, built in
    1 M-sample chunks so that making it never needs more than the array itself (the peak-RSS
    baseline then is the data, not its construction)."""
    rng = np.random.default_rng(seed)
    y = np.empty(n)
    chunk = 1 << 20
    walk = 0.0
    tmp = np.empty(chunk)
    for i in range(0, n, chunk):
        k = min(chunk, n - i)
        rng.standard_normal(out=y[i : i + k])
        y[i : i + k] *= 0.01
        rng.standard_normal(out=tmp[:k])
        np.cumsum(tmp[:k], out=tmp[:k])
        tmp[:k] += walk
        walk = float(tmp[k - 1])
        y[i : i + k] += 1e-6 * tmp[:k]
    y += 0.3  # the mean must not hurt the accuracy
    return y


def _peak_rss_bytes() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # Linux: kB


PEER = {"oadev": "oadev", "mdev": "mdev", "tdev": "tdev", "hdev": "ohdev", "totdev": "totdev"}


def _one(which: str, n: int, rate: float, taus: str, kind: str = "oadev") -> dict:
    y = _data(n)
    if which == "gyrolab" and kind == "oadev":
        from gyrolab.numerics.allan import allan_deviation

        def call(v: np.ndarray) -> np.ndarray:
            return allan_deviation(v, rate, taus=taus).dev
    elif which == "gyrolab":
        from gyrolab.numerics.deviations import deviation

        def call(v: np.ndarray) -> np.ndarray:
            return deviation(v, rate, kind, taus=taus).dev  # type: ignore[union-attr]
    else:
        import allantools

        peer = getattr(allantools, PEER[kind])

        def call(v: np.ndarray) -> np.ndarray:
            return peer(v, rate=rate, data_type="freq", taus=taus)[1]

    call(y[:10_000])  # warm-up: imports, numba compilation (cached on disk)
    rss0 = _peak_rss_bytes()
    tracemalloc.start()
    t0 = time.perf_counter()
    adev = call(y)
    dt = time.perf_counter() - t0
    _, traced_peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    rss1 = _peak_rss_bytes()
    return {
        "impl": which,
        "seconds": dt,
        "traced_peak_MB": traced_peak / 1e6,
        "rss_delta_MB": (rss1 - rss0) / 1e6,
        "data_MB": y.nbytes / 1e6,
        "n_taus": int(len(adev)),
        "adev": [float(a) for a in adev],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=40_000_000, help="samples (40 M = 11 h at 1 kHz)")
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--taus", default="octave")
    ap.add_argument("--repeat", type=int, default=1, help="alternate runs per implementation")
    ap.add_argument("--kind", default="oadev", choices=sorted(PEER))
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(_one(args.child, args.n, args.rate, args.taus, args.kind)))
        return

    env = dict(os.environ, GYROLAB_NO_PROGRESS="1")
    runs: dict[str, list[dict]] = {"gyrolab": [], "allantools": []}
    for _ in range(args.repeat):
        for which in ("allantools", "gyrolab"):  # alternate so background load hits both
            cmd = [sys.executable, __file__, "--child", which, "--n", str(args.n)]
            cmd += ["--rate", str(args.rate), "--taus", args.taus, "--kind", args.kind]
            out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env)
            runs[which].append(json.loads(out.stdout.strip().splitlines()[-1]))

    best = {k: min(v, key=lambda r: r["seconds"]) for k, v in runs.items()}
    g, a = best["gyrolab"], best["allantools"]
    m = min(len(g["adev"]), len(a["adev"]))
    rel = float(np.max(np.abs(np.array(g["adev"][:m]) / np.array(a["adev"][:m]) - 1.0)))
    print(f"# {args.kind}, {args.n:,} samples at {args.rate:g} Hz, taus={args.taus}")
    print(
        f"# {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs visible, "
        f"python {platform.python_version()}, numpy {np.__version__}, "
        f"best of {args.repeat} (fresh process each)"
    )
    print("| impl | time (s) | traced peak (MB) | peak RSS growth (MB) | taus |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for r in (a, g):
        print(
            f"| {r['impl']} | {r['seconds']:.2f} | {r['traced_peak_MB']:.0f} | "
            f"{r['rss_delta_MB']:.0f} | {r['n_taus']} |"
        )
    print(
        f"time ratio gyrolab/allantools: {g['seconds'] / a['seconds']:.3f}; "
        f"traced-memory ratio: {g['traced_peak_MB'] / a['traced_peak_MB']:.3f}; "
        f"RSS-growth ratio: {g['rss_delta_MB'] / max(a['rss_delta_MB'], 1e-9):.3f}; "
        f"max relative difference over {m} common taus: {rel:.2e}"
    )
    print(f"(input data itself: {a['data_MB']:.0f} MB, not counted)")


if __name__ == "__main__":
    main()
