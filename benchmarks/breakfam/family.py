"""Units and runs of the break family (:mod:`.physics`, :mod:`.trajectories`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .physics import (
    Unit,
    air_temperature,
    die_sensor,
    draw_unit,
    drift,
    pt100,
    synthetic_noise,
    thermal,
)
from .realnoise import DATA, real_noise
from .trajectories import NAMES, trajectory

RATE_HZ = 10.0
#: days between the calibration run (day 0) and each held-out run: aging shows as offset
DAY_OF = {name: float(i) for i, name in enumerate(NAMES)}


@dataclass
class Run:
    t: np.ndarray  # s, output sample times at RATE_HZ
    raw: np.ndarray  # °/s, gyro output
    drift: np.ndarray  # °/s, true deterministic drift at t (the oracle's)
    pt_t: np.ndarray  # s, PT100 reading times (1 Hz)
    pt_c: np.ndarray  # °C, PT100 readings
    die_c: np.ndarray  # °C, die temperature at 1 Hz (diagnostics)
    die_sensor_c: np.ndarray  # °C, the unit's die thermometer at pt_t (physics.die_sensor)


def units(n: int) -> list[Unit]:
    """``n`` units; even-numbered ones carry real static-record noise (half of them)."""
    return [draw_unit(u, real_noise=(u % 2 == 0)) for u in range(n)]


def simulate_run(
    unit: Unit,
    name: str,
    seed: int,
    rate_hz: float = RATE_HZ,
    noise_path: str = str(DATA),
    setpoints: np.ndarray | None = None,
) -> Run:
    """One trajectory of one unit, from power-on: output, true drift and PT100.
    ``setpoints`` (per second, from rest at 25 °C) replaces the named trajectory: a
    calibration profile under test (benchmarks/prior_suite.py), run on day 0."""
    sp, rest = trajectory(name, seed) if setpoints is None else (setpoints, 25.0)
    air = air_temperature(sp, rest)
    P, D = thermal(unit, air, rest)
    rng = np.random.default_rng([seed, 5])
    pt_c = pt100(unit, P, rng)
    d1 = drift(unit, P, D, DAY_OF.get(name, 0.0) * 86400.0)
    t1 = np.arange(D.size, dtype=float)
    n = int(D.size * rate_hz)
    t = np.arange(n) / rate_hz
    d = np.interp(t, t1, d1)
    if unit.real_noise:
        noise = real_noise(n, unit.arw, rng, noise_path)  # its own coloured noise
    else:
        noise = synthetic_noise(unit, n, rate_hz, rng)
    u = (np.interp(t, t1, D) - 25.0) / 50.0
    raw = d + noise * np.maximum(1.0 + unit.gamma * u, 0.2)
    # its own generator: the runs' PT100 and noise draws are those of before
    die = die_sensor(unit.index, D, np.random.default_rng([seed, 6]))
    return Run(t=t, raw=raw, drift=d, pt_t=t1, pt_c=pt_c, die_c=D, die_sensor_c=die)
