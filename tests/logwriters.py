"""Writers of small foreign logs for the tests: a ROS 2 bag through mcap-ros2-support, and a
PX4 ULog and an ArduPilot DataFlash log written byte by byte from their specifications
(read back by pyulog / pymavlink in the tests, so a wrong byte fails there)."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

IMU_MSGDEF = """std_msgs/Header header
geometry_msgs/Quaternion orientation
float64[9] orientation_covariance
geometry_msgs/Vector3 angular_velocity
float64[9] angular_velocity_covariance
geometry_msgs/Vector3 linear_acceleration
float64[9] linear_acceleration_covariance
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
================================================================================
MSG: geometry_msgs/Quaternion
float64 x 0
float64 y 0
float64 z 0
float64 w 1
================================================================================
MSG: geometry_msgs/Vector3
float64 x
float64 y
float64 z
"""

TEMPERATURE_MSGDEF = """std_msgs/Header header
float64 temperature
float64 variance
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""


def _header(t: float | None) -> dict:
    if t is None:  # a driver that leaves the stamp at zero
        return {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": "imu"}
    sec = int(np.floor(t))
    return {"stamp": {"sec": sec, "nanosec": int(round((t - sec) * 1e9))}, "frame_id": "imu"}


def write_ros2(
    path: Path,
    t: np.ndarray,
    gyro: np.ndarray,
    tt: np.ndarray,
    tc: np.ndarray,
    t0: float,
    stamp: bool = True,
    second_temperature: str | None = None,
) -> Path:
    """``sensor_msgs/msg/Imu`` on /imu/data and ``sensor_msgs/msg/Temperature`` on
    /imu/temperature; times ``t0 + t`` (s) as header stamps (zero stamps when not
    ``stamp``) and MCAP log times, gyro (n, 3) rad/s, temperature °C;
    ``second_temperature``: another Temperature topic (the readings + 10 °C)."""
    from mcap_ros2.writer import Writer

    with open(path, "wb") as fh:
        w = Writer(fh)
        s_imu = w.register_msgdef("sensor_msgs/msg/Imu", IMU_MSGDEF)
        s_tmp = w.register_msgdef("sensor_msgs/msg/Temperature", TEMPERATURE_MSGDEF)
        z9 = [0.0] * 9
        events = [(float(x), 0, i) for i, x in enumerate(t)] + [
            (float(x), 1, i) for i, x in enumerate(tt)
        ]
        for time_s, kind, i in sorted(events):
            ns = int(round((t0 + time_s) * 1e9))
            if kind == 0:
                g = gyro[i]
                msg = {
                    "header": _header(t0 + time_s if stamp else None),
                    "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
                    "orientation_covariance": [-1.0] + z9[1:],
                    "angular_velocity": {"x": g[0], "y": g[1], "z": g[2]},
                    "angular_velocity_covariance": z9,
                    "linear_acceleration": {"x": 0.0, "y": 0.0, "z": 9.81},
                    "linear_acceleration_covariance": z9,
                }
                w.write_message("/imu/data", s_imu, msg, log_time=ns, publish_time=ns)
            else:
                msg = {
                    "header": _header(t0 + time_s if stamp else None),
                    "temperature": tc[i],
                    "variance": 0.0,
                }
                w.write_message("/imu/temperature", s_tmp, msg, log_time=ns, publish_time=ns)
                if second_temperature:
                    msg2 = {**msg, "temperature": tc[i] + 10.0}
                    w.write_message(second_temperature, s_tmp, msg2, log_time=ns, publish_time=ns)
        w.finish()
    return path


def _ulog_msg(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), kind[0]) + payload


def write_ulog(
    path: Path, t_us: np.ndarray, gyro: np.ndarray, temp_c: np.ndarray, device_id: int
) -> Path:
    """A ULog (file format version 1) with one ``sensor_gyro`` instance: header, flag bits,
    format, subscription and one data message per sample."""
    fmt = (
        b"sensor_gyro:uint64_t timestamp;uint64_t timestamp_sample;uint32_t device_id;"
        b"float x;float y;float z;float temperature;uint32_t error_count;"
    )
    out = bytearray(b"ULog\x01\x12\x35" + bytes([1]) + struct.pack("<Q", int(t_us[0])))
    out += _ulog_msg(b"B", bytes(8) + bytes(8) + bytes(24))  # no flags, no appended data
    out += _ulog_msg(b"F", fmt)
    info = b"char[9] sys_name"
    out += _ulog_msg(b"I", bytes([len(info)]) + info + b"gyrolab-t")
    out += _ulog_msg(b"A", struct.pack("<BH", 0, 7) + b"sensor_gyro")
    for k in range(t_us.size):
        payload = struct.pack(
            "<HQQIffffI",
            7,
            int(t_us[k]) + 50,
            int(t_us[k]),
            device_id,
            *(float(v) for v in gyro[k]),
            float(temp_c[k]),
            0,
        )
        out += struct.pack("<HB", len(payload), ord("D")) + payload
    path.write_bytes(bytes(out))
    return path


FMT_TYPE = 128
IMU_TYPE = 131
IMU_FORMAT = "QBffffffIIfBBHH"
IMU_COLUMNS = "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz"


def _fmt(type_: int, length: int, name: str, fmt: str, cols: str) -> bytes:
    return b"\xa3\x95" + struct.pack(
        "<BBB4s16s64s", FMT_TYPE, type_, length, name.encode(), fmt.encode(), cols.encode()
    )


PARM_TYPE = 64


def _parm(t_us: int, name: str, value: float) -> bytes:
    return b"\xa3\x95" + struct.pack("<BQ16sf", PARM_TYPE, t_us, name.encode(), value)


def write_dataflash(
    path: Path,
    t_us: np.ndarray,
    gyro: np.ndarray,
    temp_c: np.ndarray,
    instance: int = 0,
    *,
    accel: np.ndarray | None = None,
    params: list[tuple[int, str, float]] = (),  # type: ignore[assignment]
) -> Path:
    """A DataFlash log: FMT of FMT, FMT of ArduPilot's IMU (and PARM) message, the
    ``params`` as PARM messages at their times (µs), one IMU per sample (the accelerometer
    ``accel``, m/s², else 0, 0, −9.81)."""
    imu_len = 3 + struct.calcsize("<" + IMU_FORMAT)
    out = bytearray(_fmt(FMT_TYPE, 89, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns"))
    out += _fmt(IMU_TYPE, imu_len, "IMU", IMU_FORMAT, IMU_COLUMNS)
    out += _fmt(PARM_TYPE, 3 + struct.calcsize("<Q16sf"), "PARM", "QNf", "TimeUS,Name,Value")
    pending = sorted(params)
    acc = np.tile([0.0, 0.0, -9.81], (t_us.size, 1)) if accel is None else accel
    for k in range(t_us.size):
        while pending and pending[0][0] <= t_us[k]:
            out += _parm(*pending.pop(0))
        out += b"\xa3\x95" + struct.pack(
            "<BQBffffffIIfBBHH",
            IMU_TYPE,
            int(t_us[k]),
            instance,
            *(float(v) for v in gyro[k]),
            *(float(v) for v in acc[k]),
            0,
            0,
            float(temp_c[k]),
            1,
            1,
            400,
            400,
        )
    path.write_bytes(bytes(out))
    return path
