"""Read the logs users already have into gyrolab's in-memory recording.

One small dispatch (:func:`read_log`) over one reader per format, each returning the same
:class:`~gyrolab.record.reader.Recording` that a gyrolab MCAP reads into:

* ``rate``: a :class:`~gyrolab.record.reader.Series` of the gyro in °/s, ``(n,)`` for one axis
  or ``(n, 3)`` for x, y, z; its ``index`` counts nominal sample periods since the first
  sample, so dropped samples stay gaps (``Series.gaps()``), never interpolated;
* ``pt100_t`` / ``pt100_c``: the temperature readings (s, °C) the drift model uses;
* ``run``: where it came from (``source``, topic or instance).

Formats, told apart by their first bytes:

=====================  ==============================  ==================================
gyrolab MCAP           header profile ``gyrolab``      `record.reader.read_recording`
ROS 2 MCAP             profile ``ros2``                :mod:`.ros2` (``sensor_msgs/msg/Imu``
                                                       + ``sensor_msgs/msg/Temperature``)
PX4 ULog               magic ``ULog\\x01\\x12\\x35``     :mod:`.ulog` (``sensor_gyro``, pyulog)
ArduPilot DataFlash    message header ``A3 95``        :mod:`.dataflash` (``IMU``, pymavlink)
=====================  ==============================  ==================================

Times are seconds since the log's first gyro sample; rates arrive in rad/s in all three
foreign formats and are converted to °/s (×180/π).
"""

from __future__ import annotations

import os
from pathlib import Path

from gyrolab.errors import InputError, existing_file
from gyrolab.record.reader import Recording

ULOG_MAGIC = b"ULog\x01\x12\x35"
MCAP_MAGIC = b"\x89MCAP0\r\n"
DATAFLASH_HEAD = b"\xa3\x95"


def detect_format(path: str | os.PathLike[str]) -> str:
    """``gyrolab`` | ``ros2`` | ``ulog`` | ``dataflash`` from the file's first bytes."""
    p = existing_file(path)
    with open(p, "rb") as fh:
        head = fh.read(8)
    if head == MCAP_MAGIC:
        return "ros2" if _mcap_profile(p) == "ros2" else "gyrolab"
    if head[:7] == ULOG_MAGIC:
        return "ulog"
    if head[:2] == DATAFLASH_HEAD:
        return "dataflash"
    raise InputError(p, "not an MCAP file (gyrolab or ROS 2), PX4 ULog or ArduPilot DataFlash log")


def _mcap_profile(path: Path) -> str:
    from gyrolab.record.source import opened

    with opened(path) as src:  # checked like every MCAP read (gyrolab/record/integrity.py)
        return str(src.header().profile)


def single_axis_gyrolab(path: str | os.PathLike[str], unit: str | None = None) -> bool:
    """True for a gyrolab MCAP whose ``/gyro/rate`` (unit ``unit``'s, of a multi-unit
    recording) has one axis (streamed as before)."""
    from gyrolab.record.blocks import decode_block
    from gyrolab.record.format import TOPIC_RATE
    from gyrolab.record.reader import iter_messages

    if detect_format(path) != "gyrolab":
        return False
    for _topic, _ts, data in iter_messages(path, [TOPIC_RATE], unit=unit):
        return decode_block(data, "rate")[3].ndim == 1
    return True  # no rate at all: the single-axis path reports it


def read_log(
    path: str | os.PathLike[str],
    *,
    temperature_topic: str | None = None,
    imu_topic: str | None = None,
    instance: int = 0,
) -> Recording:
    """Any supported log → :class:`Recording` (module docstring). ``temperature_topic`` and
    ``imu_topic`` choose ROS 2 topics; ``instance`` the PX4/ArduPilot gyro instance."""
    fmt = detect_format(path)
    if fmt == "gyrolab":
        from gyrolab.record.reader import read_recording

        return read_recording(path)
    if fmt == "ros2":
        from gyrolab.logs.ros2 import read_ros2

        return read_ros2(path, temperature_topic=temperature_topic, imu_topic=imu_topic)
    if fmt == "ulog":
        from gyrolab.logs.ulog import read_ulog

        return read_ulog(path, instance=instance)
    from gyrolab.logs.dataflash import read_dataflash

    return read_dataflash(path, instance=instance)
