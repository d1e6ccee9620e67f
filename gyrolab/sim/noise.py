"""Noise generators that stream block by block: seeded streams and 1/f (flicker) noise.

Every stochastic effect draws from its own generator, seeded from ``(seed, crc32(name),
occurrence)``, so adding or removing one effect never changes another's draws. numpy's
``Generator`` fills arrays sequentially, so drawing n then m values equals drawing n + m:
the output does not depend on how a run is cut into blocks.

Flicker noise (Kasdin 1995, "Discrete simulation of colored noise and stochastic processes
and 1/f^α power law noise generation", Proc. IEEE 83(5), §IV): white noise ``w_k`` of
variance ``Q_d`` through the fractional-difference filter of α = 1,

    x_n = Σ_{k=0}^{L−1} h_k w_{n−k},   h_0 = 1,   h_k = h_{k−1} (α/2 + k − 1) / k,

has the one-sided PSD ``S(f) ≈ Q_d / (π f)`` (independent of the sample rate), so its Allan
deviation is flat at ``σ² = 2 ln 2 · Q_d / π`` (IEEE 952-1997, Annex C: flicker rate noise
``S = h₋₁ / f`` gives ``σ² = 2 ln 2 · h₋₁``). For an Allan floor ``B``:
``Q_d = π B² / (2 ln 2)``.

It is generated at a decimated rate ``fs_d`` (10 Hz) by overlap-save FFT convolution in
chunks of ``M`` samples with a filter of ``L = nfft − M + 1`` taps (25 h at 10 Hz: the 1/f
law holds down to 1/(25 h), longer than the paper's 13 h run), and linearly interpolated to
the ADC's sample times. Above fs_d/2 the flicker is negligible beside the white rate noise.
The white history starts at zero at power-on (Kasdin's construction), so memory is one
chunk plus the filter, whatever the run's length.

A chunk costs two 2²⁰-point FFTs (about 0.1–0.3 s). The simulated bench must not spend
that inside its physics lock, so :meth:`FlickerStream.prefetch` lets another thread make
the next chunk ahead of time (numpy's FFT releases the GIL). Chunks are always made in
order from the one generator, whichever thread makes them, so the noise is bit-identical
with or without prefetching.
"""

from __future__ import annotations

import math
import threading
import zlib
from typing import Any

import numpy as np


def effect_rng(seed: int, name: str, occurrence: int = 0) -> np.random.Generator:
    """A generator private to one effect instance (seed, effect name, occurrence)."""
    key = [int(seed) % (1 << 63), zlib.crc32(name.encode()), int(occurrence)]
    return np.random.default_rng(np.random.SeedSequence(key))


def kasdin_coefficients(n: int, alpha: float = 1.0) -> np.ndarray:
    """``h_k`` of Kasdin's 1/f^α fractional-difference filter, ``k = 0..n−1``."""
    k = np.arange(1, n, dtype=float)
    h = np.empty(n)
    h[0] = 1.0
    h[1:] = np.cumprod((alpha / 2.0 + k - 1.0) / k)
    return h


class FlickerStream:
    """1/f rate noise with Allan floor ``floor`` (same units as the output), streamed.

    ``value_at(index, rate_hz)`` returns the noise at ADC sample indices (times
    ``index / rate_hz``), generating decimated chunks as time moves on and dropping the
    ones behind. Requests must not go back before the previous request's start.
    ``value_at`` is for one consumer thread; :meth:`prefetch` may run in another.
    """

    def __init__(
        self,
        floor: float,
        rng: np.random.Generator,
        fs_d: float = 10.0,
        nfft: int = 1 << 20,
        chunk: int = 1 << 17,
    ) -> None:
        self.fs_d = float(fs_d)
        self.m = int(chunk)
        self.nfft = int(nfft)
        self.taps = self.nfft - self.m + 1
        self.sigma_w = math.sqrt(math.pi * floor * floor / (2.0 * math.log(2.0)))
        self._rng = rng
        self._h_f = np.fft.rfft(kasdin_coefficients(self.taps), self.nfft)
        self._hist = np.zeros(self.taps - 1)
        self._chunks: dict[int, np.ndarray] = {}
        self._next = 0  # the next chunk to make
        self._init_locks()

    def _init_locks(self) -> None:
        # _gen serializes chunk making (generator, history, _next): held for a whole chunk.
        # _dict guards _chunks only, for microseconds, so that the consumer never waits
        # for a chunk it does not need.
        self._gen = threading.Lock()
        self._dict = threading.Lock()

    def __getstate__(self) -> dict[str, Any]:  # copy/deepcopy/pickle: locks are not state
        state = self.__dict__.copy()
        del state["_gen"], state["_dict"]
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._init_locks()

    def _make_chunk(self) -> None:
        """Make chunk ``_next`` (caller holds ``_gen``)."""
        w = self._rng.standard_normal(self.m) * self.sigma_w
        seq = np.concatenate([self._hist, w])
        y = np.fft.irfft(np.fft.rfft(seq, self.nfft) * self._h_f, self.nfft)
        with self._dict:
            self._chunks[self._next] = y[self.taps - 1 : self.taps - 1 + self.m]
        self._hist = seq[self.m :]
        self._next += 1

    def _ensure(self, c: int) -> None:
        """Make chunks up to ``c`` inclusive (waits for one being made elsewhere)."""
        if c < self._next:
            return
        with self._gen:
            while c >= self._next:
                self._make_chunk()

    def _chunk_of(self, index: int, rate_hz: float) -> int:
        """The last chunk ``value_at`` needs for ADC sample ``index``."""
        return (int(math.floor(index * (self.fs_d / rate_hz))) + 1) // self.m

    def prefetch(self, first_index: int, n: int, rate_hz: float) -> None:
        """Make now the chunks that ``value_at(first_index, n, rate_hz)`` would need.

        Thread-safe against ``value_at`` in another thread; the result is unchanged."""
        if n > 0:
            self._ensure(self._chunk_of(first_index + n - 1, rate_hz))

    def _decimated(self, k0: int, k1: int) -> np.ndarray:
        """Decimated samples k0..k1 inclusive."""
        c0, c1 = k0 // self.m, k1 // self.m
        with self._dict:
            for old in [k for k in self._chunks if k < c0]:  # time only moves forward
                del self._chunks[old]
        self._ensure(c1)
        with self._dict:
            parts = [self._chunks[c] for c in range(c0, c1 + 1)]
        seq = parts[0] if len(parts) == 1 else np.concatenate(parts)
        off = c0 * self.m
        return seq[k0 - off : k1 - off + 1]

    def value_at(self, first_index: int, n: int, rate_hz: float) -> np.ndarray:
        """Noise at the samples ``first_index .. first_index + n − 1`` of a ``rate_hz`` ADC."""
        if n <= 0:
            return np.empty(0)
        pos = (first_index + np.arange(n)) * (self.fs_d / rate_hz)
        k0 = int(math.floor(pos[0]))
        k1 = int(math.floor(pos[-1])) + 1
        seq = self._decimated(k0, k1)
        j = np.floor(pos).astype(np.int64)
        frac = pos - j
        j -= k0
        return seq[j] * (1.0 - frac) + seq[j + 1] * frac
