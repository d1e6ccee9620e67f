"""Fault injection for the simulated bench.

Two kinds of fault:

- **random, per byte / per transaction** (:class:`ByteFaults`, :class:`ModbusFaults`):
  bytes of the ADC stream corrupted (XOR with a random non-zero byte) or dropped; Modbus
  replies turned into exception responses, given a wrong CRC, or withheld; all drawn
  from seeded generators, so a run's faults are reproducible;
- **scheduled** (:class:`FaultEvent`, at a simulated time or "now" through
  ``SimBench.inject``): ADC port disconnect (for ``duration_s``), ADC stall (no bytes for
  ``duration_s``, then the backlog in a burst), thermometer outage (no replies for
  ``duration_s``), SCPI errors pushed into the thermometer's error queue, bursts of
  ``count`` Modbus exception / CRC-error / no-reply responses, a chamber alarm (the
  chamber stops and reports it for ``duration_s``), and on a multi-unit bench a unit's
  PT100 channel open (the scanner reads overload on it for ``duration_s``).

The thermometer is the multimeter on a single-unit bench and the scanner on a multi-unit
bench (the instrument that reads the PT100s there).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

ADC_KINDS = ("disconnect", "stall")
DMM_KINDS = ("outage", "scpi_error")  # the bench's thermometer: multimeter or scanner
SCANNER_KINDS = ("open_channel",)  # multi-unit benches only
OVEN_KINDS = ("modbus_exception", "modbus_crc", "modbus_no_reply")
CHAMBER_KINDS = ("chamber_alarm",)  # the chamber's own alarm (F4: its limit controller)


@dataclass
class ByteFaults:
    """Random byte faults on a byte stream: each byte independently corrupted with
    probability ``corrupt_prob`` or dropped with probability ``drop_prob``."""

    corrupt_prob: float = 0.0
    drop_prob: float = 0.0
    seed: int = 0
    bytes_corrupted: int = 0
    bytes_dropped: int = 0

    def __post_init__(self) -> None:
        for p in (self.corrupt_prob, self.drop_prob):
            if not 0.0 <= p < 1.0:
                raise ValueError("fault probabilities must be in [0, 1)")
        self._rng = np.random.default_rng(self.seed)

    @property
    def active(self) -> bool:
        return self.corrupt_prob > 0 or self.drop_prob > 0

    def apply(self, data: bytes) -> tuple[bytes, bool]:
        """``(bytes as sent, damaged?)``."""
        if not self.active or not data:
            return data, False
        n = len(data)
        u = self._rng.random(n)
        corrupt = u < self.corrupt_prob
        drop = (u >= self.corrupt_prob) & (u < self.corrupt_prob + self.drop_prob)
        if not (corrupt.any() or drop.any()):
            return data, False
        a = np.frombuffer(data, dtype=np.uint8).copy()
        k = int(corrupt.sum())
        if k:
            a[corrupt] ^= self._rng.integers(1, 256, size=k, dtype=np.uint8)
            self.bytes_corrupted += k
        d = int(drop.sum())
        if d:
            a = a[~drop]
            self.bytes_dropped += d
        return a.tobytes(), True


@dataclass
class ModbusFaults:
    """Random faults on the oven's Modbus replies (probability per request)."""

    exception_prob: float = 0.0  # reply with exception code ``exception_code``
    crc_error_prob: float = 0.0  # reply with a wrong CRC
    no_reply_prob: float = 0.0  # say nothing (the master times out)
    exception_code: int = 0x06  # slave device busy
    seed: int = 0

    def __post_init__(self) -> None:
        self._rng = np.random.default_rng(self.seed)
        self._burst: list[str] = []

    def burst(self, kind: str, count: int) -> None:
        """Force the next ``count`` replies to be ``kind`` (one of OVEN_KINDS)."""
        if kind not in OVEN_KINDS:
            raise ValueError(f"unknown Modbus fault {kind!r}")
        self._burst.extend([kind] * count)

    def draw(self) -> str | None:
        """The fault for the next reply, or None."""
        if self._burst:
            return self._burst.pop(0)
        u = float(self._rng.random())
        if u < self.exception_prob:
            return "modbus_exception"
        u -= self.exception_prob
        if u < self.crc_error_prob:
            return "modbus_crc"
        u -= self.crc_error_prob
        if u < self.no_reply_prob:
            return "modbus_no_reply"
        return None


@dataclass(frozen=True)
class FaultEvent:
    """A scheduled fault. ``t_s`` is simulated time (None: as soon as injected).

    ``kind``: ``disconnect`` / ``stall`` (ADC, for ``duration_s``), ``outage`` (the
    thermometer — multimeter, or a multi-unit bench's scanner — silent for ``duration_s``),
    ``scpi_error`` (``detail`` pushed to the thermometer's error queue, e.g.
    ``-222,"Data out of range"``), ``modbus_exception`` / ``modbus_crc`` /
    ``modbus_no_reply`` (the next ``count`` oven replies), ``chamber_alarm`` (the chamber's
    alarm for ``duration_s``: it stops and says so), ``open_channel`` (a multi-unit
    bench's scanner reads overload on the unit's PT100 channel for ``duration_s``: a lead
    broken). ``unit``: on a multi-unit bench, the unit whose ADC a ``disconnect`` or
    ``stall`` hits, or whose PT100 an ``open_channel`` opens (0-based).
    """

    kind: str
    t_s: float | None = None
    duration_s: float = 0.0
    count: int = 1
    detail: str = ""
    unit: int = 0  # disconnect / stall / open_channel: which unit (0-based)

    def __post_init__(self) -> None:
        if self.kind not in ADC_KINDS + DMM_KINDS + OVEN_KINDS + SCANNER_KINDS + CHAMBER_KINDS:
            raise ValueError(f"unknown fault kind {self.kind!r}")
        if self.unit < 0:
            raise ValueError(f"unit must be >= 0, got {self.unit}")


@dataclass
class FaultPlan:
    """All faults of one simulated bench run."""

    adc: ByteFaults = field(default_factory=ByteFaults)
    oven: ModbusFaults = field(default_factory=ModbusFaults)
    events: list[FaultEvent] = field(default_factory=list)
