"""The gyro ADC's binary frame: encoder, streaming decoder and CRC-16/CCITT.

Shared by the driver (``gyrolab.instruments.drivers.gyroadc``) and the simulated ADC source
(``gyrolab.sim.bench.adc_source``); it lives at package level so that ``sim`` never
imports ``acquisition``. docs/instruments.md is the reference for the format.

Frame layout (all multi-byte fields little-endian except the CRC)::

    offset  size  field
    0       2     sync word, bytes A5 5A
    2       2     length L = 12 + 3·n·a: bytes from ``seq`` to the last sample
    4       4     seq, uint32 frame counter (+1 per frame, wraps at 2**32)
    8       8     timestamp, uint64 µs of the ADC's clock at the frame's first sample
    16      3·n·a n samples of a axes, 24-bit two's complement, little-endian, interleaved
                  sample by sample (x0 y0 z0 x1 y1 z1 …)
    16+3na  2     CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF) over bytes 2..15+3na, big-endian

``a`` is the ADC's axis count (1–3, part of its configuration like n; a single-axis ADC,
a = 1, sends exactly the frames it always did). A frame of n samples is 18 + 3·n·a bytes
(48 bytes for the default n = 10, a = 1).

An ADC configured to carry the unit's internal temperature (``temperature=True``, like n
and a a setting both ends share) inserts one word before the CRC: at offset 16 + 3·n·a,
2 bytes, the gyro's temperature register as it read it at the frame's first sample,
int16 two's complement little-endian (its scale is the part's: docs/instruments.md). Such a
frame is 20 + 3·n·a bytes and L = 14 + 3·n·a; the CRC covers the word. Without the option
the frames are byte for byte those above.

The decoder accepts a frame only if the sync word, the length (it must be the configured
n), the CRC, the sequence number (strictly newer than the last accepted frame) and the
timestamp (consistent with the sequence step at the nominal rate) all agree. After any
failure it resumes the search one byte after the failed sync word, so an intact frame
that follows a damaged one is never lost. Damaged frames are never passed on: they show
up as gaps in the sequence numbers, which the decoder reports.
"""

from __future__ import annotations

import struct
from binascii import crc_hqx
from dataclasses import dataclass, field

import numpy as np

SYNC = b"\xa5\x5a"
HEADER_SIZE = 16  # sync + length + seq + timestamp
CRC_SIZE = 2
TEMP_SIZE = 2  # the optional internal-temperature word (int16 LE) before the CRC
MAX_SAMPLES = 4096
SEQ_MOD = 1 << 32
_HEAD = struct.Struct("<2sHIQ")
_SEQ_TS = struct.Struct("<IQ")


def crc16_ccitt(data: bytes | bytearray | memoryview, init: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0).

    ``binascii.crc_hqx`` is this CRC with a caller-given initial value, in C.
    Check value: ``crc16_ccitt(b"123456789") == 0x29B1``.
    """
    return crc_hqx(data, init)


def frame_size(samples_per_frame: int, axes: int = 1, temperature: bool = False) -> int:
    """Bytes on the wire of one frame of ``samples_per_frame`` samples of ``axes`` axes
    (and the internal-temperature word when ``temperature``)."""
    extra = TEMP_SIZE if temperature else 0
    return HEADER_SIZE + 3 * samples_per_frame * axes + extra + CRC_SIZE


def encode_frame(
    seq: int, timestamp_us: int, counts: np.ndarray, temperature_code: int | None = None
) -> bytes:
    """One frame; ``counts`` are signed 24-bit values (−8388608 … 8388607), ``(n,)`` for one
    axis or ``(n, axes)`` for several (sent interleaved, sample by sample);
    ``temperature_code``, when given, the int16 internal-temperature word."""
    words = None if temperature_code is None else [int(temperature_code)]
    return encode_frame_run(seq, [int(timestamp_us)], np.asarray(counts)[None], words)[0]


_HEAD_DTYPE = np.dtype([("sync", "S2"), ("length", "<u2"), ("seq", "<u4"), ("ts", "<u8")])


def encode_frame_run(
    seq0: int,
    timestamps_us: np.ndarray,
    counts: np.ndarray,
    temperature_codes: np.ndarray | None = None,
) -> list[bytes]:
    """Frames ``seq0, seq0+1, …`` at once, byte for byte :func:`encode_frame`'s:
    ``counts`` is ``(frames, n)`` for one axis or ``(frames, n, axes)``,
    ``temperature_codes`` one int16 word per frame or None. The fields of every frame are
    laid out with numpy in one pass; only the CRC is computed frame by frame (in C)."""
    c = np.asarray(counts, dtype=np.int64)
    k = c.shape[0]
    c = c.reshape(k, -1)
    n = c.shape[1]
    if not 1 <= n <= MAX_SAMPLES:
        raise ValueError(f"a frame holds 1..{MAX_SAMPLES} samples, not {n}")
    if k and (c.min() < -(1 << 23) or c.max() >= 1 << 23):
        raise ValueError("sample outside the signed 24-bit range")
    payload = (c & 0xFFFFFF).astype("<u4").view(np.uint8).reshape(k, n, 4)[:, :, :3]
    parts = [np.zeros((k, HEADER_SIZE), np.uint8), payload.reshape(k, 3 * n)]
    if temperature_codes is not None:
        t = np.asarray(temperature_codes, dtype=np.int64)
        if t.size and (t.min() < -(1 << 15) or t.max() >= 1 << 15):
            raise ValueError("temperature word outside the int16 range")
        parts.append(t.astype("<i2").view(np.uint8).reshape(k, 2))
    body = np.concatenate(parts, axis=1)
    head = body[:, :HEADER_SIZE].view(_HEAD_DTYPE).reshape(k)
    head["sync"] = SYNC
    head["length"] = body.shape[1] - 4
    head["seq"] = (seq0 + np.arange(k, dtype=np.int64)) % SEQ_MOD
    head["ts"] = np.asarray(timestamps_us, dtype=np.int64)
    rows = [r.tobytes() for r in body]
    return [r + crc_hqx(memoryview(r)[2:], 0xFFFF).to_bytes(2, "big") for r in rows]


def encode_frames(seq0: int, timestamps_us: np.ndarray, counts: np.ndarray) -> list[bytes]:
    """Frames ``seq0, seq0+1, …`` from a (frames × samples) array of counts."""
    return encode_frame_run(seq0, timestamps_us, np.atleast_2d(counts))


def decode_int24(raw: bytes | bytearray | memoryview) -> np.ndarray:
    """Little-endian 24-bit two's-complement samples → int32 array."""
    b = np.frombuffer(raw, dtype=np.uint8).reshape(-1, 3).astype(np.int32)
    v = b[:, 0] | (b[:, 1] << 8) | (b[:, 2] << 16)
    return (v ^ 0x800000) - 0x800000


@dataclass(frozen=True)
class Gap:
    """Frames that never arrived intact, between two accepted frames.

    ``first_seq`` is the first missing frame (unwrapped, 64-bit), ``frames`` how many.
    ``cause`` is ``"lost"`` (damaged or dropped on the wire), ``"disconnect"`` (the port
    went away meanwhile) or ``"restart"`` (the source's counter jumped; re-anchored).
    """

    first_seq: int
    frames: int
    cause: str = "lost"


@dataclass
class DecoderStats:
    """Running counts of a :class:`FrameDecoder` (since construction)."""

    frames_ok: int = 0  # accepted and passed on
    crc_errors: int = 0  # sync + length right, CRC wrong
    length_errors: int = 0  # sync found, length not the configured one
    stale_frames: int = 0  # valid CRC but not newer than the last accepted (duplicates)
    inconsistent_frames: int = 0  # valid CRC but timestamp disagrees with seq
    frames_lost: int = 0  # sum of all gaps
    gaps: int = 0
    bytes_in: int = 0
    bytes_discarded: int = 0  # skipped while hunting for a sync word
    restarts: int = 0


@dataclass
class FrameBatch:
    """Frames accepted by one :meth:`FrameDecoder.feed` call, in order.

    ``seq`` are unwrapped (64-bit) frame numbers, ``timestamp_us`` the device clock,
    ``counts`` a (frames × samples_per_frame) int32 array. ``gaps_before[k]`` is the
    :class:`Gap` just before frame ``k`` (or absent). ``temperature_code``: each frame's
    int16 internal-temperature word (None unless the decoder expects one).
    """

    seq: np.ndarray
    timestamp_us: np.ndarray
    counts: np.ndarray
    gaps_before: dict[int, Gap] = field(default_factory=dict)
    temperature_code: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.seq.size)


class FrameDecoder:
    """Streaming decoder: feed it bytes in any chunking, get intact frames out.

    ``samples_per_frame`` is the ADC's configured n and ``axes`` its axis count (frames
    of another length are rejected; ``counts`` come back as (frames × n·axes), each row
    interleaved x0 y0 z0 x1 …). ``rate_hz`` (samples/s), when given, makes the decoder also
    check that a frame's timestamp advanced by ``Δseq · n / rate_hz`` (± 1 frame + 1 %), which
    catches the rare random byte run that passes a 16-bit CRC. ``temperature``: the frames
    carry the internal-temperature word (module doc); frames without it are rejected by
    their length, and the other way round.
    """

    def __init__(
        self,
        samples_per_frame: int,
        rate_hz: float | None = None,
        *,
        restart_after: int = 4,
        axes: int = 1,
        temperature: bool = False,
    ) -> None:
        if not 1 <= samples_per_frame <= MAX_SAMPLES:
            raise ValueError(f"samples_per_frame must be 1..{MAX_SAMPLES}")
        if not 1 <= axes <= 3 or samples_per_frame * axes > MAX_SAMPLES:
            raise ValueError(f"axes must be 1..3 with n·axes <= {MAX_SAMPLES}")
        self.n = samples_per_frame
        self.axes = axes
        self.temperature = bool(temperature)
        self.size = frame_size(samples_per_frame, axes, self.temperature)
        self.length = self.size - 6  # bytes from seq through the last sample (or word)
        self.frame_us = None if rate_hz is None else samples_per_frame / rate_hz * 1e6
        self.restart_after = restart_after
        self.stats = DecoderStats()
        self._buf = bytearray()
        self._last_seq: int | None = None  # unwrapped, as passed on
        self._last_dev = 0  # the same frame's 32-bit number on the wire
        self._last_ts: int = 0
        self._cause = "lost"
        # Valid frames that disagree with the current anchor: if enough of them agree with
        # each other the source restarted, and we re-anchor on them.
        self._candidates: list[tuple[int, int]] = []

    @property
    def last_seq(self) -> int | None:
        """Unwrapped number of the last accepted frame (None before the first)."""
        return self._last_seq

    def reset_stream(self, cause: str = "disconnect") -> int:
        """Drop the partial frame in the buffer (the port closed); keep the sequence
        anchor so that the next gap is reported with ``cause``. Returns bytes dropped."""
        dropped = len(self._buf)
        self.stats.bytes_discarded += dropped
        self._buf.clear()
        self._cause = cause
        return dropped

    def _consistent(self, dseq: int, ts: int, last_ts: int) -> bool:
        dts = ts - last_ts
        if dts <= 0:
            return False
        if self.frame_us is None:
            return True
        want = dseq * self.frame_us
        return abs(dts - want) <= self.frame_us + 0.01 * want

    def feed(self, data: bytes | bytearray | memoryview) -> FrameBatch:
        """Append ``data`` and return every frame that is now complete and intact."""
        buf = self._buf
        buf += data
        st = self.stats
        st.bytes_in += len(data)
        length, size, n = self.length, self.size, self.n * self.axes
        seqs: list[int] = []
        tss: list[int] = []
        raw = bytearray()
        temps: list[int] = []
        tw = TEMP_SIZE if self.temperature else 0
        gaps: dict[int, Gap] = {}
        mv = memoryview(buf)
        pos = 0
        nbuf = len(buf)
        try:
            while True:
                i = buf.find(SYNC, pos)
                if i < 0:
                    # Keep a trailing A5: it may be the first half of the next sync word.
                    keep = 1 if nbuf and buf[-1] == 0xA5 else 0
                    st.bytes_discarded += nbuf - keep - pos
                    pos = nbuf - keep
                    break
                st.bytes_discarded += i - pos
                if nbuf - i < 4:
                    pos = i
                    break
                if buf[i + 2] | (buf[i + 3] << 8) != length:
                    st.length_errors += 1
                    st.bytes_discarded += 1
                    pos = i + 1
                    continue
                end = i + size
                if nbuf < end:
                    pos = i
                    break
                if crc_hqx(mv[i + 2 : end - 2], 0xFFFF) != (buf[end - 2] << 8) | buf[end - 1]:
                    st.crc_errors += 1
                    st.bytes_discarded += 1
                    pos = i + 1
                    continue
                seq, ts = _SEQ_TS.unpack_from(buf, i + 4)
                last = self._last_seq
                if last is None:
                    useq = seq
                else:
                    dseq = (seq - self._last_dev) % SEQ_MOD
                    if (
                        dseq == 0
                        or dseq >= SEQ_MOD // 2
                        or not self._consistent(dseq, ts, self._last_ts)
                    ):
                        if dseq == 0 or dseq >= SEQ_MOD // 2:
                            st.stale_frames += 1
                        else:
                            st.inconsistent_frames += 1
                        if self._restart_candidate(seq, ts):
                            useq = last + 1 + self._restart_gap_frames(ts)
                            gaps[len(seqs)] = Gap(last + 1, useq - last - 1, "restart")
                            st.restarts += 1
                            if useq - last - 1:
                                st.gaps += 1
                                st.frames_lost += useq - last - 1
                            self._candidates.clear()
                        else:
                            pos = end  # a valid frame, just not one to pass on
                            continue
                    else:
                        useq = last + dseq
                        if dseq > 1:
                            gaps[len(seqs)] = Gap(last + 1, dseq - 1, self._cause)
                            st.gaps += 1
                            st.frames_lost += dseq - 1
                        self._candidates.clear()
                self._last_seq = useq
                self._last_dev = seq
                self._last_ts = ts
                self._cause = "lost"
                seqs.append(useq)
                tss.append(ts)
                raw += mv[i + 16 : end - 2 - tw]
                if tw:
                    temps.append(int.from_bytes(buf[end - 4 : end - 2], "little", signed=True))
                pos = end
        finally:
            mv.release()
        del buf[:pos]
        st.frames_ok += len(seqs)
        counts = decode_int24(raw).reshape(-1, n) if raw else np.empty((0, n), dtype=np.int32)
        return FrameBatch(
            np.asarray(seqs, dtype=np.int64),
            np.asarray(tss, dtype=np.int64),
            counts,
            gaps,
            np.asarray(temps, dtype=np.int16) if tw else None,
        )

    def _restart_candidate(self, seq: int, ts: int) -> bool:
        """Record a valid frame that disagrees with the anchor; True once
        ``restart_after`` of them form a consistent run (the source restarted)."""
        c = self._candidates
        if c:
            pseq, pts = c[-1]
            d = (seq - pseq) % SEQ_MOD
            if not (0 < d < SEQ_MOD // 2 and self._consistent(d, ts, pts)):
                c.clear()
        c.append((seq, ts))
        return len(c) >= self.restart_after

    def _restart_gap_frames(self, ts: int) -> int:
        """Frames missed across a restart, estimated from the timestamps (0 if unknown)."""
        if self.frame_us is None or ts <= self._last_ts:
            return 0
        return max(0, round((ts - self._last_ts) / self.frame_us) - 1)
