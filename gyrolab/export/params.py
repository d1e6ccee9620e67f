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

from gyrolab.compensation.firmware import DEG2RAD, Poly3

ARDUPILOT_TREF_C = 35.0  # TEMP_REFERENCE in AP_InertialSensor_tempcal.cpp
ARDUPILOT_SCALE = 1.0e6  # SCALE_FACTOR
AXES = "XYZ"
MAV_PARAM_TYPE_INT32 = 6
MAV_PARAM_TYPE_REAL32 = 9


def f32(v: float) -> str:
    """Shortest decimal text that reads back as the same float32."""
    return str(np.float32(v))


def _axes3(polys: list[Poly3]) -> list[Poly3 | None]:
    return [polys[k] if k < len(polys) else None for k in range(3)]


def _range(polys: list[Poly3]) -> tuple[float, float]:
    # one temperature range per sensor in both firmwares: the axes share the calibration run
    return min(p.t_min for p in polys), max(p.t_max for p in polys)


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
    if not 0 <= instance <= 3:
        raise ValueError("PX4 has thermal compensation for gyro instances 0..3")
    lo, hi = _range(polys)
    tref = 0.5 * (lo + hi)
    g = f"TC_G{instance}_"
    vals: dict[str, tuple[str, int]] = {
        "TC_G_ENABLE": ("1", MAV_PARAM_TYPE_INT32),
        f"{g}ID": (str(int(device_id)), MAV_PARAM_TYPE_INT32),
        f"{g}TMIN": (f32(lo), MAV_PARAM_TYPE_REAL32),
        f"{g}TMAX": (f32(hi), MAV_PARAM_TYPE_REAL32),
        f"{g}TREF": (f32(tref), MAV_PARAM_TYPE_REAL32),
    }
    for a, p in enumerate(_axes3(polys)):
        c = (0.0, 0.0, 0.0, 0.0) if p is None else p.recentred(tref)
        for k in range(4):
            vals[f"{g}X{k}_{a}"] = (f32(c[k] * DEG2RAD), MAV_PARAM_TYPE_REAL32)
    lines = [
        "# Sensor thermal compensation parameters",
        "#",
        *(f"# {h}" for h in header.splitlines()),
        "# Vehicle-Id Component-Id Name Value Type",
    ]
    for name in sorted(vals):
        v, t = vals[name]
        lines.append(f"{vehicle_id}\t{component_id}\t{name}\t{v}\t{t}")
    return "\n".join(lines) + "\n"


def ardupilot_parm(polys: list[Poly3], instance: int, *, header: str = "") -> str:
    """The ArduPilot ``.parm`` text for IMU ``instance`` (0-based; module docstring)."""
    if not 0 <= instance <= 2:
        raise ValueError("ArduPilot has temperature calibration for IMU instances 0..2")
    n = instance + 1
    lo, hi = _range(polys)
    cal_temp = min(max(ARDUPILOT_TREF_C, lo), hi)
    offs = "INS_GYROFFS_" if n == 1 else f"INS_GYR{n}OFFS_"
    lines = [*(f"# {h}" for h in header.splitlines())]
    lines += [f"INS_TCAL{n}_ENABLE 1", f"INS_TCAL{n}_TMIN {f32(lo)}", f"INS_TCAL{n}_TMAX {f32(hi)}"]
    body: dict[str, str] = {}
    ofs: dict[str, str] = {}
    for a, p in enumerate(_axes3(polys)):
        c = (0.0,) * 4 if p is None else p.recentred(ARDUPILOT_TREF_C)
        for k in (1, 2, 3):
            body[f"INS_TCAL{n}_GYR{k}_{AXES[a]}"] = f32(c[k] * DEG2RAD * ARDUPILOT_SCALE)
        x = float(np.float32(cal_temp)) - ARDUPILOT_TREF_C
        # offset = bias at CALTEMP, so that GYROFFS + P(x(T)) − P(x(CALTEMP)) = b(T)
        ofs[f"{offs}{AXES[a]}"] = f32((c[0] + x * (c[1] + x * (c[2] + x * c[3]))) * DEG2RAD)
    lines += [f"{k} {v}" for k, v in body.items()]
    lines += [f"{k} {v}" for k, v in ofs.items()]
    lines.append(f"INS_GYR{n}_CALTEMP {f32(cal_temp)}")
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
    """The correction a firmware computes from its parameters, in float32 as it does:
    ``offset_rad_s(axis, T)``."""

    kind: str
    p: dict[str, float]
    instance: int

    def offset_rad_s(self, axis: int, temp_c: np.ndarray) -> np.ndarray:
        f = np.float32
        T = np.asarray(temp_c, dtype=np.float32)
        if self.kind == "px4":
            g = f"TC_G{self.instance}_"
            d = np.clip(T, f(self.p[f"{g}TMIN"]), f(self.p[f"{g}TMAX"])) - f(self.p[f"{g}TREF"])
            c = [f(self.p[f"{g}X{k}_{axis}"]) for k in range(4)]
            return c[0] + c[1] * d + c[2] * d * d + c[3] * d * d * d
        n = self.instance + 1
        lo, hi = f(self.p[f"INS_TCAL{n}_TMIN"]), f(self.p[f"INS_TCAL{n}_TMAX"])
        c = [f(self.p[f"INS_TCAL{n}_GYR{k}_{AXES[axis]}"]) for k in (1, 2, 3)]

        def poly(x: np.ndarray) -> np.ndarray:  # polynomial_eval()
            return (c[0] + (c[1] + c[2] * x) * x) * x * f(1.0e-6)

        offs = "INS_GYROFFS_" if n == 1 else f"INS_GYR{n}OFFS_"
        x = np.clip(T, lo, hi) - f(ARDUPILOT_TREF_C)
        xc = np.clip(f(self.p[f"INS_GYR{n}_CALTEMP"]), lo, hi) - f(ARDUPILOT_TREF_C)
        return f(self.p[f"{offs}{AXES[axis]}"]) + poly(x) - poly(np.asarray(xc))

    def offset_dps(self, axis: int, temp_c: np.ndarray) -> np.ndarray:
        return self.offset_rad_s(axis, temp_c).astype(float) / (np.pi / 180.0)


def px4_correction(text: str, instance: int) -> FirmwareCorrection:
    return FirmwareCorrection("px4", {k: v[2] for k, v in read_px4_params(text).items()}, instance)


def ardupilot_correction(text: str, instance: int) -> FirmwareCorrection:
    return FirmwareCorrection("ardupilot", read_ardupilot_parm(text), instance)
