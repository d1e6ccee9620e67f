"""ArduPilot's IMU temperature calibration, offsets and board orientation, as its source
applies them.

Sources (ArduPilot, ``master``):

* ``libraries/AP_InertialSensor/AP_InertialSensor_tempcal.cpp`` — per IMU *n* (1…3),
  ``INS_TCALn_ENABLE`` (0 off, 1 on, 2 learn), ``INS_TCALn_TMIN``/``TMAX`` (°C),
  ``INS_TCALn_GYR{1,2,3}_{X,Y,Z}`` (×``SCALE_FACTOR`` = 1e6); ``polynomial_eval(x) =
  (c1 + (c2 + c3·x)·x)·x·1e-6`` (no constant term); ``correct_sensor``: only when ENABLE is
  1, ``T`` and ``cal_temp`` each constrained to [TMIN, TMAX], then ``v −= P(T − 35)`` and
  ``v += P(cal_temp − 35)`` (``TEMP_REFERENCE`` 35 °C);
* ``libraries/AP_InertialSensor/AP_InertialSensor_Backend.cpp``
  ``_rotate_and_correct_gyro`` — the sample is first rotated by the sensor's own mounting
  on the board (``_gyro_orientation``, set by the board's hwdef), then (unless a gyro
  calibration is running) temperature-corrected with ``INS_GYRn_CALTEMP``, then the offsets
  ``INS_GYROFFS_*`` / ``INS_GYR2OFFS_*`` / ``INS_GYR3OFFS_*`` are subtracted, then it is
  rotated by the board orientation ``AHRS_ORIENTATION`` into the body frame. The IMU
  messages of the log and the RAW_IMU/SCALED_IMUn messages carry that body-frame,
  corrected, low-pass-filtered gyro (``get_gyro``);
* ``Tools/scripts/tempcal_IMU.py`` — reading a log, it undoes ``AHRS_ORIENTATION``
  (``rotate_by_inverse_id``) and the active correction (adding back ``P(T) − P(cal_temp)``
  while ENABLE is 1), with the PARM values in force as the log goes on.

"Sensor frame" here is the frame the calibration is made in: the IMU after its board
mounting rotation, before ``AHRS_ORIENTATION`` (what ArduPilot's own TCAL fit uses).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from gyrolab.autopilot import GYRO_CAL_SLOTS

TEMP_REFERENCE_C = 35.0  # TEMP_REFERENCE
SCALE_FACTOR = 1.0e6  # SCALE_FACTOR (parameters hold coefficient · 1e6)
INV_SCALE_FACTOR = 1.0e-6
IMUS = GYRO_CAL_SLOTS["ardupilot"]  # INS_TCAL1..3
AXES = "XYZ"
BOARD_ORIENTATION = "AHRS_ORIENTATION"
ENABLED = 1  # TCal::Enable::Enabled

f32 = np.float32


def tcal_names(instance: int) -> list[str]:
    """The ``INS_TCAL<n>_*`` gyro names of IMU ``instance`` (0-based), ENABLE first."""
    n = instance + 1
    return [f"INS_TCAL{n}_ENABLE", f"INS_TCAL{n}_TMIN", f"INS_TCAL{n}_TMAX"] + [
        f"INS_TCAL{n}_GYR{k}_{a}" for k in (1, 2, 3) for a in AXES
    ]


def gyro_offset_names(instance: int) -> list[str]:
    """``INS_GYROFFS_X`` … (IMU 1), ``INS_GYR2OFFS_X`` … (rad/s)."""
    stem = "INS_GYROFFS_" if instance == 0 else f"INS_GYR{instance + 1}OFFS_"
    return [f"{stem}{a}" for a in AXES]


def caltemp_name(instance: int, sensor: str = "GYR") -> str:
    """``INS_GYR<n>_CALTEMP`` (``INS_ACC<n>_CALTEMP``): the temperature the offsets were
    measured at (default −300: never)."""
    return f"INS_{sensor}{instance + 1}_CALTEMP"


def accel_offset_names(instance: int) -> list[str]:
    """``INS_ACCOFFS_X`` … (IMU 1), ``INS_ACC2OFFS_X`` … (m/s²)."""
    stem = "INS_ACCOFFS_" if instance == 0 else f"INS_ACC{instance + 1}OFFS_"
    return [f"{stem}{a}" for a in AXES]


def accel_scale_names(instance: int) -> list[str]:
    """``INS_ACCSCAL_X`` … (IMU 1), ``INS_ACC2SCAL_X`` …."""
    stem = "INS_ACCSCAL_" if instance == 0 else f"INS_ACC{instance + 1}SCAL_"
    return [f"{stem}{a}" for a in AXES]


@dataclass(frozen=True)
class Tcal:
    """One IMU's ``INS_TCALn`` gyro set as the firmware holds it (``coeff[k, a]`` is
    c_{k+1}·1e6, float32)."""

    enable: int
    tmin: float
    tmax: float
    coeff: np.ndarray  # (3, 3) float32, as stored (×1e6)

    @classmethod
    def from_params(cls, p: Mapping[str, float], instance: int, sensor: str = "GYR") -> Tcal:
        """The gyro's (``sensor="GYR"``) or the accelerometer's (``"ACC"``) coefficients."""
        n = instance + 1
        c = np.array(
            [[p.get(f"INS_TCAL{n}_{sensor}{k}_{a}", 0.0) for a in AXES] for k in (1, 2, 3)],
            dtype=f32,
        )
        return cls(
            int(p.get(f"INS_TCAL{n}_ENABLE", 0)),
            float(p.get(f"INS_TCAL{n}_TMIN", 0.0)),  # the parameters' defaults
            float(p.get(f"INS_TCAL{n}_TMAX", 70.0)),
            c,
        )

    def poly(self, tdiff: np.ndarray) -> np.ndarray:
        """``polynomial_eval(tdiff)``: ``(c1 + (c2 + c3·x)·x)·x·1e-6`` per axis, float32."""
        x = np.asarray(tdiff, dtype=f32)[..., None]
        c = self.coeff
        return ((c[0] + (c[1] + c[2] * x) * x) * x * f32(INV_SCALE_FACTOR)).astype(f32)

    def correction(self, temp_c: np.ndarray, cal_temp_c: float) -> np.ndarray:
        """What ``correct_sensor`` subtracts: ``P(T − 35) − P(cal_temp − 35)``, T and
        cal_temp constrained to [TMIN, TMAX]; zeros unless ENABLE is 1. ``(n, 3)`` float32."""
        t = np.asarray(temp_c, dtype=f32)
        if self.enable != ENABLED:
            return np.zeros((*t.shape, 3), dtype=f32)
        lo, hi = f32(self.tmin), f32(self.tmax)
        tc = np.clip(t, lo, hi)
        cc = np.clip(f32(cal_temp_c), lo, hi)
        return (self.poly(tc - f32(TEMP_REFERENCE_C))
                - self.poly(np.asarray(cc - f32(TEMP_REFERENCE_C)))).astype(f32)  # fmt: skip


def gyro_offsets(p: Mapping[str, float], instance: int) -> np.ndarray:
    """``INS_GYR*OFFS_{X,Y,Z}`` of IMU ``instance`` (rad/s; 0 where absent)."""
    return np.array([p.get(n, 0.0) for n in gyro_offset_names(instance)], dtype=f32)


def correct(
    sensor_rad_s: np.ndarray, temp_c: np.ndarray, p: Mapping[str, float], instance: int
) -> np.ndarray:
    """``_rotate_and_correct_gyro`` after the board-mounting rotation: temperature
    correction (``INS_GYRn_CALTEMP``), offsets, then ``AHRS_ORIENTATION``. ``(n, 3)``
    float32 rad/s, body frame."""
    from gyrolab.autopilot.rotation import rotation_matrix

    tcal = Tcal.from_params(p, instance)
    cal_temp = float(p.get(caltemp_name(instance), -300.0))
    v = np.asarray(sensor_rad_s, dtype=f32) - tcal.correction(temp_c, cal_temp)
    v = v - gyro_offsets(p, instance)
    r = rotation_matrix(int(p.get(BOARD_ORIENTATION, 0))).astype(f32)
    return (v.astype(f32) @ r.T).astype(f32)


def uncorrect(
    body_rad_s: np.ndarray, temp_c: np.ndarray, p: Mapping[str, float], instance: int
) -> np.ndarray:
    """The inverse of :func:`correct` (float64): the sensor-frame, uncorrected rate from
    what the firmware logged or streamed — ``AHRS_ORIENTATION`` undone, the offsets and the
    active temperature correction added back."""
    from gyrolab.autopilot.rotation import rotate

    tcal = Tcal.from_params(p, instance)
    cal_temp = float(p.get(caltemp_name(instance), -300.0))
    v = rotate(np.asarray(body_rad_s, dtype=np.float64), int(p.get(BOARD_ORIENTATION, 0)), True)
    return v + gyro_offsets(p, instance) + tcal.correction(temp_c, cal_temp).astype(np.float64)


def accel_scale(p: Mapping[str, float], instance: int) -> np.ndarray:
    """``INS_ACC*SCAL_{X,Y,Z}``; an unset (0) scale is 1, as for an IMU never calibrated."""
    s = np.array([p.get(n, 1.0) for n in accel_scale_names(instance)], dtype=f32)
    return np.where(s == 0, f32(1.0), s)


def uncorrect_accel(
    body_m_s2: np.ndarray, temp_c: np.ndarray, p: Mapping[str, float], instance: int
) -> np.ndarray:
    """The accelerometer's :func:`uncorrect`: ``_rotate_and_correct_accel`` applies the
    temperature correction (``INS_TCALn_ACC*``, ``INS_ACCn_CALTEMP``), subtracts
    ``INS_ACC*OFFS``, multiplies by ``INS_ACC*SCAL``, then rotates by
    ``AHRS_ORIENTATION``; this undoes the four, in reverse order (float64)."""
    from gyrolab.autopilot.rotation import rotate

    tcal = Tcal.from_params(p, instance, "ACC")
    cal_temp = float(p.get(caltemp_name(instance, "ACC"), -300.0))
    v = rotate(np.asarray(body_m_s2, dtype=np.float64), int(p.get(BOARD_ORIENTATION, 0)), True)
    v = v / accel_scale(p, instance)
    offs = np.array([p.get(n, 0.0) for n in accel_offset_names(instance)], dtype=f32)
    return v + offs + tcal.correction(temp_c, cal_temp).astype(np.float64)
