"""``gyroadc``: the gyro's ADC stream — framed 24-bit samples over a serial port
(pyserial) — as the bench's rate stream.

The frame format and the decoder are in :mod:`gyrolab.framing` (shared with the
simulated source); docs/instruments.md documents both. :class:`GyroAdcReader` adds the
port: reading, resynchronising (in the decoder), gap reporting, and reconnecting with
exponential backoff when the port disappears (USB adapter unplugged, pty closed);
:class:`GyroAdcStream` fills the :class:`~gyrolab.instruments.roles.RateStream` role with it.

Guarantees, in the order they are checked: a sample is passed on only inside a frame
whose sync word, length, CRC-16, sequence number and timestamp all check out; frames are
passed on in sequence order and at most once (a frame not newer than the last one passed
on is dropped, also across reconnects); every missing frame is reported as a
:class:`~gyrolab.framing.Gap` with its first sequence number and count.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import serial

from gyrolab.framing import FrameBatch, FrameDecoder
from gyrolab.instruments.registry import DriverSpec, OpenContext, register
from gyrolab.instruments.roles import AdcBlock, AdcEvent, AdcRead, InstrumentReport
from gyrolab.sampling import DEFAULT_RATE_HZ

NAME = "gyro ADC"


@dataclass(frozen=True)
class GyroAdcConfig:
    """``[rate_stream] driver = "gyroadc"``: the gyro's ADC stream and its conversion to °/s
    (``Ω = (V − offset)/gain``; docs/bench-config.md)."""

    driver: str = "gyroadc"
    port: str = ""  # "/dev/ttyUSB2"
    baud_rate: int = 921600
    sample_rate_hz: float = DEFAULT_RATE_HZ
    samples_per_frame: int = 10  # the ADC's frame length (docs/instruments.md)
    axes: int = 1  # values per sample (x, y, z), interleaved in each frame; 1..3
    bits: int = 24
    vref_v: float = 2.5
    gain_v_per_dps: float = 0.01  # gyro scale factor seen at the ADC input
    offset_v: float = 0.0
    block_s: float = 0.5  # samples per recorded block = block_s · rate (bounds crash loss)
    serial: str = ""
    # The unit's internal temperature sensor in every frame (docs/instruments.md, "Internal
    # temperature"): one int16 word, °C = temperature_zero_c + code · temperature_c_per_lsb.
    # Default scale: the ADIS16135's TEMP_OUT (0.0058 °C/LSB typical, 0 °C = 0x0000).
    internal_temperature: bool = False
    temperature_c_per_lsb: float = 0.0058
    temperature_zero_c: float = 0.0

    def dps_per_count(self) -> float:
        return self.vref_v / 2 ** (self.bits - 1) / self.gain_v_per_dps

    def to_dps(self, counts: Any) -> Any:
        """Counts → °/s with this calibration (works on numpy arrays)."""
        return (counts * (self.vref_v / 2 ** (self.bits - 1)) - self.offset_v) / self.gain_v_per_dps

    def to_celsius(self, codes: Any) -> Any:
        """Internal-temperature words → °C (``zero + code · c_per_lsb``; numpy arrays too)."""
        return self.temperature_zero_c + codes * self.temperature_c_per_lsb

    def check(self, safe_state_mode: str) -> None:
        """ValueError unless the stream's settings make sense."""
        if not (2 <= self.bits <= 32 and self.vref_v > 0 and self.gain_v_per_dps != 0):
            raise ValueError("needs 2 <= bits <= 32, vref_v > 0, gain_v_per_dps != 0")
        if not 1 <= self.samples_per_frame <= 4096:
            raise ValueError("samples_per_frame must be 1..4096")
        if not (1 <= self.axes <= 3 and self.samples_per_frame * self.axes <= 4096):
            raise ValueError("axes must be 1..3 with samples_per_frame·axes <= 4096")
        if not (self.temperature_c_per_lsb > 0 and math.isfinite(self.temperature_zero_c)):
            raise ValueError("temperature_c_per_lsb must be > 0, temperature_zero_c finite")


@dataclass
class ReaderStats:
    """Port-level counts; decoding counts are in ``decoder`` (a DecoderStats)."""

    disconnects: int = 0
    reconnects: int = 0
    open_failures: int = 0
    bytes_read: int = 0


class GyroAdcReader:
    """Reads and decodes the ADC stream from ``port``.

    ``samples_per_frame``, ``rate_hz`` (samples/s) and ``axes`` must match the ADC's
    configuration.
    ``read()`` returns whatever arrived since the last call (waiting up to ``timeout_s``
    for the first bytes). When the port fails, ``read()`` closes it, reports a
    ``disconnect`` event and from then on retries opening it every ``backoff`` seconds,
    doubling from ``backoff_initial_s`` to ``backoff_max_s``; frames lost meanwhile are
    reported as a gap with cause ``disconnect`` once data flows again.

    ``temperature`` = ``(zero_c, c_per_lsb)``: the frames carry the unit's internal
    temperature word (:mod:`gyrolab.framing`), delivered in °C with each block
    (``AdcBlock.temperature_c``, one reading per frame).
    """

    def __init__(
        self,
        port: str,
        *,
        samples_per_frame: int = 10,
        rate_hz: float = DEFAULT_RATE_HZ,
        axes: int = 1,
        temperature: tuple[float, float] | None = None,
        baudrate: int = 921600,
        backoff_initial_s: float = 0.05,
        backoff_max_s: float = 2.0,
        serial_factory: Callable[..., Any] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.port_name = port
        self.samples_per_frame = samples_per_frame
        self.rate_hz = float(rate_hz)
        self.period = 1.0 / self.rate_hz
        self.baudrate = baudrate
        self.backoff_initial_s = backoff_initial_s
        self.backoff_max_s = backoff_max_s
        self._factory = serial_factory or serial.Serial
        self._clock = clock
        self.axes = int(axes)
        self.temperature = temperature
        self.decoder = FrameDecoder(
            samples_per_frame, rate_hz, axes=self.axes, temperature=temperature is not None
        )
        self.stats = ReaderStats()
        self._ser: Any = None
        self._backoff = backoff_initial_s
        self._next_attempt = 0.0
        self._pending_events: list[AdcEvent] = []
        self.last_data_time: float | None = None  # clock() when bytes last arrived

    # ----------------------------------------------------------------- port
    @property
    def connected(self) -> bool:
        return self._ser is not None

    def open(self) -> None:
        """Open the port now; raises ``serial.SerialException`` if it cannot."""
        self._ser = self._factory(self.port_name, baudrate=self.baudrate, timeout=0.05)
        self._backoff = self.backoff_initial_s

    def close(self) -> None:
        if self._ser is not None:
            try:
                self._ser.close()
            except Exception:
                pass
            self._ser = None

    def __enter__(self) -> GyroAdcReader:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _event(self, kind: str, message: str, **data: Any) -> None:
        self._pending_events.append(AdcEvent(self._clock(), kind, message, data))

    def _lost_port(self, err: Exception) -> None:
        self.close()
        dropped = self.decoder.reset_stream("disconnect")
        self.stats.disconnects += 1
        self._backoff = self.backoff_initial_s
        self._next_attempt = self._clock() + self._backoff
        self._event(
            "disconnect",
            f"{self.port_name}: {err}",
            partial_bytes_dropped=dropped,
            last_seq=self.decoder.last_seq,
        )

    def _try_reopen(self) -> bool:
        now = self._clock()
        if now < self._next_attempt:
            return False
        try:
            self.open()
        except (serial.SerialException, OSError) as e:
            self.stats.open_failures += 1
            self._backoff = min(self._backoff * 2.0, self.backoff_max_s)
            self._next_attempt = now + self._backoff
            if self.stats.open_failures == 1 or self.stats.open_failures % 10 == 0:
                self._event("open_failed", f"{self.port_name}: {e}", retry_in_s=self._backoff)
            return False
        self.stats.reconnects += 1
        self._event("reconnect", f"{self.port_name} reopened", last_seq=self.decoder.last_seq)
        return True

    # ----------------------------------------------------------------- reading
    def read_bytes(self, timeout_s: float) -> bytes:
        """Bytes available now, waiting up to ``timeout_s`` for the first; b"" while
        disconnected (after at most ``timeout_s``, or the next reconnect attempt)."""
        if self._ser is None:
            deadline = self._clock() + timeout_s
            if not self._try_reopen():
                wait = min(self._next_attempt, deadline) - self._clock()
                if wait > 0:
                    time.sleep(wait)
                if not self._try_reopen():
                    return b""
        ser = self._ser
        try:
            if ser.timeout != timeout_s:  # pyserial re-applies termios on every set
                ser.timeout = timeout_s
            data = ser.read(max(1, ser.in_waiting))
            if data:
                more = ser.in_waiting  # take the rest without waiting again
                if more:
                    data += ser.read(more)
        except (serial.SerialException, OSError) as e:
            self._lost_port(e)
            return b""
        if data:
            self.stats.bytes_read += len(data)
            self.last_data_time = self._clock()
        return data

    def read(self, timeout_s: float = 0.1) -> AdcRead:
        """Decode whatever has arrived; see the class docstring."""
        data = self.read_bytes(timeout_s)
        out = AdcRead(events=self._pending_events)
        self._pending_events = []
        if data:
            self._split(self.decoder.feed(data), out)
        for g in out.gaps:
            out.events.append(
                AdcEvent(
                    self._clock(),
                    "gap",
                    f"{g.frames} frame(s) missing from seq {g.first_seq} ({g.cause})",
                    {"first_seq": g.first_seq, "frames": g.frames, "cause": g.cause},
                )
            )
        return out

    def _split(self, batch: FrameBatch, out: AdcRead) -> None:
        """Cut a batch into gap-free blocks."""
        if not len(batch):
            return
        spf = self.samples_per_frame
        cuts = sorted(batch.gaps_before)
        bounds = [0, *[c for c in cuts if c > 0], len(batch)]
        for c in cuts:
            out.gaps.append(batch.gaps_before[c])
        for a, b in zip(bounds[:-1], bounds[1:], strict=True):
            if b <= a:
                continue
            seq0 = int(batch.seq[a])
            temp = None
            if self.temperature is not None and batch.temperature_code is not None:
                zero_c, c_per_lsb = self.temperature
                temp = zero_c + batch.temperature_code[a:b].astype(np.float64) * c_per_lsb
            out.blocks.append(
                AdcBlock(
                    first_seq=seq0,
                    first_index=seq0 * spf,
                    t0=float(batch.timestamp_us[a]) * 1e-6,
                    period=self.period,
                    counts=(
                        batch.counts[a:b].reshape(-1)
                        if self.axes == 1
                        else batch.counts[a:b].reshape(-1, self.axes)
                    ),
                    temperature_c=temp,
                    samples_per_reading=spf if temp is not None else 0,
                )
            )


class GyroAdcStream(GyroAdcReader):
    """The ADC reader in the rate-stream role."""

    name = "adc"

    def __init__(self, port: str, *, config: GyroAdcConfig, **kw: Any) -> None:
        super().__init__(port, **kw)
        self.config = config

    def counters(self) -> dict[str, int]:
        d = self.decoder.stats
        s = self.stats
        return {
            "frames_ok": d.frames_ok,
            # Damaged frames: CRC failures, and CRC-passing frames whose timestamp
            # disagrees with their sequence number. (Length errors are mostly sync-word
            # look-alikes inside payloads, not frames.)
            "frames_bad": d.crc_errors + d.inconsistent_frames,
            "frames_lost": d.frames_lost,
            "frames_stale": d.stale_frames,
            "gaps": d.gaps,
            "disconnects": s.disconnects,
        }

    def reports(self) -> list[InstrumentReport]:
        return []  # the stream reports gaps and port events in its reads instead

    def describe(self) -> dict[str, Any]:
        a = self.config
        return {
            "driver": a.driver,
            "port": self.port_name,
            "serial": a.serial,
            "sample_rate_hz": a.sample_rate_hz,
            "samples_per_frame": a.samples_per_frame,
            "bits": a.bits,
            "vref_v": a.vref_v,
            "gain_v_per_dps": a.gain_v_per_dps,
            "offset_v": a.offset_v,
            "dps_per_count": a.dps_per_count(),
            # Only a multi-axis ADC says so: single-axis metadata stays as it always was.
            **({"axes": a.axes} if a.axes > 1 else {}),
            # Likewise only a stream that carries the internal temperature.
            **(
                {
                    "internal_temperature": True,
                    "temperature_c_per_lsb": a.temperature_c_per_lsb,
                    "temperature_zero_c": a.temperature_zero_c,
                }
                if a.internal_temperature
                else {}
            ),
        }


def open_adc(c: GyroAdcConfig, ctx: OpenContext) -> GyroAdcStream:
    reader = GyroAdcStream(
        ctx.address,
        config=c,
        samples_per_frame=c.samples_per_frame,
        rate_hz=c.sample_rate_hz,
        axes=c.axes,
        temperature=(
            (c.temperature_zero_c, c.temperature_c_per_lsb) if c.internal_temperature else None
        ),
        baudrate=c.baud_rate,
        clock=ctx.clock,
    )
    reader.open()
    return reader


SPEC = register(
    DriverSpec(
        name="gyroadc",
        role="rate_stream",
        config=GyroAdcConfig,
        open=open_adc,
        address_key="port",
        sim_backend="ADC",
        sim_address="adc_port",
        description="framed 24-bit ADC stream over a serial port",
    )
)
