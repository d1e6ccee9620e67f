"""Static gyro noise with the structure a real MEMS record has and the simulator's noise
terms lack, for testing the discrepancy workflow on data it was not built from.

A real static record is not white + ideal 1/f (issue 18): its spectrum has bumps (a
mechanical or loop resonance), its values sit on an output lattice, and it carries
correlated structure at long τ. :func:`reallike_noise` sums

* white rate noise of density N (°/√h, per-sample σ = (N/60)·√f_s);
* flicker with Allan floor B (°/h), spectrum shaped by FFT: S(f) = B²/(2 ln 2 · f);
* a resonance: white noise through a two-pole resonator at ``bump_hz`` (pole radius
  0.98), scaled to ``bump_ratio`` × the white σ — a hump in the Allan curve below 1 s;
* a first-order Gauss–Markov process (σ = ``gm_ratio`` × B, correlation time
  ``gm_tau_s``) — a hump at τ ≈ 2 T_c that no power law fits;

With the defaults the Allan deviation at 100–1000 s is that of the simulator's nominal
noise (0.27–0.31 °/h against 0.27–0.33 °/h on a 13 h record at 10 Hz), with a hump near
1 s and one at a few hundred seconds where the simulator's curve is flat. The module
then quantizes the sum to ``lattice_q`` (°/s) the way a digital-output gyro does when it
adds its bias correction *after* the quantizer (:func:`digital_output`), so the lattice
shows in the first differences only. Everything is deterministic given the generator.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter


@dataclass(frozen=True)
class RealLike:
    """Parameters of a real-like static noise record (module docstring)."""

    n_arw: float = 0.0523  # °/√h, as the simulator's nominal arw
    b_floor: float = 0.2  # °/h: with the Gauss–Markov hump, the nominal 0.25 °/h level
    bump_hz: float = 1.7
    bump_ratio: float = 1.0
    gm_ratio: float = 0.6
    gm_tau_s: float = 400.0
    lattice_q: float = 0.0
    """Output step °/s (0: none); applied by :func:`digital_output`."""


def flicker(n: int, dt: float, b_floor_dps: float, rng: np.random.Generator) -> np.ndarray:
    """1/f noise with one-sided PSD ``B²/(2 ln 2 · f)`` (°/s, B in °/s), FFT-shaped over
    a record twice as long (cut in half: no circular wrap)."""
    m = 2 * n
    f = np.fft.rfftfreq(m, dt)
    amp = np.zeros_like(f)
    amp[1:] = np.sqrt(b_floor_dps**2 / (2.0 * math.log(2.0) * f[1:]))
    # white of unit one-sided PSD·… : X_k with E|X_k|² = S(f_k)·m/(2 dt)
    z = rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size)
    x = np.fft.irfft(z * amp * math.sqrt(m / (4.0 * dt)), m)
    return x[:n]


def reallike_noise(n: int, dt: float, rng: np.random.Generator, p: RealLike) -> np.ndarray:
    """A static record of ``n`` samples at interval ``dt`` (°/s), before the lattice."""
    sw = p.n_arw / 60.0 / math.sqrt(dt)
    x = sw * rng.standard_normal(n)
    if p.b_floor > 0:
        x += flicker(n, dt, p.b_floor / 3600.0, rng)
    f0 = min(p.bump_hz, 0.35 / dt)
    if p.bump_ratio > 0 and f0 > 0:
        r = 0.98
        w0 = 2.0 * math.pi * f0 * dt
        y = lfilter([1.0], [1.0, -2.0 * r * math.cos(w0), r * r], rng.standard_normal(n))
        x += p.bump_ratio * sw * y / np.std(y)
    if p.gm_ratio > 0:
        sg = p.gm_ratio * p.b_floor / 3600.0
        a = math.exp(-dt / p.gm_tau_s)
        e = rng.standard_normal(n) * sg * math.sqrt(1.0 - a * a)
        g, _ = lfilter([1.0], [1.0, -a], e, zi=[a * sg * rng.standard_normal()])
        x += g
    return x


def digital_output(p: RealLike, seed: int) -> Callable[[np.ndarray, float], np.ndarray]:
    """A post-transform for :func:`~gyrolab.sim.discrepancy.synth.simulate_bench`: the
    simulated (noise-free) rate plus a real-like noise record, the noise quantized to
    ``p.lattice_q`` before the deterministic part is added (a digital gyro's bias and
    temperature correction applied after its quantizer)."""

    def post(rate: np.ndarray, dt: float) -> np.ndarray:
        rng = np.random.default_rng([seed, 18])
        x = reallike_noise(rate.size, dt, rng, p)
        if p.lattice_q > 0:
            x = p.lattice_q * np.rint(x / p.lattice_q)
        return rate + x

    return post
