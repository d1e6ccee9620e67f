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
import time
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
from gyrolab.record.metadata import BenchMetadata, RunMetadata

LIBRARY = f"gyrolab {__version__}"  # the MCAP header's library string


def json_strings(values: Mapping[str, Any]) -> dict[str, str]:
    """An MCAP metadata record's string map: non-string values as JSON text."""
    return {
        k: v if isinstance(v, str) else json.dumps(v, sort_keys=True) for k, v in values.items()
    }


class McapFile:
    """An MCAP file written record by record: chunked (``chunk_size`` bytes), compressed
    (``"zstd"``, ``"lz4"`` or ``"none"``), with message indexes and a summary, so seeking
    readers open it directly, and with all three MCAP CRCs (chunks, data section, summary).
    Schema and channel ids are this file's own (1, 2, …)."""

    def __init__(
        self,
        fh: IO[bytes],
        *,
        profile: str = PROFILE,
        library: str = LIBRARY,
        chunk_size: int = 1 << 20,
        compression: str = "zstd",
    ) -> None:
        from mcap.writer import CompressionType, Writer

        comp = {
            "zstd": CompressionType.ZSTD,
            "lz4": CompressionType.LZ4,
            "none": CompressionType.NONE,
        }
        # enable_data_crcs: the data section's CRC-32 in the DataEnd record, so that a reader
        # can check the bytes no chunk CRC covers (metadata records, the header):
        # gyrolab/record/integrity.py
        self._w = Writer(
            fh, chunk_size=chunk_size, compression=comp[compression], enable_data_crcs=True
        )
        self._w.start(profile=profile, library=library)

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        return int(self._w.register_schema(name, encoding, data))

    def register_channel(
        self,
        topic: str,
        message_encoding: str,
        schema_id: int,
        metadata: Mapping[str, str] | None = None,
    ) -> int:
        return int(
            self._w.register_channel(topic, message_encoding, schema_id, dict(metadata or {}))
        )

    def add_message(
        self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int
    ) -> None:
        self._w.add_message(
            channel_id, log_time=log_time, data=data, publish_time=publish_time, sequence=sequence
        )

    def add_metadata(self, name: str, values: Mapping[str, str]) -> None:
        self._w.add_metadata(name, dict(values))

    def flush(self) -> None:
        """Close the open chunk (written to the file object, not yet to the OS)."""
        self._w.flush()

    def finish(self) -> None:
        """Write the last chunk, the summary and the footer."""
        self._w.finish()


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
        self._last_fsync_wall = time.monotonic()
        self.flush_count = 0
        self.fsync_count = 0
        self._seq: dict[str, int] = {}
        self._chan: dict[str, int] = {}
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
    def _put(self, topic: str, t: float, data: bytes) -> None:
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
            # a Message record: opcode 1 + length 8 + channel 2 + sequence 4 + 2 times 16
            self._buf_bytes[g] += 31 + len(data)
            if self._buf_bytes[g] > self.chunk_size:
                self._write_group(g)
        if self.tap is not None:
            try:
                self.tap(topic, ts, data)
            except Exception:  # noqa: BLE001 - the recording comes first
                pass
        if self.flush_every_s is not None and t - self._last_flush_t >= self.flush_every_s:
            self.flush()
            self._last_flush_t = t

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
        self._put(topic, t, json.dumps(msg, separators=(",", ":")).encode())

    def stamp(self, t: float) -> dict[str, int]:
        """``{sec, nsec}`` Unix time of run time ``t`` (the viewers' time type)."""
        ns = self.start_time_ns + int(round(t * 1e9))
        return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}

    def _write_group(self, g: str | None) -> None:
        """Write group ``g``'s buffered messages as one chunk of their own (multi-unit)."""
        buf = self._buf[g]
        if not buf:
            return
        for chan, ts, data, seq in buf:
            self._w.add_message(chan, log_time=ts, data=data, publish_time=ts, sequence=seq)
        self._w.flush()  # closes the chunk: it holds this group's messages only
        self._buf[g], self._buf_bytes[g] = [], 0

    def flush(self) -> None:
        """Close the open chunk(s) and push them to the OS (and to disk when ``fsync``)."""
        for g in self._buf:  # multi-unit: every unit's buffer, then the shared topics'
            self._write_group(g)
        self._w.flush()
        self._fh.flush()
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
        name = unit_topic(topic, unit)
        if name not in self._chan:
            raise ValueError(f"unit {unit!r} is not one of this recording's {self.units}")
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
            self._unit(TOPIC_ADC, unit), t0, encode_block(t0, period, first_index, counts, "adc")
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
        )
        r = np.asarray(rate_dps, dtype=np.float32).astype(np.float64)  # what the block holds
        if r.size:
            n = r.shape[0]
            tm = t0 + 0.5 * (n - 1) * period
            x = r if r.ndim == 1 else r[:, 0]  # the summary's own fields: axis x
            summary = {
                "header": {
                    "stamp": self.stamp(tm),
                    "frame_id": "gyro" if unit is None else f"gyro/{unit}",
                },
                "t": tm,
                "t0": t0,
                "first_index": int(first_index),
                "n": int(n),
                "mean_dps": float(x.mean()),
                "min_dps": float(x.min()),
                "max_dps": float(x.max()),
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
