"""Noise cut from real static gyro records (benchmarks/data/README.md: five ADIS16405
records, 3 axes, 2.78 h each at 10 Hz means).

A run needs more than one record: :func:`real_noise` concatenates pieces of randomly
chosen records and axes (each with its own mean removed, so the joins carry no step;
a random sign; randomly time-reversed — the statistics of stationary noise are
unchanged by either), then scales the whole to the unit's ARW, measured on the pooled
records as σ of 1 s means × 60 (the white-noise line at τ = 1 s: the ADIS16405's own
filter acts below 0.1 s). What is kept of the real record is everything its ARW scaling
does not change: the shape of its Allan curve — flicker, the Gauss–Markov humps,
drifts of hours — which no synthetic generator here imitates.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[1] / "data" / "adis16405_static_10hz.npz"


@lru_cache(maxsize=4)
def records(path: str = str(DATA)) -> tuple[np.ndarray, float]:
    """(k, n) records in °/s at 10 Hz (every record × axis, mean removed), and their
    ARW (°/√h, σ of 1 s means × 60, pooled). Any ``.npz`` with ``sums`` (records × n ×
    axes) and ``lsb_deg_per_s``, or ``rate`` (records × n) in °/s, at 10 Hz, may stand
    in for the project's file (``--noise`` of break_suite.py)."""
    d = np.load(path)
    if "sums" in d:
        a = d["sums"].astype(float) * float(d["lsb_deg_per_s"])
        a = np.moveaxis(a, 2, 1).reshape(-1, a.shape[1])
    else:
        a = np.atleast_2d(np.asarray(d["rate"], dtype=float))
    a = a - a.mean(axis=1, keepdims=True)
    n1 = a.shape[1] // 10
    s1 = a[:, : n1 * 10].reshape(a.shape[0], n1, 10).mean(axis=2)
    arw = float(np.sqrt(np.mean(np.var(s1, axis=1))) * 60.0)
    return a, arw


def real_noise(n: int, arw: float, rng: np.random.Generator, path: str = str(DATA)) -> np.ndarray:
    """``n`` samples (10 Hz, °/s) of real record noise scaled to ARW ``arw`` (°/√h)."""
    a, arw0 = records(path)
    out = np.empty(n)
    i = 0
    while i < n:
        k = int(rng.integers(a.shape[0]))
        r = a[k]
        start = int(rng.integers(0, max(1, r.size // 2)))
        piece = r[start:]
        piece = piece - piece.mean()
        if rng.uniform() < 0.5:
            piece = piece[::-1]
        if rng.uniform() < 0.5:
            piece = -piece
        m = min(piece.size, n - i)
        out[i : i + m] = piece[:m]
        i += m
    return out * (arw / arw0)
