"""A foreign log's samples as gyrolab's in-memory recording: the common tail of every
reader of :mod:`gyrolab.logs` (below the readers, so that none imports its package)."""

from __future__ import annotations

import os

import numpy as np

from gyrolab.errors import InputError
from gyrolab.record.reader import Recording, Series

RAD2DEG = float(180.0 / np.pi)


def make_series(t_s: np.ndarray, values: np.ndarray, scale: float = 1.0) -> Series:
    """Samples at times ``t_s`` (sorted, duplicated stamps dropped) as a :class:`Series`
    indexed by its nominal period (the median spacing), so that lost samples stay gaps."""
    t = np.asarray(t_s, dtype=float)
    v = np.asarray(values, dtype=float)
    order = np.argsort(t, kind="stable")
    t, v = t[order], v[order]
    keep = np.concatenate([[True], np.diff(t) > 0])  # duplicated stamps: keep the first
    t, v = t[keep], v[keep]
    period = float(np.median(np.diff(t))) if t.size > 1 else float("nan")
    if not period > 0:
        raise ValueError("time stamps do not advance")
    return Series(t, v * scale, np.rint((t - t[0]) / period).astype(np.int64), period)


def build_recording(
    path: str | os.PathLike[str],
    t_s: np.ndarray,
    gyro_rad_s: np.ndarray,
    temp_t_s: np.ndarray,
    temp_c: np.ndarray,
    run: dict,
    *,
    accel_m_s2: np.ndarray | None = None,
) -> Recording:
    """The common tail of every reader: sort by time, convert rad/s → °/s, index the samples
    by nominal period (median spacing) so that gaps stay gaps, drop non-finite temperature
    readings, and check there is something to work with. ``accel_m_s2``: the accelerometer
    at the same samples (m/s²), kept as ``rec.accel`` on the same index."""
    t = np.asarray(t_s, dtype=float)
    if t.size < 2:
        raise InputError(path, "log has fewer than 2 gyro samples")
    try:
        rate = make_series(t, gyro_rad_s, RAD2DEG)
        accel = None if accel_m_s2 is None else make_series(t, accel_m_s2)
    except ValueError:
        raise InputError(path, "gyro time stamps do not advance") from None
    tt = np.asarray(temp_t_s, dtype=float)
    tc = np.asarray(temp_c, dtype=float)
    ok = np.isfinite(tt) & np.isfinite(tc)
    tt, tc = tt[ok], tc[ok]
    if tt.size == 0:
        raise InputError(path, "log has no finite temperature readings: nothing to model")
    o = np.argsort(tt, kind="stable")
    rec = Recording(path=str(path))
    rec.run = dict(run)
    rec.rate = rate
    rec.accel = accel
    rec.pt100_t, rec.pt100_c = tt[o], tc[o]
    rec.pt100_ohm = np.full(tt.size, np.nan)
    rec.topic_counts = {"gyro": int(rate.t.size), "temperature": int(tt.size)}
    return rec
