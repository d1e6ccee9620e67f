"""Temperature-channel candidates: ``oven_overshoot`` on the chamber's process value and
``rtd_self_heating`` on the PT100, each scored by ΔBIC over the channel's effective number
of readings and by how much it cuts the channel's RMS (docs/discrepancy.md).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gyrolab.sim.discrepancy import catalogue as cat
from gyrolab.sim.discrepancy.catalogue import limit_entry
from gyrolab.sim.discrepancy.fitting import Fitted, Fitter
from gyrolab.sim.discrepancy.scored import Scored
from gyrolab.sim.discrepancy.thermal_fit import (
    OVEN_FLOOR_C,
    air_model,
    delta_bic_channel,
    effective_n,
)

TEMP_SIG = 25.0
"""ΔBIC above which a temperature-channel candidate is significant."""
TEMP_MIN_GAIN = 0.3
"""…and it must also cut that channel's residual RMS by at least this fraction."""


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
            "pt100_noise_c": fx.pt_noise,
            "effective_n": ne,
            "initial_case_c": cand.initial_c,
        },
    )


SCORERS = {"oven_overshoot": _overshoot, "rtd_self_heating": _self_heating}


def score(fx: Fitter, cur: Fitted) -> list[Scored]:
    """Every temperature-channel candidate the model lacks."""
    return [s(fx, cur) for name, s in SCORERS.items() if not cur.structure.has(name)]


def rtd_limit(fx: Fitter, cur: Fitted) -> float | None:
    """Smallest PT100 offset δ the temperature channel would name: the constant's part
    that the case model (ΔT_self, initial case, with its prior) cannot absorb, against the
    ΔBIC (effective readings) and the RMS-gain rules."""
    dm = cur.case.design
    if dm is None:
        return None
    n_pt = cur.case.resid.size
    one = np.concatenate([np.ones(n_pt), [0.0]])
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
    """Smallest overshoot (at the damped period the effect states its limit at) whose
    extra air response over the current first-order model passes the oven channel's
    rules; the first-order refit's partial absorption of it is neglected (the limit is
    optimistic by that)."""
    d = fx.d
    period_s = cat.candidate("oven_overshoot").limit_at["period_s"]  # type: ignore[union-attr]
    x = cur.oven.x
    a0 = float(cur.oven.pred[0])
    plain = cur.oven.pred
    r1 = cur.oven.resid
    v1 = max(float(np.mean(r1**2)), OVEN_FLOOR_C**2)
    ne = effective_n(r1, floor=OVEN_FLOOR_C)

    def passes(o: float) -> bool:
        sig = air_model(d.oven_t, d.oven_t, d.oven_sp, a0, x, (o, period_s), cur.oven.form) - plain
        v0 = v1 + float(np.mean(sig**2))
        dbic = ne * math.log(v0 / v1) - 2.0 * math.log(ne)
        return dbic > TEMP_SIG and 1.0 - math.sqrt(v1 / v0) > TEMP_MIN_GAIN

    lo, hi = 1e-3, 0.9
    if not passes(hi) or passes(lo):
        return None  # no amplitude separates detected from not (limits.py)
    for _ in range(12):
        mid = math.sqrt(lo * hi)
        lo, hi = (lo, mid) if passes(mid) else (mid, hi)
    return hi


def limits(fx: Fitter, cur: Fitted) -> dict[str, dict[str, Any]]:
    """Detection limits of the temperature-channel effects the model lacks."""
    out: dict[str, dict[str, Any]] = {}
    if not cur.structure.has("rtd_self_heating"):
        out["rtd_self_heating"] = limit_entry(
            "rtd_self_heating",
            rtd_limit(fx, cur),
            "PT100 ΔBIC (effective readings) and RMS gain",
        )
    if not cur.structure.has("oven_overshoot"):
        out["oven_overshoot"] = limit_entry(
            "oven_overshoot",
            overshoot_limit(fx, cur),
            "oven ΔBIC (effective readings) and RMS gain, no refit absorption; none when a "
            "second-order chamber at this period differs at any overshoot",
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
