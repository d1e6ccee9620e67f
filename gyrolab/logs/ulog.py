"""PX4 ULog: the ``sensor_gyro`` topic (x, y, z in rad/s, ``temperature`` in °C).

Read with ``pyulog`` (https://docs.px4.io/main/en/dev_log/ulog_file_format.html). The time
of a sample is ``timestamp_sample`` (µs, when the sensor sampled it; ``timestamp`` when the
field is absent); the temperature is the same message's ``temperature`` — the IMU's own
sensor, which is then the temperature the fitted model expects (PX4 compensates with it).
``instance`` is the uORB multi-instance (gyro 0, 1, ...).
"""

from __future__ import annotations

import os

import numpy as np

from gyrolab.errors import InputError
from gyrolab.record.reader import Recording


def read_ulog(path: str | os.PathLike[str], *, instance: int = 0) -> Recording:
    """A ULog → :class:`Recording` (3 axes, °/s; temperature °C)."""
    from pyulog import ULog

    from gyrolab.logs import build_recording

    try:
        log = ULog(str(path), ["sensor_gyro"])
    except Exception as e:  # pyulog raises many types on damaged files
        raise InputError(path, f"cannot read the ULog ({e})") from None
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
    return build_recording(
        path,
        ts - t0,
        g,
        ts - t0,
        data["temperature"].astype(np.float64),
        {
            "source": "px4-ulog",
            "topic": "sensor_gyro",
            "instance": instance,
            "device_id": int(np.median(data["device_id"])) if "device_id" in data else None,
            "start_timestamp_us": t0 * 1e6,
        },
    )
