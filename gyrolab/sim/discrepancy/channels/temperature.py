"""Temperature-channel candidates: ``oven_overshoot`` on the chamber's process value and
``rtd_self_heating`` on the PT100, each scored by ΔBIC over the channel's effective number
of readings and by how much it cuts the channel's RMS (docs/discrepancy.md).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from gyrolab.pt100 import R0_OHM
from gyrolab.sim.discrepancy.catalogue import limit_entry
from gyrolab.sim.discrepancy.fitting import Fitted, Fitter
from gyrolab.sim.discrepancy.scored import Scored
from gyrolab.sim.discrepancy.thermal_fit import (
    OVEN_FLOOR_C,
    air_model,
    delta_bic_channel,
    effective_n,
    fit_oven,
)
from gyrolab.sim.effects import overshoot_period_s, self_heating_c

TEMP_SIG = 25.0
"""ΔBIC above which a temperature-channel candidate is significant."""
TEMP_MIN_GAIN = 0.3
"""…and it must also cut that channel's residual RMS by at least this fraction."""
OVERSHOOT_FLOOR = 1e-3
"""Smallest overshoot the limit search tries: a limit there means that even a critically
damped second-order chamber is told from the first-order one on this PV (its shape, not
its ringing: the simulator's exact PV, docs/discrepancy.md)."""


def _overshoot(fx: Fitter, cur: Fitted) -> Scored:
    cand = fx.thermal.oven(True, cur.structure.overshoot)
    dbic, ne = delta_bic_channel(cur.oven.resid, cand.resid, OVEN_FLOOR_C, 2)
    gain = 1.0 - cand.rms / max(cur.oven.rms, 1e-12)
    return Scored(
        "oven_overshoot",
        "temperature",
        dbic,
        dbic > TEMP_SIG and gain > TEMP_MIN_GAIN,
        {
            "oven_rms_c": [cur.oven.rms, cand.rms],
            "effective_n": ne,
            "overshoot": cand.overshoot[0] if cand.overshoot else None,
            "period_s": cand.overshoot[1] if cand.overshoot else None,
        },
    )


def _self_heating(fx: Fitter, cur: Fitted) -> Scored:
    cand = fx.thermal.case(True)  # the same data every iteration: fitted once
    dbic, ne = delta_bic_channel(cur.case.resid, cand.resid, 0.5 * fx.pt_noise, 1)
    gain = 1.0 - cand.rms / max(cur.case.rms, 1e-12)
    return Scored(
        "rtd_self_heating",
        "temperature",
        dbic,
        dbic > TEMP_SIG and gain > TEMP_MIN_GAIN,
        {
            "pt100_rms_c": [cur.case.rms, cand.rms],
            "offset_c": cand.offset_c,
            **self_heating_evidence(fx, cand.offset_c),
            "pt100_noise_c": fx.pt_noise,
            "effective_n": ne,
            "initial_case_c": cand.initial_c,
        },
    )


def self_heating_evidence(fx: Fitter, offset_c: float) -> dict[str, Any]:
    """What a self-heating δ (at 0 °C) means on this run: its range over the readings, and,
    with the multimeter's test current I known from the bench record, the sensor's
    self-heating coefficient ``θ = δ/(I²·R0)`` (°C/mW; a meter that drives the current
    only while it integrates heats less, and θ is then a lower bound)."""
    err = np.asarray(self_heating_c(offset_c, fx.d.pt100_c), dtype=float)
    i = fx.d.pt100_current_a
    theta = offset_c / (i * i * R0_OHM) / 1e3 if i else None
    return {
        "offset_range_c": [float(err.min()), float(err.max())],
        "excitation_current_a": i,
        "theta_c_per_mw": theta,
    }


SCORERS = {"oven_overshoot": _overshoot, "rtd_self_heating": _self_heating}


def score(fx: Fitter, cur: Fitted) -> list[Scored]:
    """Every temperature-channel candidate the model lacks (no PT100 effect where the
    temperature is a die sensor's: its offset is part of the die model)."""
    return [s(fx, cur) for name, s in SCORERS.items() if name in _applicable(fx, cur)]


def _applicable(fx: Fitter, cur: Fitted) -> list[str]:
    die = fx.d.temperature_source == "die"
    return [
        n for n in SCORERS if not cur.structure.has(n) and not (die and n == "rtd_self_heating")
    ]


def rtd_limit(fx: Fitter, cur: Fitted) -> float | None:
    """Smallest PT100 self-heating δ (at 0 °C) the temperature channel would name: the
    part of its signature ``δ·R(T)/R0`` that the case model (ΔT_self, initial case, with
    its prior) cannot absorb, against the ΔBIC (effective readings) and the RMS-gain
    rules."""
    dm = cur.case.design
    if dm is None:
        return None
    col = np.asarray(self_heating_c(1.0, fx.d.pt100_c), dtype=float)
    n_pt = cur.case.resid.size
    one = np.concatenate([col, [0.0]])
    coef, *_ = np.linalg.lstsq(dm, one, rcond=None)
    e = float(np.sum((one - dm @ coef)[:n_pt] ** 2)) / n_pt  # mean-square per unit δ²
    v1 = max(float(np.mean(cur.case.resid**2)), (0.5 * fx.pt_noise) ** 2)
    ne = effective_n(cur.case.resid, floor=0.5 * fx.pt_noise)
    if e <= 0:
        return None
    # ΔBIC: ne·ln(1 + δ²e/v1) − ln ne > threshold;  gain: v1/(v1 + δ²e) < (1 − g)²
    d_bic = math.sqrt(v1 * math.expm1((TEMP_SIG + math.log(ne)) / ne) / e)
    d_gain = math.sqrt(v1 * (1.0 / (1.0 - TEMP_MIN_GAIN) ** 2 - 1.0) / e)
    return max(d_bic, d_gain)


def overshoot_limit(fx: Fitter, cur: Fitted) -> float | None:
    """Smallest overshoot the oven channel's rules would name, for a second-order chamber
    as fast as the fitted first-order one (the same mean step delay, ``2ζ/ω_n = τ_air``:
    :func:`~gyrolab.sim.effects.overshoot_period_s`): its response to the recorded
    setpoints, refitted by the first-order model (whatever of it a faster or slower
    first-order chamber can absorb is no evidence), the remainder against the current
    residual's ΔBIC (effective readings) and RMS-gain rules; bisection in the overshoot."""
    d = fx.d
    x, form = cur.oven.x, cur.oven.form
    tau_air = cur.oven.params["air_tau_s"]
    a0 = float(cur.oven.pred[0])
    r1 = cur.oven.resid
    v1 = max(float(np.mean(r1**2)), OVEN_FLOOR_C**2)
    ne = effective_n(r1, floor=OVEN_FLOOR_C)

    def passes(o: float) -> bool:
        period_s = overshoot_period_s(o, tau_air)
        target = air_model(d.oven_t, d.oven_t, d.oven_sp, a0, x, (o, period_s), form)
        refit = fit_oven(replace(d, oven_pv=target), fx.model0.thermal, form=form, x_start=x)
        v0 = v1 + float(np.mean(refit.resid**2))
        dbic = ne * math.log(v0 / v1) - 2.0 * math.log(ne)
        return dbic > TEMP_SIG and 1.0 - math.sqrt(v1 / v0) > TEMP_MIN_GAIN

    lo, hi = OVERSHOOT_FLOOR, 0.9
    if x is None or not passes(hi):
        return None  # no overshoot up to 0.9 would be named
    if passes(lo):
        return lo  # any second-order chamber this fast is told from a first-order one
    for _ in range(8):
        mid = math.sqrt(lo * hi)
        lo, hi = (lo, mid) if passes(mid) else (mid, hi)
    return hi


def limits(fx: Fitter, cur: Fitted) -> dict[str, dict[str, Any]]:
    """Detection limits of the temperature-channel effects the model lacks."""
    out: dict[str, dict[str, Any]] = {}
    if "rtd_self_heating" in _applicable(fx, cur):
        out["rtd_self_heating"] = limit_entry(
            "rtd_self_heating",
            rtd_limit(fx, cur),
            "PT100 ΔBIC (effective readings) and RMS gain",
        )
    if not cur.structure.has("oven_overshoot"):
        out["oven_overshoot"] = limit_entry(
            "oven_overshoot",
            overshoot_limit(fx, cur),
            "oven ΔBIC (effective readings) and RMS gain of what a first-order refit "
            "leaves of the second-order response (as fast as the first-order chamber)",
            at={"mean_delay_s": cur.oven.params["air_tau_s"]},
        )
    return out


def params(fx: Fitter, f: Fitted) -> dict[str, dict[str, float]]:
    """Fitted simulator parameters of the temperature-channel effects ``f`` has."""
    out: dict[str, dict[str, float]] = {}
    if f.oven.overshoot is not None:
        out["oven_overshoot"] = {
            "overshoot": f.oven.overshoot[0],
            "period_s": f.oven.overshoot[1],
        }
    if f.structure.has("rtd_self_heating"):
        out["rtd_self_heating"] = {"offset_c": f.case.offset_c}
    return out
