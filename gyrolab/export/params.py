"""PX4 ``.params`` and ArduPilot ``.parm`` files of the firmware cubic
(:mod:`gyrolab.compensation.firmware`).

**PX4** (``src/modules/temperature_compensation``: ``temp_comp_params_gyro_*.c`` /
``TemperatureCompensation::calc_thermal_offsets_3D``; file layout of
``Tools/process_sensor_caldata.py``): for gyro instance *i*

    offset_a = X0_a + X1_a·Δ + X2_a·Δ² + X3_a·Δ³   (rad/s),  Δ = clamp(T, TMIN, TMAX) − TREF

with parameters ``TC_Gi_ID`` (the sensor's device id), ``TC_Gi_TREF/TMIN/TMAX`` (°C) and
``TC_Gi_X{k}_{a}`` (order k = 0…3, axis a = 0, 1, 2 = X, Y, Z); the corrected rate is
raw − offset. The file is QGroundControl's parameter file: ``#`` comment lines, then one
parameter per line, tab-separated ``vehicle-id component-id name value type`` with type 6
(MAV_PARAM_TYPE_INT32) for integers and 9 (MAV_PARAM_TYPE_REAL32) for floats.

**ArduPilot** (``libraries/AP_InertialSensor/AP_InertialSensor_tempcal.cpp``; file layout
of ``Tools/scripts/tempcal_IMU.py``): for IMU *n* (1-based)

    P(x) = (c1·x + c2·x² + c3·x³)·1e-6  (rad/s),  x = clamp(T, TMIN, TMAX) − 35 °C
    gyro −= P(x(T)) − P(x(CALTEMP))

``INS_TCALn_GYR{k}_{X,Y,Z}`` = c_k (×1e6), ``INS_TCALn_ENABLE/TMIN/TMAX``. There is no
constant term: ArduPilot's gyro offsets (``INS_GYROFFS_*``, measured at ``INS_GYRn_CALTEMP``)
carry it. The file lists them too, so that the file alone reproduces the calibration's
bias; with the default start-up gyro calibration (``INS_GYR_CAL`` = 1) ArduPilot measures
the offset and its temperature again at every boot. Lines are ``NAME value``.

gyrolab's axes x, y, z map to the sensor's X, Y, Z (the unit must be mounted so); a model
with fewer than 3 axes leaves the others at 0 (no correction). Values are written as the
shortest text that reads back as the same float32, which is how the firmware stores them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gyrolab.compensation.firmware import (
    MAV_PARAM_TYPE_INT8,
    MAV_PARAM_TYPE_INT32,
    Poly3,
    ardupilot_parameter_set,
    px4_parameter_set,
)


def f32(v: float) -> str:
    """Shortest decimal text that reads back as the same float32."""
    return str(np.float32(v))



def px4_params(
    polys: list[Poly3],
    instance: int,
    device_id: int,
    *,
    vehicle_id: int = 1,
    component_id: int = 1,
    header: str = "",
) -> str:
    """The PX4 ``.params`` text for gyro ``instance`` (module docstring)."""
    vals = px4_parameter_set(polys, instance, device_id)
    lines = [
        "# Sensor thermal compensation parameters",
        "#",
        *(f"# {h}" for h in header.splitlines()),
        "# Vehicle-Id Component-Id Name Value Type",
    ]
    for name in sorted(vals):
        v, t = vals[name]
        text = str(int(v)) if t == MAV_PARAM_TYPE_INT32 else f32(v)
        lines.append(f"{vehicle_id}\t{component_id}\t{name}\t{text}\t{t}")
    return "\n".join(lines) + "\n"


def ardupilot_parm(polys: list[Poly3], instance: int, *, header: str = "") -> str:
    """The ArduPilot ``.parm`` text for IMU ``instance`` (0-based; module docstring)."""
    vals = ardupilot_parameter_set(polys, instance)
    lines = [*(f"# {h}" for h in header.splitlines())]
    for name, (v, t) in vals.items():
        lines.append(f"{name} {int(v) if t == MAV_PARAM_TYPE_INT8 else f32(v)}")
    return "\n".join(lines) + "\n"


# ------------------------------------------------ reading back and applying (as firmware)


def read_px4_params(text: str) -> dict[str, tuple[int, int, float, int]]:
    """``name → (vehicle id, component id, value, type)`` of a QGC ``.params`` text."""
    out = {}
    for line in text.splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        vid, cid, name, value, typ = line.split("\t")
        out[name] = (int(vid), int(cid), float(value), int(typ))
    return out


def read_ardupilot_parm(text: str) -> dict[str, float]:
    """``name → value`` of a ``NAME value`` ``.parm`` text."""
    out = {}
    for line in text.splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        name, value = line.split()
        out[name] = float(value)
    return out


@dataclass(frozen=True)
class FirmwareCorrection:
    """The correction a firmware computes from its parameters, in float32 as it does
    (:mod:`gyrolab.autopilot`): ``offset_rad_s(axis, T)`` is what it subtracts at a
    steady temperature T (PX4: the TC offsets; ArduPilot: the offsets plus the temperature
    correction relative to ``CALTEMP``)."""

    kind: str
    p: dict[str, float]
    instance: int

    def offset_rad_s(self, axis: int, temp_c: np.ndarray) -> np.ndarray:
        from gyrolab.autopilot import ardupilot, px4

        if self.kind == "px4":
            return px4.TcGyro.from_params(self.p, self.instance).offsets(temp_c)[..., axis]
        tcal = ardupilot.Tcal.from_params(self.p, self.instance)
        cal_temp = self.p[ardupilot.caltemp_name(self.instance)]
        offs = ardupilot.gyro_offsets(self.p, self.instance)
        return offs[axis] + tcal.correction(temp_c, cal_temp)[..., axis]

    def offset_dps(self, axis: int, temp_c: np.ndarray) -> np.ndarray:
        return self.offset_rad_s(axis, temp_c).astype(float) / (np.pi / 180.0)


def px4_correction(text: str, instance: int) -> FirmwareCorrection:
    return FirmwareCorrection("px4", {k: v[2] for k, v in read_px4_params(text).items()}, instance)


def ardupilot_correction(text: str, instance: int) -> FirmwareCorrection:
    return FirmwareCorrection("ardupilot", read_ardupilot_parm(text), instance)
