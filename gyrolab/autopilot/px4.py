"""PX4's gyro thermal compensation, calibration offsets and board rotation, as its source runs them.

Sources (PX4-Autopilot, ``main``):

* ``src/modules/temperature_compensation/TemperatureCompensation.cpp`` —
  ``calc_thermal_offsets_3D``: ``Δ = clip(T, TC_Gi_TMIN, TC_Gi_TMAX) − TC_Gi_TREF``,
  ``offset_a = X0_a + X1_a·Δ + X2_a·Δ² + X3_a·Δ³`` (float32, rad/s);
  ``update_offsets_gyro`` computes it for the gyro's uORB instance (mapped by
  ``TC_Gi_ID`` = the sensor's device id) and asks for a new publication only when
  ``|T − last_temperature| > 1 °C`` (``last_temperature`` starts at −100 °C and is reset
  to it whenever a parameter changes, ``parameters_update``);
* ``TemperatureCompensationModule.cpp`` — the module runs once a second
  (``ScheduleOnInterval(1_s)``), takes each gyro's latest ``sensor_gyro`` sample
  (``gyroPoll``), writes every instance's freshly computed offsets into one
  ``sensor_correction`` message and publishes it when *any* instance asked for it;
* ``src/lib/sensor_calibration/Gyroscope.{hpp,cpp}`` — ``Correct(data) = R_board ·
  (data − thermal_offset − CAL_GYROn_{X,Y,Z}OFF)`` with the offsets of the message's
  entry whose device id is the sensor's (``gyro_offset_0..2``: three gyros), R_board from
  ``SENS_BOARD_ROT`` (``Utilities.cpp`` ``GetBoardRotation``);
* ``src/lib/drivers/gyroscope/PX4Gyroscope.cpp`` — ``sensor_gyro`` is the driver's sample
  rotated to the board frame and scaled: before any calibration, offset or thermal
  correction (so a ULog's ``sensor_gyro`` is the sensor frame, uncorrected).

The TC parameters are ``TC_G_ENABLE`` and, per slot *i* = 0…3, ``TC_Gi_ID``,
``TC_Gi_TREF``, ``TC_Gi_TMIN``, ``TC_Gi_TMAX``, ``TC_Gi_X{0..3}_{0,1,2}``
(``temp_comp_params_gyro_*``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from gyrolab.autopilot import GYRO_CAL_SLOTS

TC_SLOTS = GYRO_CAL_SLOTS["px4"]  # GYRO_COUNT_MAX (TemperatureCompensation.h)
CORRECTED_GYROS = 3  # sensor_correction gyro_offset_0..2 (Gyroscope.cpp)
MODULE_PERIOD_S = 1.0  # TemperatureCompensationModule::init: ScheduleOnInterval(1_s)
REPUBLISH_DELTA_C = 1.0  # update_offsets_gyro: fabsf(T - last_temperature) > 1.0f
LAST_TEMPERATURE_RESET_C = -100.0  # PerSensorData::reset_temperature
AXES = "XYZ"

f32 = np.float32


def tc_names(slot: int) -> list[str]:
    """Every ``TC_G<slot>_*`` parameter name (and ``TC_G_ENABLE``)."""
    g = f"TC_G{slot}_"
    names = ["TC_G_ENABLE", f"{g}ID", f"{g}TREF", f"{g}TMIN", f"{g}TMAX"]
    names += [f"{g}X{k}_{a}" for k in range(4) for a in range(3)]
    return names


def cal_offset_names(slot: int) -> list[str]:
    """``CAL_GYRO<slot>_XOFF`` … (rad/s; ``GetCalibrationParamsVector3f`` "OFF")."""
    return [f"CAL_GYRO{slot}_{a}OFF" for a in AXES]


def cal_id_name(slot: int) -> str:
    return f"CAL_GYRO{slot}_ID"


BOARD_ROTATION = "SENS_BOARD_ROT"
BOARD_LEVEL_OFFSETS = ("SENS_BOARD_X_OFF", "SENS_BOARD_Y_OFF", "SENS_BOARD_Z_OFF")


@dataclass(frozen=True)
class TcGyro:
    """One ``TC_G<slot>_*`` set as the firmware holds it (float32; ``x[k, a]`` rad/s/°C^k)."""

    device_id: int
    tref: float
    tmin: float
    tmax: float
    x: np.ndarray  # (4, 3) float32

    @classmethod
    def from_params(cls, p: Mapping[str, float], slot: int) -> TcGyro:
        g = f"TC_G{slot}_"
        x = np.array([[p[f"{g}X{k}_{a}"] for a in range(3)] for k in range(4)], dtype=f32)
        return cls(int(p[f"{g}ID"]), float(p[f"{g}TREF"]), float(p[f"{g}TMIN"]),
                   float(p[f"{g}TMAX"]), x)  # fmt: skip

    def offsets(self, temp_c: float | np.ndarray) -> np.ndarray:
        """``calc_thermal_offsets_3D`` at ``temp_c`` (°C): ``(3,)`` or ``(n, 3)`` float32
        rad/s, in the firmware's float32 arithmetic and order of operations."""
        t = np.asarray(temp_c, dtype=f32)
        # clip to [TMIN, TMAX] (above TMAX first, as the source's if/else does)
        d = np.where(t > f32(self.tmax), f32(self.tmax),
                     np.where(t < f32(self.tmin), f32(self.tmin), t)) - f32(self.tref)  # fmt: skip
        d = d.astype(f32)[..., None]
        d2 = (d * d).astype(f32)
        d3 = (d2 * d).astype(f32)
        x = self.x
        return (x[0] + x[1] * d + x[2] * d2 + x[3] * d3).astype(f32)


def tc_slot_for(params: Mapping[str, float], device_id: int) -> int | None:
    """The ``TC_G<slot>`` set whose ``TC_Gi_ID`` is ``device_id`` (``set_sensor_id``), or
    None; None as well while ``TC_G_ENABLE`` is not 1."""
    if int(params.get("TC_G_ENABLE", 0)) != 1:
        return None
    for i in range(TC_SLOTS):
        if int(params.get(f"TC_G{i}_ID", 0)) == int(device_id) and device_id != 0:
            return i
    return None


class TemperatureCompensationModule:
    """The ``temperature_compensation`` module's gyro part, for a set of gyros (uORB
    instances 0…n−1 with their device ids): call :meth:`poll` once per second with each
    gyro's latest temperature; it returns the ``sensor_correction`` it publishes then
    (device id → offsets, rad/s float32) or None."""

    def __init__(self, params: Mapping[str, float], device_ids: list[int]) -> None:
        self.device_ids = list(device_ids)
        self.parameters_update(params)

    def parameters_update(self, params: Mapping[str, float]) -> None:
        """New parameters (``parameters_update``): mappings from ``TC_Gi_ID``, every
        ``last_temperature`` back to −100 °C so that the next poll publishes."""
        self.enabled = int(params.get("TC_G_ENABLE", 0)) == 1
        self.sets: list[TcGyro | None] = []
        for dev in self.device_ids:
            slot = tc_slot_for(params, dev)
            self.sets.append(None if slot is None else TcGyro.from_params(params, slot))
        self.last_temperature = [LAST_TEMPERATURE_RESET_C] * len(self.device_ids)
        # the offsets in the module's sensor_correction struct (computed every poll)
        self.current = [np.zeros(3, dtype=f32) for _ in self.device_ids]
        # sensor_correction gyro_device_ids: set for every instance with a calibration
        self.ids = [
            dev if s is not None else 0 for dev, s in zip(self.device_ids, self.sets, strict=True)
        ]

    def poll(self, temps_c: list[float | None]) -> dict[int, np.ndarray] | None:
        """One ``Run()``: ``temps_c[k]`` is gyro k's latest temperature (None: no new
        sample). Returns the published ``{device_id: offsets}`` (every instance with a
        calibration; devices without one are absent, i.e. corrected by nothing) or None."""
        if not self.enabled:
            return None
        changed = False
        for k, temp in enumerate(temps_c):
            tc = self.sets[k]
            if temp is None or tc is None or not np.isfinite(temp):
                continue
            self.current[k] = tc.offsets(temp)  # written in place every poll
            if abs(f32(temp) - f32(self.last_temperature[k])) > f32(REPUBLISH_DELTA_C):
                self.last_temperature[k] = float(f32(temp))
                changed = True
        if not changed:
            return None
        return {
            dev: self.current[k].copy()
            for k, dev in enumerate(self.ids)
            if dev != 0 and k < CORRECTED_GYROS
        }


def publications(
    reading_t: np.ndarray,
    reading_c: np.ndarray,
    tc: TcGyro,
    t_end: float,
    *,
    first_poll_s: float = 0.0,
    period_s: float = MODULE_PERIOD_S,
) -> tuple[np.ndarray, np.ndarray]:
    """When PX4 publishes new thermal offsets for one gyro whose temperature readings are
    ``(reading_t, reading_c)``, up to ``t_end`` (s): the module polls every ``period_s``
    from ``first_poll_s``, takes the latest reading at or before the poll, and republishes
    only when the temperature moved more than 1 °C since its last publication. Returns the
    publication times and their offsets (``(k, 3)`` float32 rad/s) — the single-gyro view
    of :class:`TemperatureCompensationModule` (a publication another gyro triggered is not
    modelled here)."""
    rt = np.asarray(reading_t, dtype=float)
    rc = np.asarray(reading_c, dtype=float)
    if rt.size == 0 or t_end < first_poll_s:
        return np.empty(0), np.empty((0, 3), dtype=f32)
    polls = first_poll_s + period_s * np.arange(
        int(np.floor((t_end - first_poll_s) / period_s)) + 1
    )
    k = np.searchsorted(rt, polls, side="right") - 1
    polls, temps = polls[k >= 0], rc[k[k >= 0]]
    pub_t: list[float] = []
    pub_c: list[float] = []
    last_t = f32(LAST_TEMPERATURE_RESET_C)
    for t, c in zip(polls, temps, strict=True):  # the 1 °C rule is a sequential state
        if np.isfinite(c) and abs(f32(c) - last_t) > f32(REPUBLISH_DELTA_C):
            last_t = f32(c)
            pub_t.append(float(t))
            pub_c.append(float(c))
    if not pub_t:
        return np.empty(0), np.empty((0, 3), dtype=f32)
    return np.asarray(pub_t), tc.offsets(np.asarray(pub_c))


def module_publications(
    params: Mapping[str, float],
    readings: list[tuple[int, np.ndarray, np.ndarray]],
    t_end: float,
    *,
    first_poll_s: float = 0.0,
    period_s: float = MODULE_PERIOD_S,
) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """:class:`TemperatureCompensationModule` run over every gyro of a controller:
    ``readings`` is ``(device_id, t, temperature_c)`` per gyro (uORB instance order). Polls
    every ``period_s`` from ``first_poll_s`` to ``t_end``; returns the publication times and
    per device id its offsets at each publication (``(k, 3)`` float32; a publication that
    another gyro's 1 °C move triggered carries this gyro's current offsets too)."""
    mod = TemperatureCompensationModule(params, [dev for dev, _t, _c in readings])
    n = int(np.floor((t_end - first_poll_s) / period_s)) + 1
    polls = first_poll_s + period_s * np.arange(max(n, 0))
    idx = [np.searchsorted(np.asarray(t), polls, side="right") - 1 for _d, t, _c in readings]
    pub_t: list[float] = []
    pubs: dict[int, list[np.ndarray]] = {dev: [] for dev, _t, _c in readings}
    for i, poll in enumerate(polls):
        temps = [
            float(c[k[i]]) if k[i] >= 0 else None
            for (_d, _t, c), k in zip(readings, idx, strict=True)
        ]
        out = mod.poll(temps)
        if out is None:
            continue
        pub_t.append(float(poll))
        for dev in pubs:
            pubs[dev].append(out.get(dev, np.zeros(3, dtype=f32)))
    return np.asarray(pub_t), {d: np.asarray(v, dtype=f32).reshape(-1, 3) for d, v in pubs.items()}


def held(sample_t: np.ndarray, pub_t: np.ndarray, pub_offsets: np.ndarray) -> np.ndarray:
    """The offsets in force at each sample: the last publication at or before it; before
    the first, the first (the module has been running since the controller booted, and
    its first poll always publishes). ``(n, 3)`` float32; zeros without a publication."""
    st = np.asarray(sample_t, dtype=float)
    out = np.zeros((st.size, 3), dtype=f32)
    if len(pub_t) == 0:
        return out
    j = np.maximum(np.searchsorted(pub_t, st, side="right") - 1, 0)
    out[:] = pub_offsets[j]
    return out


def correct(
    raw_rad_s: np.ndarray,
    thermal_offset: np.ndarray,
    cal_offset: np.ndarray,
    board_rotation: int = 0,
) -> np.ndarray:
    """``Gyroscope::Correct``: ``R_board · (raw − thermal − offset)`` per row, float32."""
    from gyrolab.autopilot.rotation import rotation_matrix

    v = np.asarray(raw_rad_s, dtype=f32) - thermal_offset - np.asarray(cal_offset, dtype=f32)
    r = rotation_matrix(board_rotation).astype(f32)
    return (v.astype(f32) @ r.T).astype(f32)
