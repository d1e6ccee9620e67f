"""Samples a device stamps with its own clock, as the rate stream's gap-free blocks.

A flight controller's IMU messages and a VN-100's packets each carry the device's time of
the sample, not a sequence number. :class:`StampedBlocks` puts them on the stream's
``sample_rate_hz`` grid from the first sample on (index = round((t − t₀)·rate)): a lost
sample is a jump in the index (a gap, counted in ``frames_lost``), a sample at an index
already passed — a repeated or late message — is dropped (``repeated``).
"""

from __future__ import annotations

import numpy as np

from gyrolab.instruments.roles import AdcBlock


class StampedBlocks:
    """The index state of one stream (module doc); ``period`` in seconds."""

    def __init__(self, period: float) -> None:
        self.period = float(period)
        self.t_first: float | None = None
        self.last_index = -1
        self.counts = {"frames_ok": 0, "frames_bad": 0, "frames_lost": 0, "repeated": 0}

    def blocks(
        self, t: np.ndarray, values: np.ndarray, temperature_c: np.ndarray
    ) -> list[AdcBlock]:
        """Samples at device times ``t`` (s) with their ``values`` (int32 counts, one row
        each) and temperatures (°C) → gap-free blocks, in order."""
        if t.size == 0:
            return []
        if self.t_first is None:
            self.t_first = float(t[0])
        idx = np.rint((np.asarray(t, dtype=np.float64) - self.t_first) / self.period)
        idx = idx.astype(np.int64)
        keep = idx > self.last_index
        keep[1:] &= idx[1:] > np.maximum.accumulate(idx)[:-1]
        self.counts["repeated"] += int(np.count_nonzero(~keep))
        idx, values, temperature_c = idx[keep], values[keep], temperature_c[keep]
        out = []
        cuts = np.flatnonzero(np.diff(idx) != 1) + 1
        for a, b in zip([0, *cuts], [*cuts, idx.size], strict=True):
            if b <= a:
                continue
            first = int(idx[a])
            self.counts["frames_lost"] += max(0, first - self.last_index - 1)
            out.append(
                AdcBlock(
                    first_seq=first,
                    first_index=first,
                    t0=self.t_first + first * self.period,
                    period=self.period,
                    counts=values[a:b],
                    temperature_c=temperature_c[a:b],
                    samples_per_reading=1,
                )
            )
            self.last_index = int(idx[b - 1])
        self.counts["frames_ok"] += int(idx.size)
        return out
