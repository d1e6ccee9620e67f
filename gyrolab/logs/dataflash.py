"""ArduPilot DataFlash ``.bin``: the ``IMU`` message (GyrX/Y/Z in rad/s, ``T`` in °C).

Read with ``pymavlink``'s ``DFReader`` (https://ardupilot.org/dev/docs/code-overview-adding-a-new-log-message.html
for the FMT/message layout). The time of a sample is ``TimeUS`` (µs since boot); ``I`` is
the IMU instance (0, 1, 2); ``T`` is the IMU's own temperature sensor, the one ArduPilot's
INS_TCALn compensation uses.
"""

from __future__ import annotations

import os

import numpy as np

from gyrolab.errors import InputError
from gyrolab.recording import Recording


def read_dataflash(path: str | os.PathLike[str], *, instance: int = 0) -> Recording:
    """A DataFlash log → :class:`Recording` (3 axes, °/s; temperature °C)."""
    from pymavlink import DFReader

    from gyrolab.logs import build_recording

    rows: list[tuple[float, float, float, float, float]] = []
    try:
        log = DFReader.DFReader_binary(str(path), zero_time_base=True)
        while True:
            m = log.recv_match(type="IMU")
            if m is None:
                break
            if int(getattr(m, "I", 0)) != instance:
                continue
            rows.append((m.TimeUS * 1e-6, m.GyrX, m.GyrY, m.GyrZ, m.T))
    except Exception as e:  # pymavlink raises many types on damaged files
        raise InputError(path, f"cannot read the DataFlash log ({e})") from None
    if not rows:
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
