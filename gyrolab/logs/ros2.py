"""ROS 2 bags in MCAP: ``sensor_msgs/msg/Imu`` + ``sensor_msgs/msg/Temperature``.

Decoded with ``mcap-ros2-support`` (CDR). The gyro is ``angular_velocity`` (rad/s, REP 103
body axes x, y, z) at ``header.stamp`` (the MCAP log time when a driver leaves every stamp
at zero); the temperature is ``temperature`` (°C) of the
``sensor_msgs/msg/Temperature`` topic named on the command line (``--temperature-topic``;
when the bag has exactly one Temperature topic it is taken). Message definitions:
https://docs.ros2.org/latest/api/sensor_msgs/msg/Imu.html and .../Temperature.html.
"""

from __future__ import annotations

import os
import struct
from typing import Any

import numpy as np

from gyrolab.errors import InputError
from gyrolab.record.reader import Recording

IMU = "sensor_msgs/msg/Imu"
TEMPERATURE = "sensor_msgs/msg/Temperature"


def _stamp(msg: Any) -> float:
    return float(msg.header.stamp.sec) + 1e-9 * float(msg.header.stamp.nanosec)


_STAMP_LEN = struct.Struct("<iII")
_VEC3 = struct.Struct("<3d")


def imu_fast(data: bytes) -> tuple[float, ...] | None:
    """``(stamp s, ω_x, ω_y, ω_z, a_x, a_y, a_z)`` of a ``sensor_msgs/msg/Imu`` in
    little-endian plain CDR, read at the fixed offsets its definition gives (``None`` for
    another encapsulation): after the 4-byte encapsulation header, ``header.stamp`` (int32
    sec, uint32 nanosec), ``frame_id`` (uint32 length incl. NUL + bytes), padding to 8 (CDR
    aligns relative to the payload), ``orientation`` (4 float64), its covariance (9
    float64), ``angular_velocity`` (3 float64), its covariance (9), then
    ``linear_acceleration``. :func:`read_ros2` checks it against the library's decoder on
    the bag's first message and uses the library throughout if they differ."""
    if len(data) < 16 or data[0] != 0 or data[1] != 1:
        return None
    sec, nsec, slen = _STAMP_LEN.unpack_from(data, 4)
    rel = 12 + slen
    rel = (rel + 7) & ~7
    off = 4 + rel + 13 * 8
    if off + 24 + 72 + 24 > len(data):
        return None
    wx, wy, wz = _VEC3.unpack_from(data, off)
    ax, ay, az = _VEC3.unpack_from(data, off + 24 + 72)
    return sec + 1e-9 * nsec, wx, wy, wz, ax, ay, az


def _decoded(msg: Any) -> tuple[float, ...]:
    w, a = msg.angular_velocity, msg.linear_acceleration
    return (_stamp(msg), w.x, w.y, w.z, a.x, a.y, a.z)


def _topics_of(path: str | os.PathLike[str]) -> dict[str, str]:
    from gyrolab.record.source import opened

    with opened(path) as src:
        summary = src.summary
    if summary is None:
        raise InputError(path, "MCAP without a summary section: cannot list its topics")
    return {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}


def _pick(path: Any, topics: dict[str, str], kind: str, given: str | None, flag: str) -> str:
    have = sorted(t for t, s in topics.items() if s == kind)
    if given is not None:
        if given not in topics:
            raise InputError(path, f"no topic {given!r} (topics: {', '.join(sorted(topics))})")
        if topics[given] != kind:
            raise InputError(path, f"topic {given!r} is {topics[given]}, not {kind}")
        return given
    if len(have) == 1:
        return have[0]
    if not have:
        raise InputError(path, f"no {kind} topic in this bag")
    raise InputError(path, f"several {kind} topics ({', '.join(have)}): name one with {flag}")


def read_ros2(
    path: str | os.PathLike[str],
    *,
    temperature_topic: str | None = None,
    imu_topic: str | None = None,
) -> Recording:
    """A ROS 2 MCAP → :class:`Recording` (3 axes, °/s; temperature °C; the Imu's
    ``linear_acceleration`` in ``rec.accel``, m/s²)."""
    from mcap_ros2.decoder import DecoderFactory

    from gyrolab.logs.series import build_recording
    from gyrolab.record.source import opened

    factory = DecoderFactory()
    decoders: dict[int, Any] = {}
    fast: bool | None = None  # decided on the first Imu message

    topics = _topics_of(path)
    imu = _pick(path, topics, IMU, imu_topic, "--imu-topic")
    temp = _pick(path, topics, TEMPERATURE, temperature_topic, "--temperature-topic")
    t, g, acc, tt, tc, lt, tlt = [], [], [], [], [], [], []
    try:
        # opened: the bag is checked like every MCAP read (chunk CRCs, gyrolab/record/integrity.py)
        with opened(path) as src:
            schemas, channels = src.schemas(), src.channels()
            for topic, log_time, data, cid, _seq, _pub in src.messages([imu, temp]):
                ch = channels[cid]
                if ch.schema_id not in decoders:
                    schema = schemas[ch.schema_id]
                    decoders[ch.schema_id] = factory.decoder_for(ch.message_encoding, schema)
                decode = decoders[ch.schema_id]
                if topic == imu:
                    lt.append(log_time * 1e-9)
                    r = imu_fast(data) if fast is not False else None
                    if fast is None:
                        fast = r == _decoded(decode(data))
                        r = r if fast else None
                    if r is None:
                        r = _decoded(decode(data))
                    t.append(r[0])
                    g.append(r[1:4])
                    acc.append(r[4:7])
                else:
                    msg = decode(data)
                    tt.append(_stamp(msg))
                    tlt.append(log_time * 1e-9)
                    tc.append(msg.temperature)
    except InputError:
        raise
    except Exception as e:  # decoder/mcap errors on damaged bags
        raise InputError(path, f"cannot decode the ROS 2 bag ({e})") from None
    if not t:
        raise InputError(path, f"topic {imu} has no messages")
    if not tt:
        raise InputError(path, f"topic {temp} has no messages")
    stamped = any(t) and any(tt)
    if not stamped:  # unstamped driver: the recorder's receive times are all there is
        t, tt = lt, tlt
    t0 = min(t)
    return build_recording(
        path,
        np.asarray(t) - t0,
        np.asarray(g),
        np.asarray(tt) - t0,
        np.asarray(tc),
        {
            "source": "ros2",
            "imu_topic": imu,
            "temperature_topic": temp,
            "start_stamp_s": t0,
            "time": "header.stamp" if stamped else "MCAP log_time (header stamps are zero)",
        },
        accel_m_s2=np.asarray(acc),
    )
