"""The recording's format: topics, their schemas, the unit and axis naming rules, constants.

One run is one MCAP file (docs/recording-format.md is the reference). High-rate gyro
streams are batched: one Protobuf message per block of samples carrying the block's first
timestamp, the sample period and the index of its first sample (so gaps are explicit;
:mod:`gyrolab.record.blocks` encodes them). Low-rate channels are JSON with a JSON Schema.
Both are MCAP well-known encodings, so any MCAP reader (Foxglove, the ``mcap`` CLI,
``@mcap/core``) opens the file.

Times inside messages are seconds since the run's start (``t``/``t0``); the MCAP
``log_time`` is ``start_time_ns + t·1e9`` (Unix epoch, ns).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from typing import Any

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
# A unit's internal (die) temperature sensor, where its rate stream reports one and the bench
# takes it as the unit's temperature (docs/recording-format.md). Not in ALL_TOPICS: its
# channel exists only in files that have such a unit, so every other file stays as it was.
TOPIC_TEMPERATURE_INTERNAL = "/temperature/internal"
INTERNAL_TEMPERATURE_SCHEMA: dict[str, Any] = {
    "title": "gyrolab.InternalTemperature",
    "type": "object",
    "properties": {
        "t": {"type": "number", "description": "s since run start, mean time of the readings"},
        "temperature_c": {
            "type": "number",
            "description": "the unit's internal sensor, °C: mean of the readings averaged",
        },
        "readings": {"type": "integer", "description": "sensor readings averaged (≥ 1)"},
    },
    "required": ["t", "temperature_c", "readings"],
}
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


def file_descriptor_set() -> bytes:
    """Serialized FileDescriptorSet of the two block messages (the MCAP schema data of
    ``/gyro/adc`` and ``/gyro/rate``; the messages as docs/recording-format.md gives them)."""
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


@dataclass(frozen=True)
class ChannelSpec:
    """One channel of a recording: its topic, the MCAP schema (name, encoding, data) and
    the message encoding; ``unit`` is the serial of a per-unit topic (None: shared)."""

    topic: str
    schema_name: str
    schema_encoding: str  # "protobuf" | "jsonschema"
    schema_data: bytes
    message_encoding: str  # "protobuf" | "json"
    unit: str | None = None


def recording_channels(
    units: list[str] | None = None, internal_temperature: tuple[str, ...] | list[str] = ()
) -> list[ChannelSpec]:
    """Every channel of a recording, in the order the writer registers them: the single-unit
    layout (``units`` None) or the multi-unit one (each unit's ``/unit/<serial>/…`` topics
    and the shared ones), then ``/unit/<serial>/temperature/internal`` of each unit in
    ``internal_temperature``. The writer and the live view (gyrolab/acquisition/live.py)
    both take their channels from here, so a viewer is offered exactly what the file holds."""
    serials: list[str | None] = [None] if units is None else list(units)
    fds = file_descriptor_set()
    out = [
        ChannelSpec(unit_topic(topic, u), msg, "protobuf", fds, "protobuf", u)
        for u in serials
        for topic, msg in ((TOPIC_ADC, ADC_MESSAGE), (TOPIC_RATE, RATE_MESSAGE))
    ]
    for topic, schema in JSON_SCHEMAS.items():
        data = json.dumps(schema, sort_keys=True).encode()
        for u in serials if is_per_unit(topic) else [None]:
            out.append(
                ChannelSpec(unit_topic(topic, u), schema["title"], "jsonschema", data, "json", u)
            )
    s = INTERNAL_TEMPERATURE_SCHEMA
    data = json.dumps(s, sort_keys=True).encode()
    for u in internal_temperature:
        name = unit_topic(TOPIC_TEMPERATURE_INTERNAL, u)
        out.append(ChannelSpec(name, s["title"], "jsonschema", data, "json", u))
    return out
