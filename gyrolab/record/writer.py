"""The one MCAP writer of gyrolab: :class:`McapFile` (records as they are) and
:class:`RecordingWriter` (one run in the recording format, docs/recording-format.md).

Every MCAP file gyrolab writes — a run (``simulate``, ``acquire``), a compensated copy
(:mod:`gyrolab.record.rewrite`, ``gyrolab apply``), a salvaged one
(:mod:`gyrolab.record.recover`) — goes through :class:`McapFile`, so chunking,
compression and the header's library string are chosen here once.
"""

from __future__ import annotations

import json
import os
import struct
import time
import zlib
from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import IO, Any

import numpy as np

from gyrolab import __version__
from gyrolab.record.blocks import encode_block
from gyrolab.record.format import (
    FORMAT_VERSION,
    FOXGLOVE_LOG_LEVEL,
    PROFILE,
    TOPIC_ADC,
    TOPIC_EVENT,
    TOPIC_LOG,
    TOPIC_LOG_FOXGLOVE,
    TOPIC_OVEN,
    TOPIC_PT100,
    TOPIC_RATE,
    TOPIC_RATE_SUMMARY,
    TOPIC_TEMPERATURE_INTERNAL,
    check_serial,
    recording_channels,
    unit_topic,
)
from gyrolab.record.integrity import (
    MAGIC,
    OP_CHANNEL,
    OP_CHUNK,
    OP_DATA_END,
    OP_FOOTER,
    OP_HEADER,
    OP_MESSAGE,
    OP_METADATA,
    OP_SCHEMA,
)
from gyrolab.record.metadata import BenchMetadata, RunMetadata

LIBRARY = f"gyrolab {__version__}"  # the MCAP header's library string
# json.dumps(msg, separators=(",", ":")) without a new encoder per message
_COMPACT_JSON = json.JSONEncoder(separators=(",", ":"))


def json_strings(values: Mapping[str, Any]) -> dict[str, str]:
    """An MCAP metadata record's string map: non-string values as JSON text."""
    return {
        k: v if isinstance(v, str) else json.dumps(v, sort_keys=True) for k, v in values.items()
    }


class McapFile:
    """An MCAP file written record by record: chunked (``chunk_size`` bytes), compressed
    (``"zstd"``, ``"lz4"`` or ``"none"``), with message indexes and a summary (schemas,
    channels, statistics, chunk and metadata indexes, summary offsets), so seeking readers
    open it directly, and with all three MCAP CRCs (chunks, data section, summary).
    Schema and channel ids are this file's own (1, 2, …).

    The records are built here (https://mcap.dev/spec), byte for byte what the ``mcap``
    library's ``Writer`` (1.x, ``enable_data_crcs=True``) writes for the same calls —
    ``tests/test_mcap_file.py`` compares whole files — but each message record is one
    ``struct`` call and every chunk is compressed by one reused zstd context: the library's
    per-record Python and its new context per chunk were most of a multi-unit run's
    recording CPU (docs/performance.md, ``benchmarks/bench_mcap_write.py``). As in the
    library, schema and channel records go into the next chunk written (and always into
    the summary), and a metadata record is written at once, outside any chunk."""

    def __init__(
        self,
        fh: IO[bytes],
        *,
        profile: str = PROFILE,
        library: str = LIBRARY,
        chunk_size: int = 1 << 20,
        compression: str = "zstd",
    ) -> None:
        if compression == "zstd":
            import zstandard

            # level 3: zstandard.compress's (the library's) default, so the bytes match
            self._compress: Callable[[bytes], bytes] = zstandard.ZstdCompressor(level=3).compress
        elif compression == "lz4":
            import lz4.frame

            self._compress = lz4.frame.compress
        elif compression == "none":
            self._compress = bytes
        else:
            raise ValueError(f"compression must be zstd, lz4 or none, not {compression!r}")
        self._fh = fh
        self._compression = "" if compression == "none" else compression
        self._comp_str = _string(self._compression)
        self.chunk_size = chunk_size
        self._pos = fh.tell()  # where the next record goes (offsets in indexes are absolute)
        self._data_crc = 0  # the data section's CRC-32 (DataEnd): every byte before it
        self._schemas: list[bytes] = []  # records, in id order (repeated in the summary)
        self._channels: list[bytes] = []
        self._chunk_indexes: list[bytes] = []
        self._metadata_indexes: list[bytes] = []
        self._counts: dict[int, int] = {}  # messages per channel, in first-message order
        self._messages = 0
        self._t_min = self._t_max = 0
        self._metadata = 0
        # the open chunk: its records, per channel its (log time, offset) index entries
        self._chunk = bytearray()
        self._index: dict[int, list[int]] = {}
        self._c_min = self._c_max = 0
        self._c_messages = 0
        self._write(MAGIC + _record(OP_HEADER, _string(profile) + _string(library)))

    def _write(self, data: bytes) -> None:
        """Data-section bytes: written, counted and added to the data CRC."""
        self._fh.write(data)
        self._pos += len(data)
        self._data_crc = zlib.crc32(data, self._data_crc)

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        sid = len(self._schemas) + 1
        body = _H.pack(sid) + _string(name) + _string(encoding) + _I.pack(len(data)) + data
        rec = _record(OP_SCHEMA, body)
        self._schemas.append(rec)
        self._chunk += rec
        self._maybe_close()
        return sid

    def register_channel(
        self,
        topic: str,
        message_encoding: str,
        schema_id: int,
        metadata: Mapping[str, str] | None = None,
    ) -> int:
        cid = len(self._channels) + 1
        body = _HH.pack(cid, schema_id) + _string(topic) + _string(message_encoding)
        rec = _record(OP_CHANNEL, body + _string_map(metadata or {}))
        self._channels.append(rec)
        self._chunk += rec
        self._maybe_close()
        return cid

    def add_message(
        self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int
    ) -> None:
        self.add_messages([(channel_id, log_time, data, sequence)], publish_time - log_time)

    def add_messages(
        self, messages: list[tuple[int, int, bytes, int]], publish_offset: int = 0
    ) -> None:
        """Messages ``(channel, log time, data, sequence)`` in this order into the open
        chunk (each message's publish time is its log time + ``publish_offset``); the
        chunk is closed whenever it passes ``chunk_size``, as after each single message."""
        chunk, index, counts, head = self._chunk, self._index, self._counts, _MESSAGE_RECORD.pack
        for chan, ts, data, seq in messages:
            if self._c_messages:
                if ts < self._c_min:
                    self._c_min = ts
                elif ts > self._c_max:
                    self._c_max = ts
            else:
                self._c_min = self._c_max = ts
            entries = index.get(chan)
            if entries is None:
                entries = index[chan] = []
            entries += (ts, len(chunk))
            counts[chan] = counts.get(chan, 0) + 1
            chunk += head(OP_MESSAGE, 22 + len(data), chan, seq, ts, ts + publish_offset)
            chunk += data
            self._c_messages += 1
            if len(chunk) > self.chunk_size:
                self.close_chunk()
                chunk, index = self._chunk, self._index

    def add_metadata(self, name: str, values: Mapping[str, str]) -> None:
        rec = _record(OP_METADATA, _string(name) + _string_map(values))
        self._metadata_indexes.append(
            _record(OP_METADATA_INDEX, _QQ.pack(self._pos, len(rec)) + _string(name))
        )
        self._metadata += 1
        self._write(rec)

    def _maybe_close(self) -> None:
        if len(self._chunk) > self.chunk_size:
            self.close_chunk()

    def close_chunk(self) -> None:
        """Write the open chunk (if it holds a message), its message indexes and keep its
        chunk index; schema/channel records alone wait for the next chunk."""
        if not self._c_messages:
            return
        raw = bytes(self._chunk)
        packed = self._compress(raw)
        start, end = self._c_min, self._c_max
        rec = b"".join(
            (
                _CHUNK_HEAD.pack(OP_CHUNK, 36 + len(self._comp_str) + len(packed), start, end),
                _QI.pack(len(raw), zlib.crc32(raw)),
                self._comp_str,
                _Q.pack(len(packed)),
                packed,
            )
        )
        at = self._pos + len(rec)
        offsets, indexes = [], []
        for chan, entries in self._index.items():
            offsets.append(_HQ.pack(chan, at))
            n = len(entries) // 2
            mi = _MINDEX_HEAD.pack(OP_MESSAGE_INDEX, 6 + 16 * n, chan, 16 * n)
            mi += struct.pack(f"<{2 * n}Q", *entries)
            indexes.append(mi)
            at += len(mi)
        mindex = b"".join(indexes)
        self._chunk_indexes.append(
            _record(
                OP_CHUNK_INDEX,
                b"".join(
                    (
                        _QQQQ.pack(start, end, self._pos, len(rec)),
                        _I.pack(10 * len(offsets)),
                        *offsets,
                        _Q.pack(len(mindex)),
                        self._comp_str,
                        _QQ.pack(len(packed), len(raw)),
                    )
                ),
            )
        )
        if self._messages:
            self._t_min = min(self._t_min, start)
            self._t_max = max(self._t_max, end)
        else:
            self._t_min, self._t_max = start, end
        self._messages += self._c_messages
        self._write(rec + mindex)
        self._chunk = bytearray()
        self._index = {}
        self._c_messages = 0

    def flush(self) -> None:
        """Close the open chunk (written to the file object, not yet to the OS)."""
        self.close_chunk()
        self._fh.flush()

    def finish(self) -> None:
        """Write the last chunk, the summary and the footer."""
        self.close_chunk()
        self._write(_record(OP_DATA_END, _I.pack(self._data_crc)))
        summary_start = self._pos
        counts = b"".join(_HQ.pack(c, n) for c, n in self._counts.items())
        stats = _record(
            OP_STATISTICS,
            _Q.pack(self._messages)
            + struct.pack(
                "<HIIII",
                len(self._schemas),
                len(self._channels),
                0,  # attachments: gyrolab writes none
                self._metadata,
                len(self._chunk_indexes),
            )
            + _QQ.pack(self._t_min, self._t_max)
            + _I.pack(len(counts))
            + counts,
        )
        groups = [
            (OP_SCHEMA, b"".join(self._schemas)),
            (OP_CHANNEL, b"".join(self._channels)),
            (OP_STATISTICS, stats),
            (OP_CHUNK_INDEX, b"".join(self._chunk_indexes)),
            (OP_ATTACHMENT_INDEX, b""),
            (OP_METADATA_INDEX, b"".join(self._metadata_indexes)),
        ]
        at, offsets = summary_start, []
        for op, data in groups:
            offsets.append(_record(OP_SUMMARY_OFFSET, _BQQ.pack(op, at, len(data))))
            at += len(data)
        summary = b"".join([g for _, g in groups] + offsets)
        tail = _FOOTER_HEAD.pack(OP_FOOTER, 20, summary_start, at)
        self._fh.write(summary + tail + _I.pack(zlib.crc32(tail, zlib.crc32(summary))) + MAGIC)


_H, _I, _Q = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
_HH, _HQ, _QI = struct.Struct("<HH"), struct.Struct("<HQ"), struct.Struct("<QI")
_QQ, _BQQ, _QQQQ = struct.Struct("<QQ"), struct.Struct("<BQQ"), struct.Struct("<QQQQ")
_RECORD_HEAD = struct.Struct("<BQ")  # opcode, body length
_MESSAGE_RECORD = struct.Struct("<BQHIQQ")  # head, channel, sequence, log and publish time
_MINDEX_HEAD = struct.Struct("<BQHI")  # head, channel, entries' byte length
_CHUNK_HEAD = struct.Struct("<BQQQ")  # head, message start and end time
_FOOTER_HEAD = struct.Struct("<BQQQ")  # head, summary start, summary offset start
OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_ATTACHMENT_INDEX = 0x07, 0x08, 0x0A
OP_STATISTICS, OP_METADATA_INDEX, OP_SUMMARY_OFFSET = 0x0B, 0x0D, 0x0E


def _record(op: int, body: bytes) -> bytes:
    return _RECORD_HEAD.pack(op, len(body)) + body


def _string(s: str) -> bytes:
    b = s.encode()
    return _I.pack(len(b)) + b


def _string_map(values: Mapping[str, str]) -> bytes:
    body = b"".join(_string(k) + _string(v) for k, v in values.items())
    return _I.pack(len(body)) + body


class RecordingWriter:
    """Writes one run to MCAP.

    ``stream`` is a path or a binary file object. ``start_time_ns`` is the Unix time of
    the run's start; every message's ``t`` is relative to it. ``run`` and ``bench`` are
    written as the MCAP metadata records of those names (nested values as JSON text): the
    producers pass :class:`~gyrolab.record.metadata.RunMetadata` and
    :class:`~gyrolab.record.metadata.BenchMetadata`; a plain mapping is written as given.
    ``flush_every_s`` (simulated/run seconds) bounds what a crash can lose: the open
    chunk is closed and the file flushed (and fsynced when ``fsync``) at least that often.

    Crash-loss policy (docs/reliability.md): a flush closes the open chunk (a complete,
    CRC-checked MCAP chunk record) and hands it to the OS with ``write``; from then on a
    ``kill -9`` of the process cannot lose it, and ``gyrolab recover`` salvages it from a
    file that never got its footer. ``fsync_every_s`` (wall seconds) additionally bounds
    what a power cut can lose: a flush fsyncs when that much wall time has passed since the
    last fsync (``fsync=True`` fsyncs on every flush). :meth:`maybe_flush` lets a caller
    whose streams went quiet apply the same rule on its own clock.

    Multi-unit layout (``units``): every chunk holds one unit's messages, or only the shared
    topics', so that reading one unit decompresses only its own chunks (not all U units'
    data, which made a fleet cost O(U²) to read). Each group's messages are buffered up to
    ``chunk_size`` and written as one chunk; chunks of different groups overlap in time.
    A flush writes every group's buffer, so the crash-loss bound above holds for all.
    """

    def __init__(
        self,
        stream: str | os.PathLike[str] | IO[bytes],
        *,
        start_time_ns: int,
        run: RunMetadata | Mapping[str, Any] | None = None,
        bench: BenchMetadata | Mapping[str, Any] | None = None,
        chunk_size: int = 1 << 20,
        compression: str = "zstd",
        flush_every_s: float | None = None,
        fsync: bool = False,
        fsync_every_s: float | None = None,
        units: list[str] | None = None,
        internal_temperature: list[str] | tuple[str, ...] = (),
    ) -> None:
        self._own = not hasattr(stream, "write")
        self._fh: IO[bytes] = open(stream, "wb") if self._own else stream  # type: ignore[arg-type]
        # Multi-unit: this class closes every chunk (one group's buffer each), never mcap's
        # Writer, whose size rule would mix groups; single-unit: mcap's rule, as always.
        inner_size = chunk_size if units is None else 1 << 62
        self._w = McapFile(self._fh, chunk_size=inner_size, compression=compression)
        self.start_time_ns = int(start_time_ns)
        self.flush_every_s = flush_every_s
        self.fsync = fsync
        self.fsync_every_s = fsync_every_s
        self._last_flush_t = 0.0
        # Block topics (ADC, rate): run time their data reaches, written / handed to the OS.
        self._put_to: dict[str, float] = {}
        self._flushed_to: dict[str, float] = {}
        self._mates: dict[str | None, list[str]] = {}  # unit -> its block topics seen
        self._last_fsync_wall = time.monotonic()
        self.flush_count = 0
        self.fsync_count = 0
        self._seq: dict[str, int] = {}
        self._chan: dict[str, int] = {}
        self._names: dict[tuple[str, str | None], str] = {}  # (topic, unit) -> channel topic
        self.chunk_size = chunk_size
        # multi-unit chunk groups: topic -> group (a serial, or None for the shared topics);
        # per group the buffered (channel, log_time, data, sequence) and their record bytes
        self._group: dict[str, str | None] = {}
        self._buf: dict[str | None, list[tuple[int, int, bytes, int]]] = {}
        self._buf_bytes: dict[str | None, int] = {}
        self._closed = False
        #: ``tap(topic, log_time_ns, data)`` sees every message after it is recorded (the
        #: live view, gyrolab/acquisition/live.py); must not block. Its errors are ignored:
        #: a viewer never endangers the recording.
        self.tap: Callable[[str, int, bytes], None] | None = None
        # None: the single-unit layout; a list of serials: the multi-unit layout
        self.units = None if units is None else [check_serial(u) for u in units]
        if self.units is not None and (not self.units or len(set(self.units)) != len(units)):
            raise ValueError(f"units must be distinct serials, got {units}")
        if self.units is not None:
            for g in [*self.units, None]:
                self._buf[g], self._buf_bytes[g] = [], 0
        # A unit on its internal temperature sensor has its own topic, only in files that
        # have such a unit (every other file is byte for byte what it was before).
        bad = [u for u in internal_temperature if u not in (self.units or [])]
        if bad:
            raise ValueError(f"internal_temperature: {bad} are not units of this recording")
        self.internal_temperature = tuple(internal_temperature)
        # One schema record per schema, in first-use order (ids as files always had them).
        schema_ids: dict[str, int] = {}
        for c in recording_channels(self.units, self.internal_temperature):
            sid = schema_ids.get(c.schema_name)
            if sid is None:
                sid = self._w.register_schema(c.schema_name, c.schema_encoding, c.schema_data)
                schema_ids[c.schema_name] = sid
            self._chan[c.topic] = self._w.register_channel(c.topic, c.message_encoding, sid)
            self._group[c.topic] = c.unit
        if isinstance(run, RunMetadata):  # the producers: the typed schema
            if self.units is not None:
                run = replace(run, units=list(self.units))
            meta_run = run.to_dict()
        else:  # a hand-made record (tests, foreign tools): written as given
            meta_run = {"format_version": FORMAT_VERSION, "software_version": __version__}
            if self.units is not None:
                meta_run["units"] = list(self.units)
            meta_run.update(run or {})
        self.write_metadata("run", meta_run)
        self.write_metadata(
            "bench", bench.to_dict() if isinstance(bench, BenchMetadata) else bench or {}
        )

    # -- low level
    def _put(self, topic: str, t: float, data: bytes, t_end: float | None = None) -> None:
        """Add one message stamped ``t``; a block's ``t_end`` is where its data ends."""
        if self._closed:
            raise RuntimeError("recording is closed")
        seq = self._seq.get(topic, 0)
        self._seq[topic] = seq + 1
        ts = self.start_time_ns + int(round(t * 1e9))
        if self.units is None:
            self._w.add_message(
                self._chan[topic], log_time=ts, data=data, publish_time=ts, sequence=seq
            )
        else:
            g = self._group[topic]
            self._buf[g].append((self._chan[topic], ts, data, seq))
            # a Message record: opcode 1 + length 8 + channel 2 + sequence 4 + 2 times 8
            size = self._buf_bytes[g] + 31 + len(data)
            self._buf_bytes[g] = size
            if size > self.chunk_size:
                self._write_group(g)
        if self.tap is not None:
            try:
                self.tap(topic, ts, data)
            except Exception:  # noqa: BLE001 - the recording comes first
                pass
        fe = self.flush_every_s
        if fe is None:
            return
        if t_end is not None and self._block_due(topic, t, t_end, fe):
            self.flush()
            # a flush like the others: the clock rules count from it (from where the data
            # reaches, not the block's start: else the loop's next turn flushes again)
            self._last_flush_t = max(self._last_flush_t, t_end)
            return
        if t - self._last_flush_t >= fe:
            self.flush()
            self._last_flush_t = t

    def _block_due(self, topic: str, t: float, t_end: float, fe: float) -> bool:
        """Whether a block ending at ``t_end`` must be flushed now. A block is stamped with
        its start, other messages on arrival, which is later: the stamp rule alone can leave
        several blocks unflushed behind a message that arrived after them. So a unit's
        block topics (its ADC and rate blocks, written in pairs) keep their own account:
        their data not yet handed to the OS never spans more than ``flush_every_s``
        (docs/reliability.md). Checked once a pair is complete, so that the rate block
        written just after its ADC block does not flush a second time."""
        self._put_to[topic] = t_end
        self._flushed_to.setdefault(topic, t)
        mates = self._mates.setdefault(self._group[topic], [])  # the channel's unit
        if topic not in mates:
            mates.append(topic)
        ends = [self._put_to[m] for m in mates]
        if max(ends) - min(ends) > 1e-6:  # a pair half written
            return False
        return t_end - min(self._flushed_to[m] for m in mates) > fe * (1 + 1e-9)

    def maybe_flush(self, t: float) -> bool:
        """Flush if ``flush_every_s`` of run time passed since the last flush; True if done."""
        if self._closed or self.flush_every_s is None:
            return False
        if t - self._last_flush_t >= self.flush_every_s:
            self.flush()
            self._last_flush_t = t
            return True
        return False

    def _json(self, topic: str, msg: Mapping[str, Any], t: float | None = None) -> None:
        t = float(msg["t"]) if t is None else t
        self._put(topic, t, _COMPACT_JSON.encode(msg).encode())

    def stamp(self, t: float) -> dict[str, int]:
        """``{sec, nsec}`` Unix time of run time ``t`` (the viewers' time type)."""
        ns = self.start_time_ns + int(round(t * 1e9))
        return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}

    def _write_group(self, g: str | None) -> None:
        """Write group ``g``'s buffered messages as one chunk of their own (multi-unit)."""
        buf = self._buf[g]
        if not buf:
            return
        self._w.add_messages(buf)
        self._w.close_chunk()  # it holds this group's messages only
        self._buf[g], self._buf_bytes[g] = [], 0

    def flush(self) -> None:
        """Close the open chunk(s) and push them to the OS (and to disk when ``fsync``)."""
        for g in self._buf:  # multi-unit: every unit's buffer, then the shared topics'
            self._write_group(g)
        self._w.flush()
        self._fh.flush()
        self._flushed_to.update(self._put_to)
        self.flush_count += 1
        now = time.monotonic()
        if self.fsync or (
            self.fsync_every_s is not None and now - self._last_fsync_wall >= self.fsync_every_s
        ):
            os.fsync(self._fh.fileno())
            self._last_fsync_wall = now
            self.fsync_count += 1

    # -- records
    def write_metadata(self, name: str, values: Mapping[str, Any]) -> None:
        """A metadata record; non-string values are stored as JSON text."""
        self._w.add_metadata(name, json_strings(values))

    def _unit(self, topic: str, unit: str | None) -> str:
        """The channel of ``topic`` for ``unit`` (which a multi-unit recording requires)."""
        if (unit is None) != (self.units is None):
            raise ValueError(
                "a multi-unit recording needs unit=SERIAL"
                if unit is None
                else "unit= is for multi-unit recordings (RecordingWriter(units=...))"
            )
        name = self._names.get((topic, unit))
        if name is None:
            name = unit_topic(topic, unit)
            if name not in self._chan:
                raise ValueError(f"unit {unit!r} is not one of this recording's {self.units}")
            self._names[(topic, unit)] = name  # checked once: every block asks again
        return name

    def write_adc_block(
        self,
        t0: float,
        period: float,
        first_index: int,
        counts: np.ndarray,
        unit: str | None = None,
    ) -> None:
        self._put(
            self._unit(TOPIC_ADC, unit),
            t0,
            encode_block(t0, period, first_index, counts, "adc"),
            t0 + len(counts) * period,
        )

    def write_rate_block(
        self,
        t0: float,
        period: float,
        first_index: int,
        rate_dps: np.ndarray,
        unit: str | None = None,
    ) -> None:
        """One ``/gyro/rate`` block: ``(n,)`` for a single axis, ``(n, axes)`` for 2–3."""
        self._put(
            self._unit(TOPIC_RATE, unit),
            t0,
            encode_block(t0, period, first_index, rate_dps, "rate"),
            t0 + len(rate_dps) * period,
        )
        r = np.asarray(rate_dps, dtype=np.float32).astype(np.float64)  # what the block holds
        if r.size:
            n = r.shape[0]
            tm = t0 + 0.5 * (n - 1) * period
            x = r if r.ndim == 1 else r[:, 0]  # the summary's own fields: axis x
            # the ufuncs' reductions: x.mean(), x.min(), x.max() without numpy's wrappers
            # (the same numbers; one summary per block and unit)
            summary = {
                "header": {
                    "stamp": self.stamp(tm),
                    "frame_id": "gyro" if unit is None else f"gyro/{unit}",
                },
                "t": tm,
                "t0": t0,
                "first_index": int(first_index),
                "n": int(n),
                "mean_dps": float(np.add.reduce(x)) / n,
                "min_dps": float(np.minimum.reduce(x)),
                "max_dps": float(np.maximum.reduce(x)),
            }
            if r.ndim > 1:  # several axes: every axis too, x first
                summary["axes_mean_dps"] = [float(v) for v in r.mean(axis=0)]
                summary["axes_min_dps"] = [float(v) for v in r.min(axis=0)]
                summary["axes_max_dps"] = [float(v) for v in r.max(axis=0)]
            self._json(
                self._unit(TOPIC_RATE_SUMMARY, unit), summary, t0
            )  # log time = the block's, like /gyro/rate

    def write_pt100(
        self, t: float, resistance_ohm: float, temperature_c: float, unit: str | None = None
    ) -> None:
        self._json(
            self._unit(TOPIC_PT100, unit),
            {
                "t": t,
                "resistance_ohm": float(resistance_ohm),
                "temperature_c": float(temperature_c),
            },
        )

    def write_internal_temperature(
        self, t: float, temperature_c: float, readings: int, unit: str
    ) -> None:
        """One ``/unit/<serial>/temperature/internal`` message (the writer's
        ``internal_temperature`` units only): the mean of ``readings`` sensor readings."""
        name = unit_topic(TOPIC_TEMPERATURE_INTERNAL, unit)
        if name not in self._chan:
            raise ValueError(f"unit {unit!r} was not declared internal_temperature")
        self._json(name, {"t": t, "temperature_c": float(temperature_c), "readings": int(readings)})

    def write_oven(self, t: float, setpoint_c: float, process_value_c: float, mode: str) -> None:
        self._json(
            TOPIC_OVEN,
            {
                "t": t,
                "setpoint_c": float(setpoint_c),
                "process_value_c": float(process_value_c),
                "mode": mode,
            },
        )

    def write_event(
        self,
        t: float,
        event: str,
        step: int = -1,
        setpoint_c: float | None = None,
        detail: str = "",
    ) -> None:
        msg: dict[str, Any] = {"t": t, "event": event, "step": int(step), "detail": detail}
        if setpoint_c is not None:
            msg["setpoint_c"] = float(setpoint_c)
        self._json(TOPIC_EVENT, msg)

    def write_log(
        self,
        t: float,
        level: str,
        source: str,
        message: str,
        kind: str = "",
        data: Mapping[str, Any] | None = None,
    ) -> None:
        msg: dict[str, Any] = {"t": t, "level": level, "source": source, "message": message}
        if kind:
            msg["kind"] = kind
        if data:
            msg["data"] = dict(data)
        self._json(TOPIC_LOG, msg)
        fox = {
            "timestamp": self.stamp(t),
            "level": FOXGLOVE_LOG_LEVEL.get(level, 0),
            "message": f"[{kind}] {message}" if kind else message,
            "name": source,
            "file": "",
            "line": 0,
        }
        self._json(TOPIC_LOG_FOXGLOVE, fox, t)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        for g in self._buf:
            self._write_group(g)
        self._w.finish()
        self._fh.flush()
        if self.fsync or self.fsync_every_s is not None:
            os.fsync(self._fh.fileno())
        if self._own:
            self._fh.close()

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
