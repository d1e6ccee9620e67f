"""Reading a recording: whole (:func:`read_recording` into numpy arrays) or streaming
(:func:`iter_messages`, :func:`iter_blocks`, or :func:`read_recording` handing the rate
blocks to a callback while it reads the other topics), one unit of a multi-unit file at a time
(:func:`list_units`, :func:`select_unit`).

The ``run`` and ``bench`` records come back normalised (:mod:`gyrolab.record.metadata`):
files written with older spellings read in the documented shape.

A run resumed after an interruption (``gyrolab acquire --resume``) is several files, its
segments, each continuing the one before (docs/recording-format.md, "Segments"). Every
function here reads the run a file belongs to, from its first segment to that file
(:func:`segments`): the messages of each segment in turn, on the one run clock, with the
interruption a gap in the data (the sample index jumps, nothing is filled in) that
``Recording.interruptions`` and the ``run`` record's ``segments`` name.
"""

from __future__ import annotations

import json
import math
import os
import struct
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from gyrolab.errors import InputError
from gyrolab.record.blocks import decode_block
from gyrolab.record.format import (
    ALL_TOPICS,
    TOPIC_ADC,
    TOPIC_EVENT,
    TOPIC_LOG,
    TOPIC_OVEN,
    TOPIC_PT100,
    TOPIC_RATE,
    TOPIC_TEMPERATURE_INTERNAL,
    UNIT_PREFIX,
    unit_topic,
)
from gyrolab.record.metadata import normalise_bench, normalise_run
from gyrolab.record.source import Order, opened

#: A decoded rate or ADC block: ``(t0, period, first_index, values)``.
Block = tuple[float, float, int, np.ndarray]


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
    # the unit's accelerometer (m/s², x/y/z) where the source has one (users' logs,
    # gyrolab.logs); None otherwise
    accel: Series | None = None
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
    # What pt100_t / pt100_c hold: the unit's PT100 ("pt100"), or, for a unit whose bench
    # took its internal sensor as its temperature, that sensor ("internal": pt100_ohm is NaN)
    temperature_source: str = "pt100"

    @property
    def interruptions(self) -> list[tuple[float, float]]:
        """A resumed run's gaps between segments: ``(last time before, time it resumed)``
        (run seconds) each; empty for a run in one piece."""
        return interruptions(self.run)

    def require_rate(self) -> Series:
        if self.rate is None or self.rate.t.size == 0:
            raise InputError(self.path, f"recording has no {TOPIC_RATE} data")
        return self.rate

    def require_temperature(self) -> tuple[np.ndarray, np.ndarray]:
        """The temperature readings the drift model uses (s, °C): see ``temperature_source``."""
        if self.pt100_t.size == 0:
            raise InputError(
                self.path, f"recording has no {TOPIC_PT100} (or {TOPIC_TEMPERATURE_INTERNAL}) data"
            )
        return self.pt100_t, self.pt100_c

    @property
    def axes(self) -> int:
        """Axes of the rate stream (1 when there is none)."""
        return 1 if self.rate is None else self.rate.axes

    def axis(self, k: int) -> Recording:
        """A shallow copy whose ``rate`` is axis ``k`` only (the same object for one axis)."""
        if self.axes == 1 and k == 0:
            return self
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


def file_metadata(path: str | os.PathLike[str]) -> dict[str, dict[str, Any]]:
    """One file's metadata records as written (not normalised, not merged with the other
    segments of its run: :func:`read_metadata`), values JSON-decoded where possible."""
    with opened(path) as src:
        return {m.name: _parse_meta(m.metadata) for m in src.metadata()}


#: Longest chain of segments followed (a loop of file names cannot hang a reader).
MAX_SEGMENTS = 1000


def _run_record(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The ``run`` record of one file, and no other: read through the summary's metadata
    index, so that following a run's segments opens no other record (a workflow that
    must not see ``sim_provenance`` may read runs; tests/test_discrepancy_workflow.py)."""
    with opened(path) as src:
        return _parse_meta(src.metadata_record("run") or {})


def segments(path: str | os.PathLike[str]) -> list[Path]:
    """The files of the run ``path`` belongs to, first to ``path``: a continuation (its
    ``run`` record's ``segment`` > 1) names the file it continues (``previous_segment``,
    beside it), which must hold the same ``run_id`` and the segment before. A missing or
    foreign previous segment is an :class:`InputError` naming it: the run is not whole."""
    chain = [Path(path)]
    run = _run_record(path)
    while isinstance(run.get("segment"), int) and run["segment"] > 1:
        prev = run.get("previous_segment") or {}
        p = chain[0].parent / str(prev.get("file", ""))
        want = f"segment {run['segment'] - 1} of run {run.get('run_id')}"
        if not prev.get("file") or not p.is_file():
            raise InputError(chain[0], f"continues {p.name} ({want}), which is not beside it")
        before = _run_record(p)
        if before.get("run_id") != run.get("run_id") or before.get("segment", 1) != (
            run["segment"] - 1
        ):
            raise InputError(chain[0], f"continues {p.name}, which is not {want}")
        chain.insert(0, p)
        if len(chain) > MAX_SEGMENTS:
            raise InputError(path, f"more than {MAX_SEGMENTS} segments: a loop of file names")
        run = before
    return chain


def interruptions(run: Mapping[str, Any]) -> list[tuple[float, float]]:
    """The gaps of a resumed run from its ``run`` record (:func:`read_metadata`'s
    ``segments``): ``(after_t, at_t)`` per continuation, run seconds."""
    segs = run.get("segments") or []
    return [(float(s["after_t"]), float(s["at_t"])) for s in segs[1:] if "after_t" in s]


def read_metadata(path: str | os.PathLike[str]) -> dict[str, dict[str, Any]]:
    """All metadata records of a recording, values JSON-decoded where possible; ``run``
    and ``bench`` normalised (:func:`~gyrolab.record.metadata.normalise_run`).

    A resumed run's are its first segment's (what was run, on which bench), with ``run``
    ``segments``: each segment's ``segment`` and ``file``, a continuation's ``after_t``,
    ``at_t``, ``step`` (where it resumed), and a segment's ``recovery`` record if it went
    through ``gyrolab recover``."""
    paths = segments(path)
    records = file_metadata(paths[0])
    if len(paths) > 1:
        first: dict[str, Any] = {"segment": 1, "file": paths[0].name}
        if "recovery" in records:
            first["recovery"] = records.pop("recovery")
        segs = [first]
        for p in paths[1:]:
            later = file_metadata(p)
            run = later.get("run", {})
            seg = {"segment": run.get("segment"), "file": p.name, **(run.get("resumed") or {})}
            if "recovery" in later:
                seg["recovery"] = later["recovery"]
            segs.append(seg)
        records["run"] = {**records.get("run", {}), "segments": segs}
    for name, normalise in (("run", normalise_run), ("bench", normalise_bench)):
        if name in records:
            records[name] = normalise(records[name])
    return records


def read_bench_record(path: str | os.PathLike[str]) -> dict[str, Any] | None:
    """The ``bench`` metadata record alone, normalised (None when the file has none): no
    other record is decoded — the discrepancy workflow reads the instruments' settings
    this way and never sees a simulator's ``sim_provenance``."""
    with opened(path) as src:
        record = src.metadata_record("bench")
    return None if record is None else normalise_bench(_parse_meta(record))


def list_units(path: str | os.PathLike[str]) -> list[str]:
    """The unit serials of a multi-unit recording, in file order; ``[]`` for single-unit."""
    with opened(path) as src:
        channels = src.channels().values()
        units: list[str] = []
        for ch in channels:
            if ch.topic.startswith(UNIT_PREFIX):
                serial = ch.topic[len(UNIT_PREFIX) :].split("/", 1)[0]
                if serial not in units:
                    units.append(serial)
        return units


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
    path: str | os.PathLike[str],
    topics: list[str] | None = None,
    unit: str | None = None,
    order: Order = "log_time",
) -> Iterator[tuple[str, int, bytes]]:
    """``(topic, log_time_ns, data)`` in log-time order, streaming.

    ``unit``: in a multi-unit recording, read that unit's topics under their single-unit
    names (``/unit/<unit>/gyro/rate`` comes back as ``/gyro/rate``) beside the shared ones.

    ``order="topic"``: each topic's messages in log-time order (exactly as with
    ``"log_time"``), the topics interleaved as the file holds them — for callers that keep
    each topic apart. It reads the file's chunks in file order, one at a time, without the
    log-time merge of every message (a heap: a quarter of a unit's read time), whenever the
    summary shows that order is exact (:func:`~gyrolab.record.source.chunks_in_file_order`:
    files gyrolab writes); otherwise through the merge, as ``"log_time"`` does. One topic
    asked for in ``"log_time"`` order reads the same way (its order is then the whole order).

    Every chunk read is checked (:mod:`gyrolab.record.integrity`): a damaged one is an
    :class:`~gyrolab.errors.InputError` naming its byte offset and time span."""
    prefix = ""
    if unit is not None:
        names = list(ALL_TOPICS) if topics is None else topics
        topics = [unit_topic(t, unit) for t in names]
        prefix = f"{UNIT_PREFIX}{unit}"
    per_topic = order == "topic" or (topics is not None and len(set(topics)) == 1)
    # A resumed run's segments in turn: each ends before the next begins (the run clock
    # goes on across the interruption), so either order holds over the whole run.
    for p in segments(path):
        yield from _iter_file(p, topics, prefix, per_topic)


def _iter_file(
    path: Path, topics: list[str] | None, prefix: str, per_topic: bool
) -> Iterator[tuple[str, int, bytes]]:
    """:func:`iter_messages` of one file (topics already a unit's, ``prefix`` stripped)."""
    with opened(path) as src:
        for topic, log_time, data, _c, _s, _p in src.messages(
            topics, "topic" if per_topic else "log_time"
        ):
            if prefix and topic.startswith(prefix):
                topic = topic[len(prefix) :]
            yield topic, log_time, data


def iter_blocks(
    path: str | os.PathLike[str], topic: str = TOPIC_RATE, unit: str | None = None
) -> Iterator[Block]:
    """Stream ``/gyro/rate`` or ``/gyro/adc`` blocks as ``(t0, period, first_index, values)``."""
    kind = "adc" if topic == TOPIC_ADC else "rate"
    for _topic, _ts, data in iter_messages(path, [topic], unit=unit, order="topic"):
        yield decode_block(data, kind)


def _series(blocks: list[Block], dtype: type) -> Series:
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


def _decode(topic: str, data: bytes) -> Any:
    """One message of ``topic`` as :func:`read_recording` keeps it: a block, a row
    (PT100 ``(t, Ω, °C)``, internal ``(t, nan, °C)``, oven ``(t, setpoint, pv, mode)``) or
    the JSON object (events, log)."""
    if topic in (TOPIC_RATE, TOPIC_ADC):
        return decode_block(data, "rate" if topic == TOPIC_RATE else "adc")
    msg = json.loads(data)
    if topic == TOPIC_PT100:
        return (msg["t"], msg["resistance_ohm"], msg["temperature_c"])
    if topic == TOPIC_TEMPERATURE_INTERNAL:
        return (msg["t"], math.nan, msg["temperature_c"])
    if topic == TOPIC_OVEN:
        return (msg["t"], msg["setpoint_c"], msg["process_value_c"], msg["mode"])
    return msg


def read_recording(
    path: str | os.PathLike[str],
    topics: list[str] | None = None,
    unit: str | None = None,
    on_rate: Callable[[Block], None] | None = None,
) -> Recording:
    """Read a recording into arrays. ``topics`` limits what is decoded (default: all);
    ``unit`` selects one unit of a multi-unit recording (:func:`select_unit`), whose
    topics come back under their single-unit names.

    ``on_rate``: each ``/gyro/rate`` block, in log-time order, goes to it instead of into
    ``rate`` (left ``None``): a caller streams the rate in bounded memory while the small
    topics are read in the same pass (one decompression of the file's chunks, not two).

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
    rate_blocks: list[Block] = []
    adc_blocks: list[Block] = []
    keep_rate = rate_blocks.append if on_rate is None else on_rate
    pt, oven, internal = [], [], []
    counts: dict[str, int] = {}
    wanted = list(topics)
    if unit is not None and TOPIC_PT100 in wanted:
        # A unit on its internal sensor has that topic instead of a PT100 (the bench said so)
        wanted.append(TOPIC_TEMPERATURE_INTERNAL)
    # each topic is kept apart, so only its own order matters
    for topic, ts, data in iter_messages(path, wanted, unit=unit, order="topic"):
        counts[topic] = counts.get(topic, 0) + 1
        try:
            item = _decode(topic, data)
        except (ValueError, KeyError, TypeError, IndexError, struct.error) as e:
            # a message its writer got wrong (its CRC checked): not silently skipped
            raise InputError(
                path, f"a {topic} message (log time {ts} ns) does not decode: {e!r}"
            ) from None
        if topic == TOPIC_RATE:
            keep_rate(item)
        elif topic == TOPIC_ADC:
            adc_blocks.append(item)
        elif topic == TOPIC_PT100:
            pt.append(item)
        elif topic == TOPIC_TEMPERATURE_INTERNAL:
            internal.append(item)
        elif topic == TOPIC_OVEN:
            oven.append(item[:3])
            rec.oven_mode.append(item[3])
        elif topic == TOPIC_EVENT:
            rec.events.append(item)
        elif topic == TOPIC_LOG:
            rec.logs.append(item)
    rec.topic_counts = counts
    try:
        if TOPIC_RATE in topics and on_rate is None:
            rec.rate = _series(rate_blocks, np.float64)
        if TOPIC_ADC in topics:
            rec.adc = _series(adc_blocks, np.int32)
    except ValueError as e:
        raise InputError(path, str(e)) from None
    if internal and not pt:
        pt, rec.temperature_source = internal, "internal"
    if pt:
        a = np.asarray(pt, dtype=float)
        rec.pt100_t, rec.pt100_ohm, rec.pt100_c = a[:, 0], a[:, 1], a[:, 2]
    if oven:
        a = np.asarray(oven, dtype=float)
        rec.oven_t, rec.oven_setpoint_c, rec.oven_pv_c = a[:, 0], a[:, 1], a[:, 2]
    return rec
