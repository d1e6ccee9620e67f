"""ArduPilot DataFlash ``.bin``: the ``IMU`` message (GyrX/Y/Z in rad/s, ``T`` in °C).

Read with ``pymavlink``'s ``DFReader`` (https://ardupilot.org/dev/docs/code-overview-adding-a-new-log-message.html
for the FMT/message layout). The time of a sample is ``TimeUS`` (µs since boot); ``I`` is
the IMU instance (0, 1, 2); ``T`` is the IMU's own temperature sensor, the one ArduPilot's
INS_TCALn compensation uses.
"""

from __future__ import annotations

import os
import re
from typing import Any

import numpy as np

from gyrolab.errors import InputError
from gyrolab.record.reader import Recording

_NP = {
    "b": "i1",
    "B": "u1",
    "h": "<i2",
    "H": "<u2",
    "i": "<i4",
    "I": "<u4",
    "f": "<f4",
    "d": "<f8",
    "q": "<i8",
    "Q": "<u8",
    "s": "S",
}
COLUMNS = ("TimeUS", "GyrX", "GyrY", "GyrZ", "T")


def imu_rows_fast(log: Any, instance: int) -> np.ndarray | None:
    """``(n, 5)`` TimeUS·1e-6, GyrX/Y/Z, T of the IMU messages of ``instance``, gathered with
    numpy at the offsets pymavlink's index found, with the field layout of the log's own FMT
    record (``None`` when the index or a field type is not the expected kind, or a field it
    needs carries a multiplier: then the message-by-message path reads it)."""
    mtype = getattr(log, "name_to_id", {}).get("IMU")
    offsets = getattr(log, "offsets", None)
    if mtype is None or not isinstance(offsets, list) or not offsets[mtype]:
        return None
    fmt = log.formats[mtype]
    fields = re.findall(r"(\d*)([a-zA-Z])", fmt.msg_struct.lstrip("<"))
    if len(fields) != len(fmt.columns) or any(c not in _NP for _n, c in fields):
        return None
    if any(
        fmt.msg_mults[fmt.columns.index(c)] not in (None, 1)
        for c in (*COLUMNS, "I")
        if c in fmt.columns
    ):
        return None
    dt = np.dtype(
        [
            (col, f"S{n or 1}" if c == "s" else _NP[c])
            for col, (n, c) in zip(fmt.columns, fields, strict=True)
        ]
    )
    if dt.itemsize != fmt.len - 3 or not set(COLUMNS) <= set(fmt.columns):
        return None
    raw = np.frombuffer(log.data_map, dtype=np.uint8)
    offs = np.asarray(offsets[mtype], dtype=np.int64) + 3
    rec = raw[offs[:, None] + np.arange(dt.itemsize)].copy().view(dt).ravel()
    if "I" in fmt.columns:
        rec = rec[rec["I"] == instance]
    elif instance != 0:
        rec = rec[:0]
    return np.column_stack(
        [rec["TimeUS"] * 1e-6, *(rec[c].astype(np.float64) for c in COLUMNS[1:])]
    )


def read_dataflash(path: str | os.PathLike[str], *, instance: int = 0) -> Recording:
    """A DataFlash log → :class:`Recording` (3 axes, °/s; temperature °C)."""
    from pymavlink import DFReader

    from gyrolab.logs import build_recording

    rows: list[tuple[float, float, float, float, float]] = []
    try:
        log = DFReader.DFReader_binary(str(path), zero_time_base=True)
        fast = imu_rows_fast(log, instance)
        if fast is not None and fast.size:
            rows = fast  # type: ignore[assignment]
        while fast is None:
            m = log.recv_match(type="IMU")
            if m is None:
                break
            if int(getattr(m, "I", 0)) != instance:
                continue
            rows.append((m.TimeUS * 1e-6, m.GyrX, m.GyrY, m.GyrZ, m.T))
    except Exception as e:  # pymavlink raises many types on damaged files
        raise InputError(path, f"cannot read the DataFlash log ({e})") from None
    if len(rows) == 0:
        raise InputError(path, f"no IMU messages of instance {instance}")
    a = np.asarray(rows, dtype=np.float64)
    t0 = float(a[:, 0].min())
    return build_recording(
        path,
        a[:, 0] - t0,
        a[:, 1:4],
        a[:, 0] - t0,
        a[:, 4],
        {"source": "ardupilot-dataflash", "message": "IMU", "instance": instance},
    )
