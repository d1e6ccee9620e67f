"""The IMUs of a simulated flight controller: consumer MEMS gyros on a self-heated board.

Each IMU axis is a :class:`~gyrolab.sim.model.SimModel` on the nominal chamber (same air
model as the bench's gyro, so every axis and the chamber controller see one air
temperature) with a flight-controller board instead of a gyro case:

* **board heating** — the board (``case_capacity_j_per_k`` 40 J/K through
  ``case_resistance_k_per_w`` 10 K/W: τ 400 s) dissipates 0.8 W (``gyro_power_w``): it sits
  8 °C above the chamber air at rest, as an autopilot's IMU does in a closed enclosure;
* **the die lags the board** (``thermal_lag``, τ 40 s) and the bias follows the die, which
  the IMU's own temperature sensor reads (offset, noise, quantisation:
  :class:`~gyrolab.sim.sensors.DieThermometer`) — the temperature the firmware compensates
  with;
* **bias over temperature** — a quartic in the die temperature (``bias_poly`` c0…c4,
  t_ref 25 °C): a zero-rate offset of 1.5–2 °/s (an uncalibrated consumer gyro's may be
  larger still; this one never crosses zero over the range, which keeps the 1 mrad/s
  truncation of the MAVLink message a constant shift in the calibration data), a slope of
  a few 10⁻³ °/s/°C — the order of a consumer MEMS gyro's data-sheet "ZRO variation over
  temperature" — and a 4th-order term (up to 1 °/s at 40 °C from 25 °C) a firmware's
  cubic cannot hold; every IMU and axis its own, drawn from the seed;
* **noise** — white (``arw`` 0.5 °/√h, 0.008 °/s/√Hz: 0.042 °/s, 0.73 steps of the MAVLink
  message's 1 mrad/s, per sample at 25 Hz — enough to dither the step; the data sheets of
  autopilot IMUs give 0.0028 (ICM-42688-P) to 0.014 °/s/√Hz (BMI088)) and a small
  flicker floor (``bias_instability`` 2 °/h).

Values are those of a plausible autopilot board, not of a particular part; docs/sim-model.md.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from gyrolab.sim.model import SimModel, nominal_model

BOARD_THERMAL = {
    "case_capacity_j_per_k": 40.0,
    "case_resistance_k_per_w": 10.0,
    "gyro_power_w": 0.8,
}
DIE_TAU_S = 40.0
ARW_DEG_PER_SQRT_H = 0.5
BIAS_INSTABILITY_DEG_PER_H = 2.0
# spread of the bias polynomial per IMU axis (°/s per °C^k), Δ = T − 25 °C
BIAS_SCALES = (2.0, 3.0e-3, 4.0e-5, 1.0e-6, 4.0e-7)


def imu_axis_model(seed: int, imu: int, axis: int) -> SimModel:
    """The model of one IMU axis (module doc), deterministic in ``(seed, imu, axis)``."""
    rng = np.random.default_rng([int(seed), 9173, imu, axis])
    c = [float(s * rng.uniform(0.5, 1.0) * rng.choice((-1.0, 1.0))) for s in BIAS_SCALES]
    c[0] = float(np.sign(c[0]) * max(abs(c[0]), 1.5))  # a zero-rate offset of 1.5-2 °/s
    base = nominal_model().with_thermal(**BOARD_THERMAL)
    return (
        base.without_effect("bias_poly")
        .without_effect("arw")
        .without_effect("bias_instability")
        .with_effect("thermal_lag", tau_s=DIE_TAU_S)
        .with_effect("bias_poly", c0=c[0], c1=c[1], c2=c[2], c3=c[3], c4=c[4], t_ref_c=25.0)
        .with_effect("arw", N=ARW_DEG_PER_SQRT_H)
        .with_effect("bias_instability", B=BIAS_INSTABILITY_DEG_PER_H)
    )


def imu_seed(seed: int, imu: int, axis: int) -> int:
    """The noise seed of one IMU axis (its own streams: seed, IMU and axis)."""
    return int(seed) * 1000 + 10 * imu + axis


def imu_physics(
    seed: int, rate_hz: float, ambient_c: float = 25.0, imus: int = 3
) -> list[list[Any]]:
    """Per IMU its x, y, z :class:`~gyrolab.sim.physics.Physics` at ``rate_hz`` (each axis
    its own noise streams: seed, IMU and axis)."""
    from gyrolab.sim.physics import Physics

    return [
        [
            Physics(
                imu_axis_model(seed, k, a),
                rate_hz=rate_hz,
                seed=imu_seed(seed, k, a),
                ambient_c=ambient_c,
            )
            for a in range(3)
        ]
        for k in range(imus)
    ]
