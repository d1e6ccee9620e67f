"""Simulated gyro ADC: frames the physics' counts and streams them over a pty.

Frame ``k`` carries samples ``k·n … k·n + n − 1`` (n = samples per frame) of the physics'
sample index, so its sequence number *is* its position in the run and its timestamp is
``k·n / rate_hz`` in µs. A source with ``temperature`` adds each frame's
internal-temperature word (the unit's die sensor,
:meth:`gyrolab.sim.physics.Physics.die_sensor_codes`). The source keeps, on request, the
truth of every frame it produced — its samples and what happened to it on the way out —
so tests can check the driver against it.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np

from gyrolab.framing import encode_frame_run, frame_size
from gyrolab.sim.bench.faults import ByteFaults
from gyrolab.sim.bench.serial_pty import PortClosed, PtyPort

# What happened to a frame on its way out
SENT = "sent"  # written intact
DAMAGED = "damaged"  # written with corrupted and/or dropped bytes
UNPLUGGED = "unplugged"  # produced while the port was disconnected: never written
OVERRUN = "overrun"  # the reader did not drain the pty in time: cut short


@dataclass
class AdcTruth:
    """Every frame the source produced, in order (only if ``keep_truth``)."""

    seq: list[int] = field(default_factory=list)
    counts: list[np.ndarray] = field(default_factory=list)
    status: list[str] = field(default_factory=list)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(seq, counts[frames, n], status)`` as numpy arrays."""
        return (
            np.asarray(self.seq, dtype=np.int64),
            np.asarray(self.counts, dtype=np.int32),
            np.asarray(self.status),
        )


@dataclass
class SourceStats:
    frames: int = 0
    sent: int = 0
    damaged: int = 0
    unplugged: int = 0
    overrun: int = 0
    bytes_written: int = 0


class AdcSource:
    """Streams physics blocks as frames on ``port`` (see module doc)."""

    def __init__(
        self,
        port: PtyPort,
        *,
        samples_per_frame: int,
        rate_hz: float,
        axes: int = 1,
        temperature: bool = False,
        faults: ByteFaults | None = None,
        keep_truth: bool = False,
        write_timeout_s: float = 0.5,
    ) -> None:
        self.port = port
        self.n = int(samples_per_frame)
        self.rate_hz = float(rate_hz)
        self.faults = faults or ByteFaults()
        self.keep_truth = keep_truth
        self.truth = AdcTruth()
        self.stats = SourceStats()
        self.write_timeout_s = write_timeout_s
        self._stall_backlog: list[tuple[int, bytes]] | None = None
        self._lock = threading.Lock()
        self.axes = int(axes)
        self.temperature = bool(temperature)  # frames carry the internal-temperature word
        self._frame_bytes = frame_size(self.n, self.axes, self.temperature)

    # ----------------------------------------------------------------- faults
    def start_stall(self) -> None:
        """Stop sending; frames produced meanwhile are held (the device's FIFO)."""
        with self._lock:
            if self._stall_backlog is None:
                self._stall_backlog = []

    def end_stall(self) -> None:
        """Send the held frames in one burst and carry on."""
        with self._lock:
            backlog, self._stall_backlog = self._stall_backlog, None
        if backlog:
            self._write([b for _, b in backlog], [i for i, _ in backlog])

    def unplug(self) -> None:
        self.port.disconnect()

    def replug(self) -> None:
        self.port.connect()

    # ----------------------------------------------------------------- output
    def emit(
        self, first_index: int, counts: np.ndarray, temperature_codes: np.ndarray | None = None
    ) -> None:
        """Frame and send samples ``first_index …`` (a whole number of frames); ``counts``
        is ``(samples,)`` for one axis or ``(samples, axes)``, sent interleaved;
        ``temperature_codes`` (a source with ``temperature``): one word per frame."""
        if self.temperature != (temperature_codes is not None):
            raise ValueError("temperature_codes: one per frame exactly when temperature=True")
        n = self.n
        if first_index % n or len(counts) % n:
            raise ValueError("blocks must hold whole frames, aligned on frame boundaries")
        shape = (-1, n) if self.axes == 1 else (-1, n, self.axes)
        c = np.clip(counts, -(1 << 23), (1 << 23) - 1).reshape(shape)
        seq0 = first_index // n
        frames: list[bytes] = []
        slots: list[int] = []
        # every frame of the block laid out at once (the bench's largest cost per tick)
        stamps = [round(seq * n * 1e6 / self.rate_hz) for seq in range(seq0, seq0 + c.shape[0])]
        raws = encode_frame_run(seq0, np.asarray(stamps, dtype=np.int64), c, temperature_codes)
        for k, raw in enumerate(raws):
            seq = seq0 + k
            wire, damaged = self.faults.apply(raw)
            self.stats.frames += 1
            slot = -1
            if self.keep_truth:
                slot = len(self.truth.seq)
                self.truth.seq.append(seq)
                self.truth.counts.append(c[k].astype(np.int32))
                self.truth.status.append(DAMAGED if damaged else SENT)
            if damaged:
                self.stats.damaged += 1
            frames.append(wire)
            slots.append(slot)
        with self._lock:
            if self._stall_backlog is not None:
                self._stall_backlog.extend(zip(slots, frames, strict=True))
                return
        self._write(frames, slots)

    def _mark(self, slots: list[int], status: str) -> None:
        for s in slots:
            if s >= 0 and self.truth.status[s] == SENT:
                self.truth.status[s] = status
            elif s >= 0 and status == UNPLUGGED:
                self.truth.status[s] = status

    def _write(self, frames: list[bytes], slots: list[int]) -> None:
        data = b"".join(frames)
        if not self.port.connected:
            self.stats.unplugged += len(frames)
            self._mark(slots, UNPLUGGED)
            return
        try:
            # a UART transmits regardless: while nobody drains the port the wait is capped
            done = self.port.write_capped(data, self.write_timeout_s)
        except PortClosed:
            self.stats.unplugged += len(frames)
            self._mark(slots, UNPLUGGED)
            return
        self.stats.bytes_written += done
        if done < len(data):
            # Frames from the one cut short onward never made it out whole.
            pos = 0
            for k, f in enumerate(frames):
                if pos + len(f) > done:
                    self.stats.overrun += len(frames) - k
                    self._mark(slots[k:], OVERRUN)
                    break
                pos += len(f)
        self.stats.sent = self.stats.frames - self.stats.damaged - self.stats.unplugged
