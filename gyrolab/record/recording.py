"""The MCAP recording format: topics, schemas, a writer and a streaming reader.

One run is one MCAP file (docs/recording-format.md is the reference). High-rate gyro
streams are batched: one Protobuf message per block of samples carrying the block's first
timestamp, the sample period and the index of its first sample (so gaps are explicit).
Low-rate channels are JSON with a JSON Schema. Both are MCAP well-known encodings, so any
MCAP reader (Foxglove, the ``mcap`` CLI, ``@mcap/core``) opens the file.

Times inside messages are seconds since the run's start (``t``/``t0``); the MCAP
``log_time`` is ``start_time_ns + t·1e9`` (Unix epoch, ns).

The Protobuf payloads are encoded and decoded here by hand (packed fixed-width fields are
raw little-endian arrays), which keeps a 47 M-sample run at numpy speed; the
FileDescriptorSet stored as the schema lets generic readers decode them too.
"""

from __future__ import annotations

import json
import os
import re
import struct
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from gyrolab.errors import InputError

TOPIC_ADC = "/gyro/adc"
TOPIC_RATE = "/gyro/rate"
TOPIC_PT100 = "/temperature/pt100"
TOPIC_OVEN = "/oven/state"
TOPIC_EVENT = "/profile/event"
TOPIC_LOG = "/log"
# Viewer-friendly mirrors (Foxglove/Lichtblick panels): block statistics with a header stamp,
# and /log as foxglove.Log for the Log panel. Additive: readers of the topics above ignore them.
TOPIC_RATE_SUMMARY = "/gyro/rate_summary"
TOPIC_LOG_FOXGLOVE = "/log/foxglove"
ALL_TOPICS = (
    TOPIC_ADC,
    TOPIC_RATE,
    TOPIC_PT100,
    TOPIC_OVEN,
    TOPIC_EVENT,
    TOPIC_LOG,
    TOPIC_RATE_SUMMARY,
    TOPIC_LOG_FOXGLOVE,
)
#: gyrolab /log level -> foxglove.LogLevel (UNKNOWN 0, DEBUG 1, INFO 2, WARNING 3, ERROR 4,
#: FATAL 5; @foxglove/schemas 2.1 jsonschema Log)
FOXGLOVE_LOG_LEVEL = {"debug": 1, "info": 2, "warning": 3, "error": 4, "fault": 5}

# Multi-unit recordings (docs/recording-format.md "Several units"): every topic under
# /gyro/ and /temperature/ belongs to one unit and is written as /unit/<serial><topic>;
# the chamber's topics (/oven/state, /profile/event, /log) stay shared and unprefixed.
UNIT_PREFIX = "/unit/"
PER_UNIT_ROOTS = ("/gyro/", "/temperature/")
SERIAL_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")


def is_per_unit(topic: str) -> bool:
    """Whether ``topic`` (single-unit name) is one unit's in a multi-unit recording."""
    return topic.startswith(PER_UNIT_ROOTS)


def unit_topic(topic: str, serial: str | None) -> str:
    """The name of ``topic`` for unit ``serial`` (unchanged when ``serial`` is None or the
    topic is shared): ``unit_topic("/gyro/rate", "SN7")`` → ``/unit/SN7/gyro/rate``."""
    if serial is None or not is_per_unit(topic):
        return topic
    check_serial(serial)
    return f"{UNIT_PREFIX}{serial}{topic}"


def check_serial(serial: str) -> str:
    """A serial is one topic path segment: letters, digits, ``.``, ``_``, ``-`` (≤ 64)."""
    if not isinstance(serial, str) or not SERIAL_RE.fullmatch(serial):
        raise ValueError(
            f"unit serial {serial!r} must be 1-64 letters, digits, '.', '_' or '-' "
            "(not starting with a punctuation mark)"
        )
    return serial


FORMAT_VERSION = "1"
PROFILE = "gyrolab"  # MCAP header profile

MAX_AXES = 3  # a unit's rate stream carries 1–3 axes (x, y, z)
AXIS_NAMES = ("x", "y", "z")

ADC_MESSAGE = "gyrolab.GyroAdcBlock"
RATE_MESSAGE = "gyrolab.GyroRateBlock"

# --------------------------------------------------------------------------- schemas

JSON_SCHEMAS: dict[str, dict[str, Any]] = {
    TOPIC_PT100: {
        "title": "gyrolab.Pt100Reading",
        "type": "object",
        "properties": {
            "t": {"type": "number", "description": "s since run start"},
            "resistance_ohm": {"type": "number", "description": "4-wire resistance, Ω"},
            "temperature_c": {"type": "number", "description": "IEC 60751 inverse, °C"},
        },
        "required": ["t", "resistance_ohm", "temperature_c"],
    },
    TOPIC_OVEN: {
        "title": "gyrolab.OvenState",
        "type": "object",
        "properties": {
            "t": {"type": "number", "description": "s since run start"},
            "setpoint_c": {"type": "number", "description": "commanded setpoint, °C"},
            "process_value_c": {"type": "number", "description": "chamber air, °C"},
            "mode": {"type": "string", "description": "run | hold | standby | safe | fault"},
        },
        "required": ["t", "setpoint_c", "process_value_c", "mode"],
    },
    TOPIC_EVENT: {
        "title": "gyrolab.ProfileEvent",
        "type": "object",
        "properties": {
            "t": {"type": "number", "description": "s since run start"},
            "event": {
                "type": "string",
                "description": "run_started | step_started | soaked | step_ended | "
                "run_ended | aborted | safe_state",
            },
            "step": {"type": "integer", "description": "0-based step index, -1 if none"},
            "setpoint_c": {"type": "number"},
            "detail": {"type": "string"},
        },
        "required": ["t", "event"],
    },
    TOPIC_LOG: {
        "title": "gyrolab.Log",
        "type": "object",
        "properties": {
            "t": {"type": "number", "description": "s since run start"},
            "level": {"type": "string", "enum": ["debug", "info", "warning", "error", "fault"]},
            "source": {"type": "string", "description": "instrument or component"},
            "message": {"type": "string"},
            "kind": {
                "type": "string",
                "description": "machine-readable tag: fault | recovery | gap | ...",
            },
            "data": {"type": "object"},
        },
        "required": ["t", "level", "source", "message"],
    },
    TOPIC_RATE_SUMMARY: {
        "title": "gyrolab.RateSummary",
        "type": "object",
        "properties": {
            "header": {
                "type": "object",
                "description": "stamp: Unix time of the block's middle sample (sec, nsec)",
                "properties": {
                    "stamp": {
                        "type": "object",
                        "properties": {
                            "sec": {"type": "integer", "minimum": 0},
                            "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
                        },
                    },
                    "frame_id": {"type": "string"},
                },
            },
            "t": {"type": "number", "description": "s since run start, the block's middle"},
            "t0": {"type": "number", "description": "s since run start, first sample"},
            "first_index": {"type": "integer", "description": "index of the first sample"},
            "n": {"type": "integer", "description": "samples in the block"},
            "mean_dps": {"type": "number", "description": "mean angular rate, °/s"},
            "min_dps": {"type": "number", "description": "°/s"},
            "max_dps": {"type": "number", "description": "°/s"},
            "axes_mean_dps": {
                "type": "array",
                "items": {"type": "number"},
                "description": "multi-axis units only: mean per axis (x, y, z), °/s; the "
                "fields above are axis x's",
            },
            "axes_min_dps": {"type": "array", "items": {"type": "number"}},
            "axes_max_dps": {"type": "array", "items": {"type": "number"}},
        },
        "required": ["header", "t", "t0", "first_index", "n", "mean_dps", "min_dps", "max_dps"],
    },
    # foxglove.Log exactly as @foxglove/schemas 2.1.0 (jsonschema) defines it
    TOPIC_LOG_FOXGLOVE: {
        "title": "foxglove.Log",
        "description": "A log message",
        "type": "object",
        "properties": {
            "timestamp": {
                "type": "object",
                "title": "time",
                "properties": {
                    "sec": {"type": "integer", "minimum": 0},
                    "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
                },
                "description": "Timestamp of log message",
            },
            "level": {
                "title": "foxglove.LogLevel",
                "description": "Log level",
                "oneOf": [
                    {"title": name, "const": i, "description": f"{desc} log level"}
                    for i, (name, desc) in enumerate(
                        (
                            ("UNKNOWN", "Unknown"),
                            ("DEBUG", "Debug"),
                            ("INFO", "Info"),
                            ("WARNING", "Warning"),
                            ("ERROR", "Error"),
                            ("FATAL", "Fatal"),
                        )
                    )
                ],
            },
            "message": {"type": "string", "description": "Log message"},
            "name": {"type": "string", "description": "Process or node name"},
            "file": {"type": "string", "description": "Filename"},
            "line": {"type": "integer", "minimum": 0, "description": "Line number in the file"},
        },
        "required": ["timestamp", "level", "message", "name", "file", "line"],
    },
}

_PROTO_TEXT = """\
syntax = "proto3";
package gyrolab;
// One block of raw ADC counts (24-bit signed, sign-extended).
message GyroAdcBlock {
  double t0 = 1;           // s since run start, first sample
  double period = 2;       // s between samples
  uint64 first_index = 3;  // index of the first sample since run start
  repeated sfixed32 counts = 4;
  uint32 axes = 5;         // values per sample, interleaved; absent/0 = 1 (single axis)
}
// One block of angular rate, deg/s.
message GyroRateBlock {
  double t0 = 1;
  double period = 2;
  uint64 first_index = 3;
  repeated float rate_dps = 4;
  uint32 axes = 5;         // values per sample, interleaved (x, y, z); absent/0 = 1
}
"""


def _file_descriptor_set() -> bytes:
    """Serialized FileDescriptorSet of the two block messages (the MCAP schema data)."""
    from google.protobuf import descriptor_pb2

    fds = descriptor_pb2.FileDescriptorSet()
    fd = fds.file.add()
    fd.name = "gyrolab/blocks.proto"
    fd.package = "gyrolab"
    fd.syntax = "proto3"
    F = descriptor_pb2.FieldDescriptorProto
    for msg_name, arr_name, arr_type in (
        ("GyroAdcBlock", "counts", F.TYPE_SFIXED32),
        ("GyroRateBlock", "rate_dps", F.TYPE_FLOAT),
    ):
        m = fd.message_type.add()
        m.name = msg_name
        for num, (name, typ, lab) in enumerate(
            (
                ("t0", F.TYPE_DOUBLE, F.LABEL_OPTIONAL),
                ("period", F.TYPE_DOUBLE, F.LABEL_OPTIONAL),
                ("first_index", F.TYPE_UINT64, F.LABEL_OPTIONAL),
                (arr_name, arr_type, F.LABEL_REPEATED),
                ("axes", F.TYPE_UINT32, F.LABEL_OPTIONAL),
            ),
            start=1,
        ):
            f = m.field.add()
            f.name, f.number, f.type, f.label = name, num, typ, lab
            f.json_name = "".join(
                w if i == 0 else w.capitalize() for i, w in enumerate(name.split("_"))
            )
    return fds.SerializeToString(deterministic=True)


# ------------------------------------------------------------------ protobuf codec


def _varint(n: int) -> bytes:
    out = bytearray()
    while True:
        b = n & 0x7F
        n >>= 7
        if n:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def encode_block(
    t0: float, period: float, first_index: int, values: np.ndarray, kind: str
) -> bytes:
    """Protobuf wire bytes of a block; ``kind`` is ``"adc"`` (int32) or ``"rate"`` (float32).

    ``values`` is ``(n,)`` for one axis or ``(n, axes)`` for 2–3 axes (stored interleaved,
    sample-major, with ``axes`` in field 5). A single-axis block omits field 5, so its bytes
    are those of the format before axis counts existed."""
    dtype = "<i4" if kind == "adc" else "<f4"
    v = np.asarray(values)
    axes = 1 if v.ndim == 1 else int(v.shape[1])
    if v.ndim > 2 or not 1 <= axes <= MAX_AXES:
        raise ValueError(f"a block holds (n,) or (n, 1..{MAX_AXES}) values, not {v.shape}")
    payload = np.ascontiguousarray(v, dtype=dtype).tobytes()
    tail = (b"\x28", _varint(axes)) if axes > 1 else ()
    return b"".join(
        (
            b"\x09",
            struct.pack("<d", t0),
            b"\x11",
            struct.pack("<d", period),
            b"\x18",
            _varint(int(first_index)),
            b"\x22",
            _varint(len(payload)),
            payload,
            *tail,
        )
    )


def decode_block(data: bytes, kind: str) -> tuple[float, float, int, np.ndarray]:
    """Inverse of :func:`encode_block`; accepts any valid field order. The values come back
    ``(n,)`` for a single-axis block, ``(n, axes)`` for a multi-axis one."""
    t0 = period = 0.0
    first = 0
    axes = 1
    arr: np.ndarray = np.empty(0, dtype="<i4" if kind == "adc" else "<f4")
    mv = memoryview(data)
    i, n = 0, len(data)
    while i < n:
        key = 0
        shift = 0
        while True:
            b = mv[i]
            i += 1
            key |= (b & 0x7F) << shift
            shift += 7
            if not b & 0x80:
                break
        fno, wt = key >> 3, key & 7
        if wt == 1:
            (val,) = struct.unpack_from("<d", mv, i)
            i += 8
            if fno == 1:
                t0 = val
            elif fno == 2:
                period = val
        elif wt == 0:
            v = 0
            shift = 0
            while True:
                b = mv[i]
                i += 1
                v |= (b & 0x7F) << shift
                shift += 7
                if not b & 0x80:
                    break
            if fno == 3:
                first = v
            elif fno == 5:
                axes = max(1, v)
        elif wt == 2:
            ln = 0
            shift = 0
            while True:
                b = mv[i]
                i += 1
                ln |= (b & 0x7F) << shift
                shift += 7
                if not b & 0x80:
                    break
            if fno == 4:
                arr = np.frombuffer(mv[i : i + ln], dtype=arr.dtype)
            i += ln
        elif wt == 5:
            i += 4
        else:
            raise ValueError(f"unsupported protobuf wire type {wt}")
    if axes > 1:
        if arr.size % axes:
            raise ValueError(f"{arr.size} values do not split into {axes} axes")
        arr = arr.reshape(-1, axes)
    return t0, period, first, arr


# -------------------------------------------------------------------------- writer


class RecordingWriter:
    """Writes one run to MCAP.

    ``stream`` is a path or a binary file object. ``start_time_ns`` is the Unix time of
    the run's start; every message's ``t`` is relative to it. ``run`` and ``bench`` are
    written as the MCAP metadata records of those names (nested values as JSON text).
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
        run: Mapping[str, Any] | None = None,
        bench: Mapping[str, Any] | None = None,
        chunk_size: int = 1 << 20,
        compression: str = "zstd",
        flush_every_s: float | None = None,
        fsync: bool = False,
        fsync_every_s: float | None = None,
        units: list[str] | None = None,
    ) -> None:
        from mcap.writer import CompressionType, Writer

        self._own = not hasattr(stream, "write")
        self._fh: IO[bytes] = open(stream, "wb") if self._own else stream  # type: ignore[arg-type]
        comp = {
            "zstd": CompressionType.ZSTD,
            "lz4": CompressionType.LZ4,
            "none": CompressionType.NONE,
        }
        # Multi-unit: this class closes every chunk (one group's buffer each), never mcap's
        # Writer, whose size rule would mix groups; single-unit: mcap's rule, as always.
        inner_size = chunk_size if units is None else 1 << 62
        self._w = Writer(self._fh, chunk_size=inner_size, compression=comp[compression])
        self._w.start(profile=PROFILE, library=f"gyrolab {_version()}")
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
        serials: list[str | None] = [None] if self.units is None else list(self.units)
        if self.units is not None:
            for g in [*self.units, None]:
                self._buf[g], self._buf_bytes[g] = [], 0
        fds = _file_descriptor_set()
        adc_schema = self._w.register_schema(ADC_MESSAGE, "protobuf", fds)
        rate_schema = self._w.register_schema(RATE_MESSAGE, "protobuf", fds)
        for u in serials:
            for topic, sch in ((TOPIC_ADC, adc_schema), (TOPIC_RATE, rate_schema)):
                name = unit_topic(topic, u)
                self._chan[name] = self._w.register_channel(name, "protobuf", sch)
                self._group[name] = u
        for topic, schema in JSON_SCHEMAS.items():
            sid = self._w.register_schema(
                schema["title"], "jsonschema", json.dumps(schema, sort_keys=True).encode()
            )
            for u in serials if is_per_unit(topic) else [None]:
                name = unit_topic(topic, u)
                self._chan[name] = self._w.register_channel(name, "json", sid)
                self._group[name] = u
        meta_run = {"format_version": FORMAT_VERSION, "software_version": _version()}
        if self.units is not None:
            meta_run["units"] = list(self.units)
        meta_run.update(run or {})
        self.write_metadata("run", meta_run)
        self.write_metadata("bench", bench or {})

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
        flat = {
            k: v if isinstance(v, str) else json.dumps(v, sort_keys=True) for k, v in values.items()
        }
        self._w.add_metadata(name, flat)

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


def _version() -> str:
    from gyrolab import __version__

    return __version__


# -------------------------------------------------------------------------- reader


@dataclass
class Series:
    """A batched stream unpacked: per-sample times, values and sample indices."""

    t: np.ndarray
    values: np.ndarray
    index: np.ndarray
    period: float

    @property
    def rate_hz(self) -> float:
        return 1.0 / self.period if self.period > 0 else float("nan")

    @property
    def axes(self) -> int:
        """Values per sample: 1 (``values`` is ``(n,)``) or 2–3 (``values`` is ``(n, axes)``)."""
        return 1 if self.values.ndim == 1 else int(self.values.shape[1])

    def axis(self, k: int) -> Series:
        """The single-axis series of axis ``k`` (the series itself when it has one axis)."""
        if self.values.ndim == 1:
            if k != 0:
                raise IndexError(f"single-axis series has no axis {k}")
            return self
        return Series(self.t, np.ascontiguousarray(self.values[:, k]), self.index, self.period)

    def gaps(self) -> list[tuple[float, int]]:
        """``(t_before_gap, n_missing)`` for every jump in the sample index."""
        if self.index.size < 2:
            return []
        d = np.diff(self.index)
        where = np.flatnonzero(d != 1)
        return [(float(self.t[i]), int(d[i] - 1)) for i in where]


@dataclass
class Recording:
    """A recording read into numpy arrays (only the topics that were asked for)."""

    path: str
    run: dict[str, Any] = field(default_factory=dict)
    bench: dict[str, Any] = field(default_factory=dict)
    metadata: dict[str, dict[str, Any]] = field(default_factory=dict)
    rate: Series | None = None
    adc: Series | None = None
    pt100_t: np.ndarray = field(default_factory=lambda: np.empty(0))
    pt100_ohm: np.ndarray = field(default_factory=lambda: np.empty(0))
    pt100_c: np.ndarray = field(default_factory=lambda: np.empty(0))
    oven_t: np.ndarray = field(default_factory=lambda: np.empty(0))
    oven_setpoint_c: np.ndarray = field(default_factory=lambda: np.empty(0))
    oven_pv_c: np.ndarray = field(default_factory=lambda: np.empty(0))
    oven_mode: list[str] = field(default_factory=list)
    events: list[dict[str, Any]] = field(default_factory=list)
    logs: list[dict[str, Any]] = field(default_factory=list)
    topic_counts: dict[str, int] = field(default_factory=dict)
    unit: str | None = None  # the unit read from a multi-unit recording

    def require_rate(self) -> Series:
        if self.rate is None or self.rate.t.size == 0:
            raise InputError(self.path, f"recording has no {TOPIC_RATE} data")
        return self.rate

    def require_temperature(self) -> tuple[np.ndarray, np.ndarray]:
        if self.pt100_t.size == 0:
            raise InputError(self.path, f"recording has no {TOPIC_PT100} data")
        return self.pt100_t, self.pt100_c

    @property
    def axes(self) -> int:
        """Axes of the rate stream (1 when there is none)."""
        return 1 if self.rate is None else self.rate.axes

    def axis(self, k: int) -> Recording:
        """A shallow copy whose ``rate`` is axis ``k`` only (the same object for one axis)."""
        if self.axes == 1 and k == 0:
            return self
        from dataclasses import replace

        rate = self.require_rate().axis(k)
        adc = None if self.adc is None or self.adc.values.ndim == 1 else self.adc.axis(k)
        return replace(self, rate=rate, adc=adc)


def _parse_meta(values: Mapping[str, str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in values.items():
        try:
            out[k] = json.loads(v)
        except (json.JSONDecodeError, TypeError):
            out[k] = v
    return out


def _open_reader(path: str | os.PathLike[str]) -> tuple[IO[bytes], Any]:
    from mcap.reader import make_reader

    p = Path(path)
    if not p.is_file():
        raise InputError(p, "file not found")
    fh = open(p, "rb")
    magic = fh.read(8)
    fh.seek(0)
    if magic != b"\x89MCAP0\r\n":
        fh.close()
        raise InputError(p, "not an MCAP file")
    return fh, make_reader(fh)


def read_metadata(path: str | os.PathLike[str]) -> dict[str, dict[str, Any]]:
    """All metadata records of a recording, values JSON-decoded where possible."""
    fh, reader = _open_reader(path)
    try:
        return {m.name: _parse_meta(m.metadata) for m in reader.iter_metadata()}
    except InputError:
        raise
    except Exception as e:  # mcap raises many types on damaged files
        raise InputError(path, f"damaged or truncated MCAP ({e}); try `gyrolab recover`") from None
    finally:
        fh.close()


def list_units(path: str | os.PathLike[str]) -> list[str]:
    """The unit serials of a multi-unit recording, in file order; ``[]`` for single-unit."""
    fh, reader = _open_reader(path)
    try:
        summary = reader.get_summary()
        channels = summary.channels.values() if summary is not None else None
        if channels is None:  # no summary section (a recovered file): scan the messages
            channels = [c for _s, c, _m in reader.iter_messages()]
        units: list[str] = []
        for ch in channels:
            if ch.topic.startswith(UNIT_PREFIX):
                serial = ch.topic[len(UNIT_PREFIX) :].split("/", 1)[0]
                if serial not in units:
                    units.append(serial)
        return units
    except InputError:
        raise
    except Exception as e:
        raise InputError(path, f"damaged or truncated MCAP ({e}); try `gyrolab recover`") from None
    finally:
        fh.close()


def select_unit(path: str | os.PathLike[str], unit: str | None) -> str | None:
    """Resolve ``--unit``: the serial to read from ``path``, or None for a single-unit file.

    A multi-unit file with one unit needs no ``unit``; with several, ``unit`` is required.
    A unit the file does not hold is an :class:`InputError` listing the serials it has."""
    try:
        units = list_units(path)
    except InputError:
        if unit is None:  # not a gyrolab MCAP (a user's log): no units; its reader reports
            return None
        raise
    if not units:
        if unit is not None:
            serial = read_metadata(path).get("run", {}).get("unit_serial")
            if unit != serial:
                raise InputError(
                    path,
                    f"is a single-unit recording (unit {serial or 'unnamed'}); "
                    f"it has no unit {unit!r}",
                )
        return None
    if unit is None:
        if len(units) == 1:
            return units[0]
        raise InputError(
            path, f"holds {len(units)} units; choose one with --unit SERIAL: {', '.join(units)}"
        )
    if unit not in units:
        raise InputError(path, f"has no unit {unit!r}; its units: {', '.join(units)}")
    return unit


def iter_messages(
    path: str | os.PathLike[str], topics: list[str] | None = None, unit: str | None = None
) -> Iterator[tuple[str, int, bytes]]:
    """``(topic, log_time_ns, data)`` in log-time order, streaming.

    ``unit``: in a multi-unit recording, read that unit's topics under their single-unit
    names (``/unit/<unit>/gyro/rate`` comes back as ``/gyro/rate``) beside the shared ones."""
    fh, reader = _open_reader(path)
    if unit is not None:
        names = list(ALL_TOPICS) if topics is None else topics
        topics = [unit_topic(t, unit) for t in names]
        prefix = f"{UNIT_PREFIX}{unit}"
    try:
        for _schema, channel, message in reader.iter_messages(topics=topics):
            topic = channel.topic
            if unit is not None and topic.startswith(prefix):
                topic = topic[len(prefix) :]
            yield topic, message.log_time, message.data
    except InputError:
        raise
    except Exception as e:
        raise InputError(path, f"damaged or truncated MCAP ({e}); try `gyrolab recover`") from None
    finally:
        fh.close()


def iter_blocks(
    path: str | os.PathLike[str], topic: str = TOPIC_RATE, unit: str | None = None
) -> Iterator[tuple[float, float, int, np.ndarray]]:
    """Stream ``/gyro/rate`` or ``/gyro/adc`` blocks as ``(t0, period, first_index, values)``."""
    kind = "adc" if topic == TOPIC_ADC else "rate"
    for _topic, _ts, data in iter_messages(path, [topic], unit=unit):
        yield decode_block(data, kind)


def _series(blocks: list[tuple[float, float, int, np.ndarray]], dtype: type) -> Series:
    if not blocks:
        return Series(np.empty(0), np.empty(0, dtype=dtype), np.empty(0, dtype=np.int64), 0.0)
    n = sum(b[3].shape[0] for b in blocks)
    shapes = {b[3].shape[1:] for b in blocks}
    if len(shapes) != 1:
        raise ValueError(f"blocks with different axis counts {sorted(shapes)}")
    t = np.empty(n)
    v = np.empty((n, *shapes.pop()), dtype=dtype)
    idx = np.empty(n, dtype=np.int64)
    pos = 0
    for t0, period, first, arr in blocks:
        m = arr.shape[0]
        k = np.arange(m)
        t[pos : pos + m] = t0 + k * period
        v[pos : pos + m] = arr
        idx[pos : pos + m] = first + k
        pos += m
    return Series(t, v, idx, float(np.median([b[1] for b in blocks])))


def read_recording(
    path: str | os.PathLike[str], topics: list[str] | None = None, unit: str | None = None
) -> Recording:
    """Read a recording into arrays. ``topics`` limits what is decoded (default: all);
    ``unit`` selects one unit of a multi-unit recording (:func:`select_unit`), whose
    topics come back under their single-unit names.

    Rate samples come back as float64 °/s, ADC counts as int32. Raises
    :class:`~gyrolab.errors.InputError` on a missing, foreign or damaged file.
    """
    topics = list(ALL_TOPICS) if topics is None else topics
    rec = Recording(path=str(path))
    rec.metadata = read_metadata(path)
    rec.run = rec.metadata.get("run", {})
    rec.bench = rec.metadata.get("bench", {})
    if unit is not None:
        rec.unit = unit
        rec.run = {**rec.run, "unit_serial": unit}
    rate_blocks: list[tuple[float, float, int, np.ndarray]] = []
    adc_blocks: list[tuple[float, float, int, np.ndarray]] = []
    pt, oven = [], []
    counts: dict[str, int] = {}
    for topic, _ts, data in iter_messages(path, topics, unit=unit):
        counts[topic] = counts.get(topic, 0) + 1
        if topic == TOPIC_RATE:
            rate_blocks.append(decode_block(data, "rate"))
        elif topic == TOPIC_ADC:
            adc_blocks.append(decode_block(data, "adc"))
        else:
            msg = json.loads(data)
            if topic == TOPIC_PT100:
                pt.append((msg["t"], msg["resistance_ohm"], msg["temperature_c"]))
            elif topic == TOPIC_OVEN:
                oven.append((msg["t"], msg["setpoint_c"], msg["process_value_c"]))
                rec.oven_mode.append(msg["mode"])
            elif topic == TOPIC_EVENT:
                rec.events.append(msg)
            elif topic == TOPIC_LOG:
                rec.logs.append(msg)
    rec.topic_counts = counts
    try:
        if TOPIC_RATE in topics:
            rec.rate = _series(rate_blocks, np.float64)
        if TOPIC_ADC in topics:
            rec.adc = _series(adc_blocks, np.int32)
    except ValueError as e:
        raise InputError(path, str(e)) from None
    if pt:
        a = np.asarray(pt, dtype=float)
        rec.pt100_t, rec.pt100_ohm, rec.pt100_c = a[:, 0], a[:, 1], a[:, 2]
    if oven:
        a = np.asarray(oven, dtype=float)
        rec.oven_t, rec.oven_setpoint_c, rec.oven_pv_c = a[:, 0], a[:, 1], a[:, 2]
    return rec
