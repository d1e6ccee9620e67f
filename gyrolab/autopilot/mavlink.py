"""Which MAVLink message carries which IMU of a flight controller, in which units, how fast.

Message definitions: ``common.xml`` of the MAVLink standard (as shipped with pymavlink,
``message_definitions/v1.0/common.xml``):

=============  ===  ===============================  ===========================================
message        id   time                             fields used
=============  ===  ===============================  ===========================================
RAW_IMU        27   ``time_usec`` (µs)               ``x/y/zgyro`` int16 mrad/s, ``x/y/zacc``
                                                     int16 mG, ``id`` (ext.), ``temperature``
                                                     int16 cdegC (ext.; 0 = none, 0 °C sent as 1)
SCALED_IMU     26   ``time_boot_ms`` (ms)            as RAW_IMU (``temperature`` ext.)
SCALED_IMU2    116  ``time_boot_ms``                 the second IMU
SCALED_IMU3    129  ``time_boot_ms``                 the third IMU
HIGHRES_IMU    105  ``time_usec``                    float rad/s — not used: PX4 sends only the
                                                     selected IMU with the estimator's bias
                                                     removed and the barometer's temperature
=============  ===  ===============================  ===========================================

What each firmware puts in them (the sources):

* **PX4** ``src/modules/mavlink/streams/SCALED_IMU.hpp``, ``SCALED_IMU2.hpp``,
  ``SCALED_IMU3.hpp``: ``vehicle_imu`` instance 0, 1, 2 (the calibrated, thermally
  compensated, board-rotated IMU integrated at ``IMU_INTEG_RATE``, default 200 Hz,
  ``src/modules/sensors/vehicle_imu/imu_parameters.c``) as ``delta_angle/dt·1000``
  converted to int16 (truncation toward zero), ``time_boot_ms = timestamp/1000``, the
  temperature of ``vehicle_imu_status`` (accel's, else gyro's) ``roundf(·100)``; a
  message goes out only when ``vehicle_imu`` updated, so the rate is at most
  ``IMU_INTEG_RATE``; the MAVLink main loop runs at most at 1 kHz and streams are scaled
  down to the link's data rate (``src/modules/mavlink/mavlink_main.cpp``). Rates are set
  with ``MAV_CMD_SET_MESSAGE_INTERVAL`` (511).
* **ArduPilot** ``libraries/GCS_MAVLink/GCS_Common.cpp`` ``send_raw_imu`` /
  ``send_scaled_imu``: RAW_IMU is IMU 0 (``micros64()``), SCALED_IMU2/3 IMU 1/2
  (``millis()``), each ``get_gyro(i)·1000`` (the filtered, TCAL-corrected, body-frame gyro)
  and ``int16_t(get_temperature(i)·100)``. The stream group ``SRn_RAW_SENS`` (0–50 Hz,
  ``GCS_MAVLink_Parameters.cpp``) or ``MAV_CMD_SET_MESSAGE_INTERVAL`` per message; an
  interval is capped at 80 % of the main loop rate (``set_ap_message_interval``: at most
  ``SCHED_LOOP_RATE``·0.8, 320 Hz at Copter's default 400 Hz).

``mrad/s`` int16 quantises the rate to 1 mrad/s (0.0573 °/s) per message: the sensor's own
noise (a few mrad/s at these rates) dithers it, so averages over many messages resolve far
below one step; the truncation toward zero PX4 applies (``float → int16``) is a bias of the
order of the step times the fraction of samples near zero, which the drift model absorbs
as part of the bias.
"""

from __future__ import annotations

import numpy as np

GRAVITY_MSS = 9.80665  # ArduPilot GRAVITY_MSS, PX4 CONSTANTS_ONE_G
IMU_MESSAGES = {
    "px4": ("SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3"),
    "ardupilot": ("RAW_IMU", "SCALED_IMU2", "SCALED_IMU3"),
}
MESSAGE_IDS = {"RAW_IMU": 27, "SCALED_IMU": 26, "SCALED_IMU2": 116, "SCALED_IMU3": 129}
FIRMWARES = tuple(IMU_MESSAGES)
# HEARTBEAT.autopilot (MAV_AUTOPILOT): which firmware answers
MAV_AUTOPILOT = {12: "px4", 3: "ardupilot"}  # MAV_AUTOPILOT_PX4, MAV_AUTOPILOT_ARDUPILOTMEGA
MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN = 246
# the highest rate each firmware streams an IMU message at, with its defaults (Hz)
MAX_RATE_HZ = {"px4": 200.0, "ardupilot": 320.0}


def message_for(firmware: str, instance: int) -> str:
    """The message that carries IMU ``instance`` (0-based) of ``firmware``."""
    names = IMU_MESSAGES[firmware]
    if not 0 <= instance < len(names):
        raise ValueError(f"{firmware} streams IMUs 0..{len(names) - 1}, not {instance}")
    return names[instance]


def time_s(msg: object) -> float:
    """The message's time stamp, s since the controller booted."""
    t_us = getattr(msg, "time_usec", None)
    if t_us is not None:
        return float(t_us) * 1e-6
    return float(msg.time_boot_ms) * 1e-3  # type: ignore[attr-defined]


def gyro_rad_s(msg: object) -> np.ndarray:
    """``(x, y, z)`` rad/s from an IMU message's mrad/s fields."""
    return np.array([msg.xgyro, msg.ygyro, msg.zgyro], dtype=np.float64) * 1e-3  # type: ignore[attr-defined]


def accel_m_s2(msg: object) -> np.ndarray:
    """``(x, y, z)`` m/s² from an IMU message's mG fields."""
    return np.array([msg.xacc, msg.yacc, msg.zacc], dtype=np.float64) * (GRAVITY_MSS * 1e-3)  # type: ignore[attr-defined]


def temperature_c(msg: object) -> float:
    """The IMU temperature, °C (NaN when the message says it has none: 0)."""
    c = int(getattr(msg, "temperature", 0) or 0)
    return float("nan") if c == 0 else c * 0.01


def encode_temperature(temp_c: float, firmware: str) -> int:
    """cdegC as the firmware writes it: PX4 ``roundf`` (0 sent as 1), ArduPilot
    ``int16_t(T·100)`` (truncation)."""
    v = temp_c * 100.0
    c = int(round(v)) if firmware == "px4" else int(v)
    c = max(-32768, min(32767, c))
    return 1 if c == 0 else c


def encode_mrad_s(rate_rad_s: np.ndarray) -> list[int]:
    """rad/s → the int16 mrad/s fields: C's float → int16 conversion truncates toward 0."""
    v = np.trunc(np.asarray(rate_rad_s, dtype=np.float32) * np.float32(1000.0))
    return [int(x) for x in np.clip(v, -32768, 32767)]


def encode_mg(accel_m_s2: np.ndarray) -> list[int]:
    """m/s² → the int16 mG fields (``accel·1000/g``, truncated)."""
    v = np.trunc(np.asarray(accel_m_s2, dtype=np.float32) * np.float32(1000.0 / GRAVITY_MSS))
    return [int(x) for x in np.clip(v, -32768, 32767)]


# MAV_PARAM_TYPE (common.xml) and how each firmware puts a parameter in PARAM_VALUE's /
# PARAM_SET's float ``param_value`` (mavlink.io "Parameter Protocol", parameter encoding):
# PX4 copies the integer's bytes into the float (MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE,
# src/modules/mavlink/mavlink_parameters.cpp), ArduPilot casts the value (..._C_CAST).
MAV_PARAM_TYPE_UINT8, MAV_PARAM_TYPE_INT8 = 1, 2
MAV_PARAM_TYPE_UINT16, MAV_PARAM_TYPE_INT16 = 3, 4
MAV_PARAM_TYPE_UINT32, MAV_PARAM_TYPE_INT32 = 5, 6
MAV_PARAM_TYPE_REAL32 = 9
_INT_FORMATS = {1: "<B", 2: "<b", 3: "<H", 4: "<h", 5: "<I", 6: "<i"}


def param_to_wire(value: float, param_type: int, firmware: str) -> float:
    """The float ``param_value`` carrying ``value`` of ``param_type`` for ``firmware``."""
    import struct

    fmt = _INT_FORMATS.get(int(param_type))
    if fmt is None:
        return float(np.float32(value))
    if firmware != "px4":
        return float(np.float32(int(value)))
    raw = struct.pack(fmt, int(value)).ljust(4, b"\0")
    return float(struct.unpack("<f", raw)[0])


def param_from_wire(wire: float, param_type: int, firmware: str) -> float:
    """The parameter's value from the float ``param_value`` (inverse of
    :func:`param_to_wire`)."""
    import struct

    fmt = _INT_FORMATS.get(int(param_type))
    if fmt is None:
        return float(np.float32(wire))
    if firmware != "px4":
        return float(int(round(wire)))
    raw = struct.pack("<f", wire)
    return float(struct.unpack(fmt, raw[: struct.calcsize(fmt)])[0])
