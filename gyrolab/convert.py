"""``gyrolab convert RUN.mcap --to csv|hdf5|parquet|netcdf --out FILE``: export a recording.

The sample table is the same in every format, one row per gyro sample (docs/convert.md):

    index        sample index since the run's start (a jump is a gap; nothing is filled in)
    t_s          s since the run's start
    rate_dps     angular rate, °/s (float32, as recorded); a multi-axis unit has
                 rate_x_dps, rate_y_dps (, rate_z_dps) instead, and adc_counts_x … likewise
    adc_counts   raw 24-bit ADC code (int32; only when the recording has /gyro/adc)
    pt100_c      PT100 temperature, °C: the last reading at or before t_s (NaN before the
                 first); held, never interpolated. A unit on its internal sensor
                 (``--unit`` of a multi-unit recording) has internal_temperature_c instead
    setpoint_c   oven setpoint, °C: the last /oven/state at or before t_s (NaN before)

HDF5 and NetCDF also hold the low-rate tables as they were recorded (``pt100``: t_s,
resistance_ohm, temperature_c, or ``internal_temperature``: t_s, temperature_c, readings;
``oven``: t_s, setpoint_c, process_value_c, mode) and every
format carries the run's metadata records, profile events and log (JSON text in
attributes / key-value metadata / ``#`` header lines of the CSV), units on every column.

Streaming: the recording is read message by message in log-time order and the table is
written block by block (one block of samples is held until the next arrives, so that the
readings taken during it are known): memory is bounded by a block, the low-rate readings
and the row-group buffer (``ROWS_PER_WRITE``), not by the run's length. Outputs are
atomic (temporary sibling, renamed at the end) and never the input file.
"""

from __future__ import annotations

import csv
import json
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gyrolab.errors import GyrolabError, InputError
from gyrolab.outputs import atomic_file, check_output
from gyrolab.progress import progress
from gyrolab.record.blocks import decode_block
from gyrolab.record.format import (
    TOPIC_ADC,
    TOPIC_EVENT,
    TOPIC_LOG,
    TOPIC_OVEN,
    TOPIC_PT100,
    TOPIC_RATE,
    TOPIC_TEMPERATURE_INTERNAL,
    unit_topic,
)
from gyrolab.record.reader import Recording, iter_messages, read_metadata, select_unit

FORMATS = ("csv", "hdf5", "parquet", "netcdf")
#: rows buffered before one write (a Parquet row group, an HDF5/NetCDF append)
ROWS_PER_WRITE = 1 << 16
ADC_FILL = np.iinfo(np.int32).min  # adc_counts of a sample whose ADC block is missing

COLUMNS: dict[str, tuple[str, str, str]] = {
    # name: (dtype, unit, description)
    "index": ("int64", "1", "sample index since run start; a jump is a gap"),
    "t_s": ("float64", "s", "time since run start"),
    "rate_dps": ("float32", "deg/s", "angular rate"),
    "adc_counts": ("int32", "count", "raw 24-bit ADC code, sign-extended"),
    "pt100_c": ("float64", "degC", "PT100 temperature, last reading at or before t_s"),
    "setpoint_c": ("float64", "degC", "oven setpoint, last state at or before t_s"),
}
#: pt100_c's place for a unit whose temperature is its internal (die) sensor: named for it,
#: so the die reading is never taken for the case PT100
INTERNAL_COLUMN = (
    "internal_temperature_c",
    ("float64", "degC", "unit's internal (die) sensor, last reading at or before t_s"),
)
LOW_RATE: dict[str, dict[str, tuple[str, str]]] = {
    "pt100": {
        "t_s": ("s", "time since run start"),
        "resistance_ohm": ("ohm", "4-wire resistance"),
        "temperature_c": ("degC", "IEC 60751 temperature"),
    },
    "oven": {
        "t_s": ("s", "time since run start"),
        "setpoint_c": ("degC", "commanded setpoint"),
        "process_value_c": ("degC", "chamber air"),
    },
    "internal_temperature": {
        "t_s": ("s", "mean time of the readings averaged"),
        "temperature_c": ("degC", "unit's internal (die) sensor, mean of the readings"),
        "readings": ("1", "sensor readings averaged"),
    },
}
_LIBS = {"hdf5": "h5py", "parquet": "pyarrow", "netcdf": "netCDF4"}


@dataclass
class RunTables:
    """What a conversion carries besides the sample table (all small)."""

    metadata: dict[str, dict[str, Any]]
    has_adc: bool
    start_time_ns: int
    # the unit's temperature readings as recorded: PT100 (t, ohm, °C), or its internal
    # sensor (t, °C, readings) when temperature_source is "internal"
    pt100: list[tuple[float, float, float]] = field(default_factory=list)
    oven: list[tuple[float, float, float, str]] = field(default_factory=list)
    events: list[dict[str, Any]] = field(default_factory=list)
    logs: list[dict[str, Any]] = field(default_factory=list)
    gaps: int = 0
    axes: int = 1  # a multi-axis unit has one rate (and ADC) column per axis
    unit: str | None = None  # the unit converted from a multi-unit recording
    temperature_source: str = "pt100"  # or "internal" (Recording.temperature_source)
    # a user's log (gyrolab.logs: ULog, DataFlash, ROS 2): no oven, the IMU's own
    # temperature sensor, and its accelerometer where it has one
    foreign: bool = False
    has_accel: bool = False

    def low_rate(self) -> list[tuple[str, list[tuple[Any, ...]]]]:
        """The low-rate tables (names of :data:`LOW_RATE`) with their rows."""
        temp = "pt100" if self.temperature_source == "pt100" else "internal_temperature"
        return [(temp, self.pt100)] + ([] if self.foreign else [("oven", self.oven)])


AXIS_NAMES = "xyz"


def table_columns(tables: RunTables) -> dict[str, tuple[str, str, str]]:
    """The sample table's columns in order. A single-axis run has :data:`COLUMNS`
    (``adc_counts`` only with /gyro/adc); a unit of a axes has ``rate_x_dps``,
    ``rate_y_dps`` (, ``rate_z_dps``) and likewise ``adc_counts_x`` … instead."""
    out: dict[str, tuple[str, str, str]] = {}
    if tables.foreign:
        return log_columns(tables.has_accel)
    for k, (dt, u, d) in COLUMNS.items():
        if k == "adc_counts" and not tables.has_adc:
            continue
        if k == "pt100_c" and tables.temperature_source == "internal":
            out[INTERNAL_COLUMN[0]] = INTERNAL_COLUMN[1]
            continue
        if tables.axes > 1 and k in ("rate_dps", "adc_counts"):
            for j in range(tables.axes):
                a = AXIS_NAMES[j]
                name = f"rate_{a}_dps" if k == "rate_dps" else f"adc_counts_{a}"
                out[name] = (dt, u, f"{d}, axis {a}")
        else:
            out[k] = (dt, u, d)
    return out


def log_columns(accel: bool) -> dict[str, tuple[str, str, str]]:
    """The sample table of a user's log: the gyro in the sensor frame, uncorrected
    (gyrolab.logs), the accelerometer where the log has one, the IMU's temperature."""
    out = {k: COLUMNS[k] for k in ("index", "t_s")}
    for a in AXIS_NAMES:
        out[f"rate_{a}_dps"] = (
            "float32", "deg/s", f"angular rate, axis {a}, sensor frame, uncorrected",
        )  # fmt: skip
    if accel:
        for a in AXIS_NAMES:
            out[f"accel_{a}_mps2"] = (
                "float32", "m/s^2",
                f"acceleration, axis {a}, sensor frame, uncorrected; last sample at or before t_s",
            )  # fmt: skip
    out[INTERNAL_COLUMN[0]] = (
        "float64", "degC", "IMU's own temperature sensor, last reading at or before t_s",
    )  # fmt: skip
    return out


def hold_last(t: np.ndarray, rt: np.ndarray, rv: np.ndarray) -> np.ndarray:
    """The last reading ``(rt, rv)`` at or before each ``t`` (NaN before the first); ``rv``
    may have a second axis. Held, never interpolated."""
    tt = np.asarray(rt, dtype=float)
    vv = np.asarray(rv, dtype=float)
    if tt.size == 0:
        return np.full((np.size(t), *vv.shape[1:]), np.nan)
    k = np.searchsorted(tt, t, side="right") - 1
    out = vv[np.maximum(k, 0)]
    out[k < 0] = np.nan
    return out


def iter_log_blocks(rec: Recording, tables: RunTables) -> Iterator[dict[str, np.ndarray]]:
    """The sample table of a user's log read into memory (gyrolab.logs.read_log), in blocks
    of ``ROWS_PER_WRITE`` rows; fills ``tables`` (temperature readings, gap count)."""
    rate = rec.require_rate()
    tables.pt100 = [(float(t), float(c), 1) for t, c in zip(rec.pt100_t, rec.pt100_c, strict=True)]
    tables.gaps = len(rate.gaps())
    for a in range(0, rate.t.size, ROWS_PER_WRITE):
        sl = slice(a, a + ROWS_PER_WRITE)
        t = rate.t[sl]
        cols: dict[str, np.ndarray] = {"index": rate.index[sl].astype(np.int64), "t_s": t}
        for j, ax in enumerate(AXIS_NAMES):
            cols[f"rate_{ax}_dps"] = rate.values[sl, j].astype(np.float32)
        if tables.has_accel and rec.accel is not None:
            acc = hold_last(t, rec.accel.t, rec.accel.values)
            for j, ax in enumerate(AXIS_NAMES):
                cols[f"accel_{ax}_mps2"] = acc[:, j].astype(np.float32)
        cols[INTERNAL_COLUMN[0]] = hold_last(t, rec.pt100_t, rec.pt100_c)
        yield cols


def _is_adc(name: str) -> bool:
    return name.startswith("adc_counts")


def _summary(path: Path) -> dict[str, int]:
    """Message count per topic, from the summary sections of the run's files (a resumed
    run's segments, gyrolab.record.reader.segments), each read checked."""
    from gyrolab.record.reader import segments
    from gyrolab.record.source import opened

    counts: dict[str, int] = {}
    for p in segments(path):
        with opened(p) as src:
            s = src.summary
        if s is None or s.statistics is None:
            raise InputError(p, "MCAP without a summary section; try `gyrolab recover`")
        topics = {c.id: c.topic for c in s.channels.values()}
        for c, n in s.statistics.channel_message_counts.items():
            counts[topics[c]] = counts.get(topics[c], 0) + int(n)
    return counts


def iter_sample_blocks(path: Path, tables: RunTables) -> Iterator[dict[str, np.ndarray]]:
    """The sample table, block by block (columns of :data:`COLUMNS`); fills ``tables``."""
    pending: list[tuple[float, float, int, np.ndarray]] = []
    adc: dict[int, np.ndarray] = {}
    pt_t: list[float] = []
    pt_c: list[float] = []
    ov_t: list[float] = []
    ov_sp: list[float] = []
    last_pt = (np.nan, np.nan)  # (t, value) of the last reading before the pending blocks
    last_ov = (np.nan, np.nan)
    next_index: int | None = None

    def held(t: np.ndarray, rt: list[float], rv: list[float], last: tuple[float, float]):
        # last reading at or before each t: the readings since the last emitted block, with
        # the one before them in front
        first = [last] if np.isfinite(last[0]) else []
        tt = np.asarray([r[0] for r in first] + rt, dtype=float)
        vv = np.asarray([r[1] for r in first] + rv, dtype=float)
        return hold_last(t, tt, vv)

    def emit() -> Iterator[dict[str, np.ndarray]]:
        nonlocal last_pt, last_ov, next_index
        for t0, period, first, rate in pending:
            n = len(rate)
            t = t0 + np.arange(n) * period
            cols: dict[str, np.ndarray] = {
                "index": first + np.arange(n, dtype=np.int64),
                "t_s": t,
            }
            ax = tables.axes
            if ax == 1:
                cols["rate_dps"] = rate.astype(np.float32)
            else:
                for j in range(ax):
                    cols[f"rate_{AXIS_NAMES[j]}_dps"] = rate[:, j].astype(np.float32)
            if tables.has_adc:
                a = adc.pop(first, None)
                codes = (
                    a.astype(np.int32).reshape(n, ax)
                    if a is not None and a.size == n * ax
                    else np.full((n, ax), ADC_FILL, np.int32)
                )
                if ax == 1:
                    cols["adc_counts"] = codes[:, 0]
                else:
                    for j in range(ax):
                        cols[f"adc_counts_{AXIS_NAMES[j]}"] = codes[:, j]
            cols[temp_col] = held(t, pt_t, pt_c, last_pt)
            cols["setpoint_c"] = held(t, ov_t, ov_sp, last_ov)
            if next_index is not None and first != next_index:
                tables.gaps += 1
            next_index = first + n
            yield cols
        pending.clear()
        # keep only the last reading at or before the end of what was emitted
        if pt_t:
            last_pt = (pt_t[-1], pt_c[-1])
            pt_t.clear()
            pt_c.clear()
        if ov_t:
            last_ov = (ov_t[-1], ov_sp[-1])
            ov_t.clear()
            ov_sp.clear()

    internal = tables.temperature_source == "internal"
    temp_col = INTERNAL_COLUMN[0] if internal else "pt100_c"
    topics = [TOPIC_RATE, TOPIC_ADC, TOPIC_OVEN, TOPIC_EVENT, TOPIC_LOG]
    topics.append(TOPIC_TEMPERATURE_INTERNAL if internal else TOPIC_PT100)
    for topic, _ts, data in iter_messages(path, topics, unit=tables.unit):
        if topic == TOPIC_RATE:
            blk = decode_block(data, "rate")
            axes = 1 if blk[3].ndim == 1 else blk[3].shape[1]
            if axes != tables.axes:  # the columns were fixed from the first block
                raise InputError(path, f"/gyro/rate mixes {tables.axes}- and {axes}-axis blocks")
            if pending and blk[0] > pending[-1][0]:
                # every reading logged before this block's start is known: emit the rest,
                # keeping readings that fall after the emitted blocks' start for later
                yield from emit()
            pending.append((blk[0], blk[1], blk[2], blk[3].copy()))
        elif topic == TOPIC_ADC:
            _t0, _p, first, counts = decode_block(data, "adc")
            adc[first] = counts.copy()
        else:
            msg = json.loads(data)
            if topic == TOPIC_PT100:
                tables.pt100.append((msg["t"], msg["resistance_ohm"], msg["temperature_c"]))
                pt_t.append(float(msg["t"]))
                pt_c.append(float(msg["temperature_c"]))
            elif topic == TOPIC_TEMPERATURE_INTERNAL:
                tables.pt100.append((msg["t"], msg["temperature_c"], msg["readings"]))
                pt_t.append(float(msg["t"]))
                pt_c.append(float(msg["temperature_c"]))
            elif topic == TOPIC_OVEN:
                tables.oven.append(
                    (msg["t"], msg["setpoint_c"], msg["process_value_c"], msg["mode"])
                )
                ov_t.append(float(msg["t"]))
                ov_sp.append(float(msg["setpoint_c"]))
            elif topic == TOPIC_EVENT:
                tables.events.append(msg)
            else:
                tables.logs.append(msg)
    yield from emit()


def _batched(blocks: Iterator[dict[str, np.ndarray]], rows: int) -> Iterator[dict[str, np.ndarray]]:
    buf: list[dict[str, np.ndarray]] = []
    n = 0
    for b in blocks:
        buf.append(b)
        n += b["t_s"].size
        if n >= rows:
            yield {k: np.concatenate([x[k] for x in buf]) for k in buf[0]}
            buf, n = [], 0
    if buf:
        yield {k: np.concatenate([x[k] for x in buf]) for k in buf[0]}


def _attrs(tables: RunTables, src: Path) -> dict[str, str]:
    """File-level attributes: all JSON text (string maps are what every format stores)."""
    plain = tables.axes == 1 and tables.temperature_source == "pt100" and not tables.foreign
    cols = COLUMNS if plain else table_columns(tables)  # single-axis PT100 run: as always
    unit = {} if tables.unit is None else {"gyrolab_unit": tables.unit}
    return {
        "gyrolab_source": str(src.name),
        "gyrolab_start_time_ns": str(tables.start_time_ns),
        "gyrolab_metadata": json.dumps(tables.metadata, sort_keys=True, default=str),
        "gyrolab_columns": json.dumps(
            {k: {"unit": u, "description": d} for k, (_t, u, d) in cols.items()}
        ),
        **unit,
    }


def _tail_attrs(tables: RunTables) -> dict[str, str]:
    """Attributes known only at the end: events, log and the gap count."""
    return {
        "gyrolab_events": json.dumps(tables.events, default=str),
        "gyrolab_log": json.dumps(tables.logs, default=str),
        "gyrolab_gaps": str(tables.gaps),
    }


# ---------------------------------------------------------------------------- writers


def _write_csv(tmp: Path, blocks: Iterator[dict], tables: RunTables, src: Path) -> int:
    spec = table_columns(tables)
    names = list(spec)
    n = 0
    with open(tmp, "w", encoding="utf-8", newline="") as fh:
        for k, v in _attrs(tables, src).items():
            fh.write(f"# {k}: {v}\n")
        for k in names:
            _t, u, d = spec[k]
            fh.write(f"# column {k}: {u}; {d}\n")
        fh.write(",".join(names) + "\n")
        out = csv.writer(fh, lineterminator="\n")
        for b in _batched(blocks, ROWS_PER_WRITE):
            # Python's float repr is the shortest string that reads back to the same float64
            # (float32 rates widened to float64 read back exactly too); an ADC code of a
            # block whose ADC message is missing is an empty field
            cols = [b[k].astype(np.float64 if k.startswith("rate_") else b[k].dtype).tolist()
                    for k in names]  # fmt: skip
            for j, k in enumerate(names):
                if _is_adc(k) and np.any(b[k] == ADC_FILL):
                    cols[j] = ["" if v == ADC_FILL else v for v in cols[j]]
            out.writerows(zip(*cols, strict=True))
            n += b["t_s"].size
        # events and log are only known at the end: trailing comment lines
        for k, v in _tail_attrs(tables).items():
            fh.write(f"# {k}: {v}\n")
    return n


def _write_parquet(tmp: Path, blocks: Iterator[dict], tables: RunTables, src: Path) -> int:
    import pyarrow as pa
    import pyarrow.parquet as pq

    spec = table_columns(tables)
    names = list(spec)
    fields = [
        pa.field(
            k,
            pa.from_numpy_dtype(np.dtype(spec[k][0])),
            nullable=_is_adc(k),
            metadata={"unit": spec[k][1], "description": spec[k][2]},
        )
        for k in names
    ]
    schema = pa.schema(fields, metadata=_attrs(tables, src))
    n = 0
    with pq.ParquetWriter(tmp, schema, compression="zstd") as w:
        for b in _batched(blocks, ROWS_PER_WRITE):
            arrays = []
            for k in names:
                v = b[k]
                mask = v == ADC_FILL if _is_adc(k) else None
                arrays.append(pa.array(v, type=schema.field(k).type, mask=mask))
            w.write_table(pa.Table.from_arrays(arrays, schema=schema))
            n += b["t_s"].size
        # the footer's key-value metadata gets events and log too (known at the end)
        w.add_key_value_metadata(_tail_attrs(tables))
    return n


def _write_hdf5(tmp: Path, blocks: Iterator[dict], tables: RunTables, src: Path) -> int:
    import h5py

    spec = table_columns(tables)
    names = list(spec)
    n = 0
    with h5py.File(tmp, "w") as f:
        for k, v in _attrs(tables, src).items():
            f.attrs[k] = v
        g = f.create_group("samples")
        ds = {}
        for k in names:
            dt, u, d = spec[k]
            ds[k] = g.create_dataset(
                k, shape=(0,), maxshape=(None,), dtype=dt, chunks=(min(ROWS_PER_WRITE, 65536),),
                compression="gzip", compression_opts=4,
                **({"fillvalue": ADC_FILL} if _is_adc(k) else {}),
            )  # fmt: skip
            ds[k].attrs["units"] = u
            ds[k].attrs["description"] = d
        for k in names:
            if _is_adc(k):
                ds[k].attrs["_FillValue"] = np.int32(ADC_FILL)
        for b in _batched(blocks, ROWS_PER_WRITE):
            m = b["t_s"].size
            for k in names:
                ds[k].resize((n + m,))
                ds[k][n : n + m] = b[k]
            n += m
        _low_rate_hdf5(f, tables)
        for k, v in _tail_attrs(tables).items():
            f.attrs[k] = v
    return n


def _low_rate_hdf5(f: Any, tables: RunTables) -> None:
    for name, rows in tables.low_rate():
        g = f.create_group(name)
        a = np.asarray([r[:3] for r in rows], dtype=float).reshape(-1, 3)
        for j, (col, (u, d)) in enumerate(LOW_RATE[name].items()):
            ds = g.create_dataset(col, data=a[:, j])
            ds.attrs["units"] = u
            ds.attrs["description"] = d
        if name == "oven":
            g.create_dataset("mode", data=np.array([r[3] for r in rows], dtype="S8"))


def _write_netcdf(tmp: Path, blocks: Iterator[dict], tables: RunTables, src: Path) -> int:
    import datetime as _dt

    import netCDF4

    spec = table_columns(tables)
    names = list(spec)
    start = _dt.datetime.fromtimestamp(tables.start_time_ns / 1e9, tz=_dt.timezone.utc)
    n = 0
    with netCDF4.Dataset(tmp, "w", format="NETCDF4") as nc:
        nc.Conventions = "CF-1.8"
        nc.title = f"gyrolab recording {src.name}"
        for k, v in _attrs(tables, src).items():
            setattr(nc, k, v)
        nc.createDimension("sample", None)
        var = {}
        for k in names:
            dt, u, d = spec[k]
            var[k] = nc.createVariable(
                k, np.dtype(dt), ("sample",), zlib=True, complevel=4,
                fill_value=ADC_FILL if _is_adc(k) else None,
            )  # fmt: skip
            var[k].units = u
            var[k].long_name = d
        # CF time coordinate: seconds since the run's start (UTC)
        var["t_s"].units = f"seconds since {start.isoformat().replace('+00:00', 'Z')}"
        var["t_s"].standard_name = "time"
        for k in names:
            var[k].set_auto_mask(False)
        for b in _batched(blocks, ROWS_PER_WRITE):
            m = b["t_s"].size
            for k in names:
                var[k][n : n + m] = b[k]
            n += m
        for name, rows in tables.low_rate():
            g = nc.createGroup(name)
            g.createDimension("reading", len(rows))
            a = np.asarray([r[:3] for r in rows], dtype=float).reshape(-1, 3)
            for j, (col, (u, d)) in enumerate(LOW_RATE[name].items()):
                v = g.createVariable(col, "f8", ("reading",))
                v.units = u
                v.long_name = d
                v[:] = a[:, j]
            if name == "oven":
                v = g.createVariable("mode", str, ("reading",))
                for i, r in enumerate(rows):
                    v[i] = r[3]
        for k, v in _tail_attrs(tables).items():
            setattr(nc, k, v)
    return n


_WRITERS = {
    "csv": _write_csv,
    "parquet": _write_parquet,
    "hdf5": _write_hdf5,
    "netcdf": _write_netcdf,
}


def convert_recording(
    src: str | os.PathLike[str],
    to: str,
    out: str | os.PathLike[str],
    force: bool = False,
    unit: str | None = None,
    log_options: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Convert ``src`` to ``out`` in format ``to``; returns ``{"rows", "gaps", "format"}``.
    ``unit``: the unit of a multi-unit recording (needed when it holds several);
    ``log_options``: :func:`gyrolab.logs.read_log`'s keywords for a user's log."""
    src_p, out_p = Path(src), Path(out)
    if to not in FORMATS:
        raise GyrolabError(f"convert: unknown format {to!r} (one of {', '.join(FORMATS)})")
    if to in _LIBS:
        import importlib.util

        if importlib.util.find_spec(_LIBS[to]) is None:
            raise GyrolabError(
                f"convert --to {to} needs the {_LIBS[to]} package: "
                f"pip install 'gyrolab[export]' (or pip install {_LIBS[to]})"
            )
    check_output(out_p, force, inputs=(src_p,), kind="file")  # never the input (outputs.py)
    from gyrolab.logs import detect_format

    if detect_format(src_p) != "gyrolab":  # a user's log (docs/convert.md, "Users' logs")
        if unit is not None:
            raise InputError(src_p, "--unit is for multi-unit gyrolab recordings, not logs")
        return _convert_log(src_p, to, out_p, force, log_options or {})
    meta = read_metadata(src_p)  # also rejects a missing, foreign or damaged file
    unit = select_unit(src_p, unit)
    counts = _summary(src_p)
    rate_topic = unit_topic(TOPIC_RATE, unit)
    if counts.get(rate_topic, 0) == 0:
        raise InputError(src_p, f"recording has no {rate_topic} data")
    # a unit whose bench took its internal sensor has that topic and no PT100 (the reader's
    # rule, gyrolab.record.reader.read_recording)
    internal = unit is not None and counts.get(unit_topic(TOPIC_PT100, unit), 0) == 0
    internal = internal and counts.get(unit_topic(TOPIC_TEMPERATURE_INTERNAL, unit), 0) > 0
    # log_time = start + t (docs/recording-format.md): the start from the first rate block
    _topic, ts, data = next(iter_messages(src_p, [TOPIC_RATE], unit=unit))
    first = decode_block(data, "rate")
    start_ns = ts - int(round(first[0] * 1e9))
    tables = RunTables(
        metadata=meta,
        has_adc=counts.get(unit_topic(TOPIC_ADC, unit), 0) > 0,
        start_time_ns=start_ns,
        axes=1 if first[3].ndim == 1 else int(first[3].shape[1]),
        unit=unit,
        temperature_source="internal" if internal else "pt100",
    )
    blocks = iter_sample_blocks(src_p, tables)
    return _write_table(src_p, to, out_p, force, tables, blocks, counts[rate_topic], "block")


def _write_table(
    src: Path,
    to: str,
    out: Path,
    force: bool,
    tables: RunTables,
    blocks: Iterator[dict[str, np.ndarray]],
    total: int,
    unit: str,
) -> dict[str, Any]:
    """Write ``blocks`` as ``to`` into ``out`` (atomically), with a progress bar of
    ``total`` blocks or samples; the conversion's summary."""
    bar = progress(total=total, desc=f"convert → {to}", unit=unit)

    def counted() -> Iterator[dict[str, np.ndarray]]:
        for b in blocks:
            bar.update(1 if unit == "block" else b["t_s"].size)
            yield b

    try:
        with atomic_file(out, force, inputs=(src,)) as tmp:
            rows = _WRITERS[to](tmp, counted(), tables, src)
    finally:
        bar.close()
    return {"rows": rows, "gaps": tables.gaps, "format": to, "out": str(out)}


def _convert_log(
    src: Path, to: str, out: Path, force: bool, options: dict[str, Any]
) -> dict[str, Any]:
    """A user's log (ULog, DataFlash, ROS 2 MCAP) read into memory by
    :func:`gyrolab.logs.read_log` — sensor frame, uncorrected — written as the log table
    (:func:`log_columns`)."""
    from gyrolab.logs import read_log

    rec = read_log(src, **options)
    rate = rec.require_rate()
    if rate.axes != 3:
        raise InputError(src, f"log gyro has {rate.axes} axes, expected x, y, z")
    tables = RunTables(
        metadata={"run": rec.run},
        has_adc=False,
        start_time_ns=0,  # users' logs: times are since the log's first gyro sample
        axes=3,
        temperature_source="internal",
        foreign=True,
        has_accel=rec.accel is not None,
    )
    blocks = iter_log_blocks(rec, tables)
    return _write_table(src, to, out, force, tables, blocks, rate.t.size, "sample")

