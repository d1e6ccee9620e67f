"""ArduPilot DataFlash ``.bin``: one IMU's gyro (and accelerometer) in the sensor frame,
uncorrected.

ArduPilot logs each IMU after its corrections (docs/export.md "Users' logs";
:mod:`gyrolab.autopilot.ardupilot`): temperature-corrected (``INS_TCALn_*`` while
``INS_TCALn_ENABLE`` is 1, relative to ``INS_GYRn_CALTEMP``), minus the offsets
(``INS_GYROFFS_*`` …) and rotated to the body frame by ``AHRS_ORIENTATION``. A drift model
must be fitted on what the sensor put out, so this reader reads the log's ``PARM``
messages and undoes the three, as ArduPilot's ``Tools/scripts/tempcal_IMU.py`` does before
its own fit, with the values in force at each sample's time (a parameter logged again
later applies from then on; before its first ``PARM`` the first logged value holds). The
accelerometer likewise (``INS_TCALn_ACC*``, ``INS_ACC*OFFS_*``, ``INS_ACC*SCAL_*``,
``INS_ACCn_CALTEMP``).

Messages: ``IMU`` with its instance field ``I`` (ArduPilot ≥ 4.0), or, in older logs,
``IMU`` / ``IMU2`` / ``IMU3`` for instances 0 / 1 / 2. ``TimeUS`` is µs since boot, ``T``
the IMU's own temperature sensor (the one INS_TCAL uses). Read with ``pymavlink``'s
``DFReader`` (its index of message offsets), the columns gathered with numpy in the layout
of the log's own ``FMT`` records.

**Checked reads.** DataFlash has no checksum, so the reader checks what it can: every byte
of the file belongs to one message whose header and type the log defines (a skipped or
unknown byte run is damage; only the last 528 bytes may be block padding, as pymavlink
allows), the IMU's time stamps increase, its values are finite. Anything else is one line
naming the file and where, never data read past damage.
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
from collections.abc import Iterator
from typing import Any

import numpy as np

from gyrolab.errors import InputError
from gyrolab.record.reader import Recording

# DataFlash format characters (the FMT record's) → numpy field type; the scale pymavlink
# applies to a few of them (DFReader.FORMAT_TO_STRUCT) is applied after the gather
_NP = {
    "a": "S64",  # int16[32], read as bytes (pymavlink: "64s")
    "b": "i1",
    "B": "u1",
    "g": "<f2",
    "h": "<i2",
    "H": "<u2",
    "i": "<i4",
    "I": "<u4",
    "f": "<f4",
    "n": "S4",
    "N": "S16",
    "Z": "S64",
    "c": "<i2",
    "C": "<u2",
    "e": "<i4",
    "E": "<u4",
    "L": "<i4",
    "d": "<f8",
    "M": "i1",
    "q": "<i8",
    "Q": "<u8",
}
COLUMNS = ("TimeUS", "GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ", "T")
# Trailing bytes pymavlink's indexer tolerates as block-log padding (DFReader.init_arrays).
TRAILING_PADDING = 528


def _columns(log: Any, name: str) -> dict[str, np.ndarray] | None:
    """Every message ``name`` as columns, gathered with numpy at pymavlink's offsets in the
    layout of the log's FMT record, scaled as pymavlink scales them (``{}`` when the log has
    no such message; None when its layout is not one numpy can view: then pymavlink
    decodes the messages one by one)."""
    mtype = getattr(log, "name_to_id", {}).get(name)
    offsets = getattr(log, "offsets", None)
    if mtype is None or not isinstance(offsets, list):
        return {}
    fmt = log.formats[mtype]
    chars = list(fmt.format)
    if len(chars) != len(fmt.columns) or any(c not in _NP for c in chars):
        return None
    dt = np.dtype([(col, _NP[c]) for col, c in zip(fmt.columns, chars, strict=True)])
    if dt.itemsize != fmt.len - 3:
        return None
    offs = np.asarray(offsets[mtype], dtype=np.int64) + 3
    raw = np.frombuffer(log.data_map, dtype=np.uint8)
    offs = offs[offs + dt.itemsize <= raw.size]  # a message cut by the end of the file
    rec = raw[offs[:, None] + np.arange(dt.itemsize)].copy().view(dt).ravel()
    out = {}
    for col, mult in zip(fmt.columns, fmt.msg_mults, strict=True):
        out[col] = rec[col] if mult is None else rec[col] * mult
    return out


def _columns_slow(log: Any, name: str) -> dict[str, np.ndarray]:
    """The same through pymavlink message by message (multipliers applied by it)."""
    log.rewind()
    rows: list[Any] = []
    cols: list[str] = []
    while (m := log.recv_match(type=name)) is not None:
        cols = cols or list(m.get_fieldnames())
        rows.append(tuple(getattr(m, c) for c in cols))
    log.rewind()
    return {c: np.asarray([r[j] for r in rows]) for j, c in enumerate(cols)}


def imu_rows(log: Any, instance: int) -> np.ndarray:
    """``(n, 8)`` TimeUS·1e-6, GyrX/Y/Z, AccX/Y/Z, T of IMU ``instance``: the ``IMU``
    messages whose ``I`` is the instance, or the older per-instance ``IMU``/``IMU2``/``IMU3``
    messages (empty when the log has none of that instance)."""
    names = getattr(log, "name_to_id", {})
    new_style = "IMU" in names and "I" in log.formats[names["IMU"]].columns
    name = "IMU" if new_style or instance == 0 else f"IMU{instance + 1}"
    if name not in names:
        return np.empty((0, len(COLUMNS)))
    cols = _columns(log, name)
    if cols is None:
        cols = _columns_slow(log, name)
    if not cols:
        return np.empty((0, len(COLUMNS)))
    missing = [c for c in COLUMNS if c not in cols]
    if missing:
        raise ValueError(f"{name} messages lack {', '.join(missing)}")
    keep = np.ones(cols["TimeUS"].size, bool)
    if new_style:
        keep = cols["I"] == instance
    out = np.column_stack([np.asarray(cols[c], dtype=np.float64)[keep] for c in COLUMNS])
    out[:, 0] *= 1e-6
    return out


def parameter_timeline(log: Any) -> list[tuple[float, str, float]]:
    """Every ``PARM`` message as ``(t_s, name, value)`` in file order."""
    cols = _columns(log, "PARM")
    if cols is None:
        cols = _columns_slow(log, "PARM")
    if not cols:
        return []
    names = [bytes(n).split(b"\0", 1)[0].decode("ascii", "replace") for n in cols["Name"]]
    return list(
        zip(
            (np.asarray(cols["TimeUS"], dtype=np.float64) * 1e-6).tolist(),
            names,
            np.asarray(cols["Value"], dtype=np.float64).tolist(),
            strict=True,
        )
    )


def check_layout(log: Any, path: str | os.PathLike[str]) -> None:
    """Every byte of the file in exactly one message the log defines (module doc);
    InputError naming the first byte that is not."""
    starts: list[np.ndarray] = []
    ends: list[np.ndarray] = []
    for mtype, offs in enumerate(getattr(log, "offsets", [])):
        if not offs:
            continue
        fmt = log.formats.get(mtype)
        if fmt is None:
            raise InputError(path, f"damaged DataFlash log: unknown message type {mtype}")
        o = np.asarray(offs, dtype=np.int64)
        starts.append(o)
        ends.append(o + int(fmt.len))
    if not starts:
        raise InputError(path, "damaged DataFlash log: no messages")
    s = np.concatenate(starts)
    e = np.concatenate(ends)
    order = np.argsort(s, kind="stable")
    s, e = s[order], e[order]
    size = int(log.data_len)
    if s[0] != 0:
        raise InputError(path, f"damaged DataFlash log: {s[0]} unreadable bytes at its start")
    bad = np.flatnonzero(s[1:] != e[:-1])
    if bad.size:
        k = int(bad[0])
        what = "overlapping messages" if s[k + 1] < e[k] else "unreadable bytes"
        raise InputError(path, f"damaged DataFlash log: {what} at byte {int(e[k])}")
    if e[-1] > size:
        # the last message cut by the end of the file (logging stopped mid-write): it is
        # not read (the gather drops it), the rest is whole
        e = e[:-1]
    tail = size - int(e[-1]) if e.size else size
    if tail > TRAILING_PADDING:
        raise InputError(
            path, f"damaged DataFlash log: the messages stop {tail} bytes before its end"
        )


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    """pymavlink's indexer (its C extension too) reports every bad byte on the process's
    stderr: silenced while the log is indexed, since :func:`check_layout` reports the
    damage in one line."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 1)
        os.dup2(null, 2)
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, null):
            os.close(fd)


def _in_force(
    timeline: list[tuple[float, str, float]], wanted: set[str], times: np.ndarray
) -> list[tuple[int, int, dict[str, float]]]:
    """Segments ``(i0, i1, params)`` of the samples at ``times``: the wanted parameters'
    values in force from sample i0 up to i1 (the first logged value before its first
    change; every later PARM from its time on)."""
    first: dict[str, float] = {}
    changes: list[tuple[float, str, float]] = []
    for t, name, value in timeline:
        if name not in wanted:
            continue
        if name not in first:
            first[name] = value
        else:
            changes.append((t, name, value))
    state = dict(first)
    segments: list[tuple[int, int, dict[str, float]]] = []
    i0 = 0
    for t, name, value in changes:
        i1 = int(np.searchsorted(times, t, side="left"))
        if i1 > i0:
            segments.append((i0, i1, dict(state)))
            i0 = i1
        state[name] = value
    segments.append((i0, times.size, dict(state)))
    return segments


def relevant_parameters(instance: int) -> set[str]:
    """The parameters that shape IMU ``instance``'s logged gyro and accelerometer."""
    from gyrolab.autopilot import ardupilot as ap

    n = instance + 1
    names = {ap.BOARD_ORIENTATION, ap.caltemp_name(instance), f"INS_ACC{n}_CALTEMP"}
    names |= set(ap.tcal_names(instance)) | set(ap.gyro_offset_names(instance))
    names |= {f"INS_TCAL{n}_ACC{k}_{a}" for k in (1, 2, 3) for a in ap.AXES}
    names |= set(ap.accel_offset_names(instance)) | set(ap.accel_scale_names(instance))
    return names


def read_dataflash(path: str | os.PathLike[str], *, instance: int = 0) -> Recording:
    """IMU ``instance`` of a DataFlash log → :class:`Recording` (3 axes, °/s, sensor frame,
    uncorrected; temperature °C; accelerometer m/s² in ``rec.accel``)."""
    from pymavlink import DFReader

    from gyrolab.autopilot import ardupilot as ap
    from gyrolab.logs.series import build_recording

    try:
        with _quiet():
            log = DFReader.DFReader_binary(str(path), zero_time_base=True)
    except Exception as e:  # pymavlink raises many types on damaged files
        raise InputError(path, f"cannot read the DataFlash log ({e})") from None
    check_layout(log, path)
    try:
        rows = imu_rows(log, instance)
        timeline = parameter_timeline(log)
    except Exception as e:
        raise InputError(path, f"cannot read the DataFlash log ({e})") from None
    if rows.shape[0] == 0:
        have = imu_instances(log)
        raise InputError(
            path, f"no IMU messages of instance {instance} (instances in the log: {have})"
        )
    if not np.all(np.isfinite(rows)):
        raise InputError(path, f"damaged DataFlash log: non-finite IMU {instance} values")
    if np.any(np.diff(rows[:, 0]) < 0):
        raise InputError(path, f"damaged DataFlash log: IMU {instance} time stamps go back")
    t, temp = rows[:, 0], rows[:, 7]
    gyro = np.empty((t.size, 3))
    acc = np.empty((t.size, 3))
    wanted = relevant_parameters(instance)
    segments = _in_force(timeline, wanted, t)
    try:
        for i0, i1, p in segments:
            gyro[i0:i1] = ap.uncorrect(rows[i0:i1, 1:4], temp[i0:i1], p, instance)
            acc[i0:i1] = ap.uncorrect_accel(rows[i0:i1, 4:7], temp[i0:i1], p, instance)
    except ValueError as e:  # a board orientation outside the enum, e.g. ROTATION_CUSTOM
        raise InputError(path, f"cannot undo AHRS_ORIENTATION: {e}") from None
    t0 = float(t.min())
    used = {k: v for k, v in segments[0][2].items() if k in wanted}
    rec = build_recording(
        path,
        t - t0,
        gyro,
        t - t0,
        temp,
        {
            "source": "ardupilot-dataflash",
            "message": "IMU" if instance == 0 or "I" in _imu_columns(log) else f"IMU{instance + 1}",
            "instance": instance,
            "frame": "sensor (AHRS_ORIENTATION undone), uncorrected (INS_TCAL, offsets undone)",
            "parameters": dict(sorted(used.items())),
            "parameter_changes": len(segments) - 1,
        },
        accel_m_s2=acc,
    )
    return rec


def _imu_columns(log: Any) -> list[str]:
    mtype = getattr(log, "name_to_id", {}).get("IMU")
    return [] if mtype is None else list(log.formats[mtype].columns)


def imu_instances(log: Any) -> list[int]:
    """The IMU instances a log holds."""
    names = getattr(log, "name_to_id", {})
    if "IMU" in names and "I" in _imu_columns(log):
        cols = _columns(log, "IMU") or _columns_slow(log, "IMU")
        return sorted({int(i) for i in np.unique(cols.get("I", np.empty(0)))})
    out = [0] if "IMU" in names and log.counts[names["IMU"]] else []
    return out + [k - 1 for k in (2, 3) if f"IMU{k}" in names and log.counts[names[f"IMU{k}"]]]
