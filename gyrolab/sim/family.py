"""A family of simulated units: one model per unit, dispersed around a nominal model.

Production lots of one gyro type differ unit to unit in their temperature coefficients,
noise and thermal coupling; the chamber they share does not. :func:`unit_family` draws
``n`` units from a nominal :class:`~gyrolab.sim.model.SimModel` (docs/fleet.md):

* every real-valued effect parameter ``p`` → ``p · exp(σ_e·z)`` (log-normal: keeps its
  sign, relative spread σ_e = 0.15), except reference temperatures (names ending
  ``_c``), which stay;
* ``bias_poly.c0`` additionally ``+ N(0, σ_b)`` with σ_b = 0.01 °/s (turn-on bias spread);
* the unit's thermal coupling — ``case_capacity_j_per_k``, ``case_resistance_k_per_w``,
  ``die_tau_s``, ``gyro_power_w`` — ``· exp(0.10·z)``; the chamber's parameters
  (``air_tau_s``, heating/cooling rates, cooling knee and floor) are shared, so every unit
  sees the same chamber air;
* the scale factor ``adc_gain_v_per_dps`` ``· exp(0.005·z)``.

``z`` are standard normal draws from ``numpy.random.default_rng([seed, k, 0x5EED])`` for
unit ``k`` (0-based), and the unit's own noise streams are seeded with
``SeedSequence([seed, k])``; serials are ``SIM<seed>-<k+1:02d>``. Everything is a function
of (nominal model, n, seed): the same arguments give the same units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gyrolab.sim.model import SimModel

EFFECT_SIGMA = 0.15
BIAS_SIGMA_DPS = 0.01
THERMAL_SIGMA = 0.10
SCALE_SIGMA = 0.005
UNIT_THERMAL = ("case_capacity_j_per_k", "case_resistance_k_per_w", "die_tau_s", "gyro_power_w")


@dataclass(frozen=True)
class Unit:
    """One simulated unit: its serial, its model and the seed of its noise streams."""

    serial: str
    model: SimModel
    seed: int


def unit_serial(seed: int, k: int) -> str:
    """The serial of unit ``k`` (0-based) of the family drawn with ``seed``."""
    return f"SIM{int(seed)}-{k + 1:02d}"


def unit_family(nominal: SimModel, n: int, seed: int) -> list[Unit]:
    """``n`` units dispersed around ``nominal`` (module docstring for the law)."""
    if n < 1:
        raise ValueError(f"units must be >= 1, got {n}")
    out = []
    for k in range(n):
        rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, k, 0x5EED])
        d = nominal.to_dict()
        for e in d.get("effect", []):
            for name, v in list(e.items()):
                if name == "name" or name.endswith("_c") or isinstance(v, bool):
                    continue
                # floats only: integer parameters are orders and counts, not coefficients
                if isinstance(v, float) and v != 0 and math.isfinite(v):
                    e[name] = v * math.exp(EFFECT_SIGMA * rng.standard_normal())
            if e["name"] == "bias_poly":
                e["c0"] = float(e.get("c0", 0.0)) + BIAS_SIGMA_DPS * rng.standard_normal()
        th = d["thermal"]
        for name in UNIT_THERMAL:
            if th.get(name):
                th[name] = float(th[name]) * math.exp(THERMAL_SIGMA * rng.standard_normal())
        sens = d["sensors"]
        sens["adc_gain_v_per_dps"] = float(sens["adc_gain_v_per_dps"]) * math.exp(
            SCALE_SIGMA * rng.standard_normal()
        )
        unit_seed = int(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, k]).generate_state(1)[0])
        out.append(Unit(unit_serial(seed, k), SimModel.from_dict(d), unit_seed))
    return out
