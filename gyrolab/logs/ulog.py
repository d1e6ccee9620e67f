"""PX4 ULog: the ``sensor_gyro`` topic — the sensor frame, before any calibration or thermal
compensation — with its temperature, ``sensor_accel`` beside it, and the TC parameters.

Which topic is uncorrected (PX4 source, docs/export.md): a driver publishes
``sensor_gyro`` through ``PX4Gyroscope::update`` (``src/lib/drivers/gyroscope/``), which
only rotates the sample by the sensor's mounting on the board and scales it. The thermal
offsets (``TC_G*``, module ``temperature_compensation``), the ``CAL_GYRO*`` offsets and
``SENS_BOARD_ROT`` are applied downstream, in ``vehicle_imu`` / ``vehicle_angular_velocity``
(``calibration::Gyroscope::Correct``). So ``sensor_gyro`` needs nothing undone, and
``vehicle_imu`` or ``vehicle_angular_velocity`` would (they are not read). The log's
parameters are read and recorded: ``TC_G_ENABLE``, the ``TC_Gi_*`` set whose ``TC_Gi_ID``
is this gyro's ``device_id`` (what the firmware was applying downstream while the log was
written), the gyro's ``CAL_GYROi_*`` and ``SENS_BOARD_ROT``.

Read with ``pyulog`` (https://docs.px4.io/main/en/dev_log/ulog_file_format.html). The time
of a sample is ``timestamp_sample`` (µs, when the sensor sampled it; ``timestamp`` when the
field is absent); the temperature is the same message's ``temperature`` — the IMU's own
sensor, the one PX4 compensates with. ``instance`` is the uORB multi-instance (gyro 0, 1,
...). A file pyulog finds corrupt (``file_corruption``) is refused with one line.
"""

from __future__ import annotations

import contextlib
import io
import os
from typing import Any

import numpy as np

from gyrolab.errors import InputError
from gyrolab.record.reader import Recording


def _load(path: str | os.PathLike[str]) -> Any:
    from pyulog import ULog

    said = io.StringIO()  # pyulog reports problems on stdout: keep them out of ours
    try:
        with contextlib.redirect_stdout(said):
            log = ULog(str(path), ["sensor_gyro", "sensor_accel"])
    except Exception as e:  # pyulog raises many types on damaged files
        raise InputError(path, f"cannot read the ULog ({e})") from None
    if log.file_corruption:
        first = next((ln for ln in said.getvalue().splitlines() if ln.strip()), "")
        detail = f": {first}" if first else ""
        raise InputError(path, f"damaged ULog (pyulog found corruption{detail})")
    return log


def tc_parameters(params: dict[str, Any], device_id: int | None) -> dict[str, Any]:
    """The parameters that act on this gyro downstream of ``sensor_gyro``: ``TC_G_ENABLE``,
    the ``TC_Gi_*`` set matching ``device_id``, the ``CAL_GYROi_*`` slot of that device and
    ``SENS_BOARD_ROT`` (those present in the log)."""
    from gyrolab.autopilot import px4

    out: dict[str, Any] = {}
    for name in ("TC_G_ENABLE", px4.BOARD_ROTATION, *px4.BOARD_LEVEL_OFFSETS):
        if name in params:
            out[name] = params[name]
    if device_id is None:
        return out
    for slot in range(px4.TC_SLOTS):
        if params.get(f"TC_G{slot}_ID") == device_id:
            out.update({n: params[n] for n in px4.tc_names(slot) if n in params})
        if params.get(px4.cal_id_name(slot)) == device_id:
            names = (px4.cal_id_name(slot), *px4.cal_offset_names(slot))
            out.update({n: params[n] for n in names if n in params})
    return out


def read_ulog(path: str | os.PathLike[str], *, instance: int = 0) -> Recording:
    """A ULog → :class:`Recording` (3 axes, °/s, sensor frame; temperature °C;
    ``sensor_accel`` of the same instance in ``rec.accel`` where logged)."""
    from gyrolab.logs.series import build_recording, make_series

    log = _load(path)
    found = [d for d in log.data_list if d.name == "sensor_gyro"]
    if not found:
        raise InputError(path, "ULog has no sensor_gyro topic")
    data = next((d.data for d in found if d.multi_id == instance), None)
    if data is None:
        have = sorted(d.multi_id for d in found)
        raise InputError(path, f"no sensor_gyro instance {instance} (instances {have})")
    if "temperature" not in data:
        raise InputError(path, "sensor_gyro has no temperature field")
    ts = data.get("timestamp_sample", data["timestamp"]).astype(np.float64) * 1e-6
    t0 = float(ts.min())
    g = np.column_stack([data["x"], data["y"], data["z"]]).astype(np.float64)
    device_id = int(np.median(data["device_id"])) if "device_id" in data else None
    params = tc_parameters(dict(log.initial_parameters), device_id)
    changed = [(round(t * 1e-6 - t0, 6), n, v) for t, n, v in log.changed_parameters if n in params]
    rec = build_recording(
        path,
        ts - t0,
        g,
        ts - t0,
        data["temperature"].astype(np.float64),
        {
            "source": "px4-ulog",
            "topic": "sensor_gyro",
            "instance": instance,
            "device_id": device_id,
            "start_timestamp_us": t0 * 1e6,
            "frame": "sensor (board-mounted, before SENS_BOARD_ROT), uncorrected "
            "(sensor_gyro: before CAL_GYRO offsets and TC_G thermal compensation)",
            "parameters": params,
            "parameter_changes": changed,
        },
    )
    acc = next(
        (d.data for d in log.data_list if d.name == "sensor_accel" and d.multi_id == instance),
        None,
    )
    if acc is not None and acc["timestamp"].size >= 2:
        at = acc.get("timestamp_sample", acc["timestamp"]).astype(np.float64) * 1e-6 - t0
        rec.accel = make_series(at, np.column_stack([acc["x"], acc["y"], acc["z"]]))
    return rec
