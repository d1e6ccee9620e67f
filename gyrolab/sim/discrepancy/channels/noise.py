"""Noise-channel candidates: the Allan-curve terms (``arw``, ``bias_instability``,
``rate_random_walk``) the model lacks, each scored by the χ² drop of the weighted Allan fit
when it is added (docs/discrepancy.md, step 4)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gyrolab.sim.discrepancy import catalogue as cat
from gyrolab.sim.discrepancy import noise_fit as nf
from gyrolab.sim.discrepancy.catalogue import limit_entry
from gyrolab.sim.discrepancy.fitting import Fitted, Fitter
from gyrolab.sim.discrepancy.scored import Scored


def score(fx: Fitter, cur: Fitted) -> list[Scored]:
    """Allan-curve terms missing from the model: χ² drop when each is added."""
    out = []
    d = fx.d
    have = fx.noise_terms(cur.structure)
    for name in cat.on_channel("noise"):
        if name in have:
            continue
        alt = nf.fit_allan(cur.noise.curve, d.hr.dt, have | {name}, cur.quant_q, d.hr.white_sigma)
        dchi = cur.noise.chi2 - alt.chi2
        out.append(
            Scored(
                name,
                "noise",
                float(dchi),
                bool(dchi > nf.RRW_CHI2),
                {"allan_chi2": [cur.noise.chi2, alt.chi2], "params": alt.sim_params()[name]},
            )
        )
    return out


def rrw_limit(fx: Fitter, cur: Fitted) -> float | None:
    """Smallest K (°/h/√h) whose K²τ/3 added to the measured Allan curve makes the
    random-walk term pass its Δχ² rule."""
    c = cur.noise.curve
    have = fx.noise_terms(cur.structure)
    d = fx.d

    def passes(k_sim: float) -> bool:
        k = k_sim / (3600.0 * 60.0)
        ad = np.sqrt(c.adev**2 + k * k * c.tau / 3.0)
        cc = nf.AllanCurve(c.tau, ad, c.edf)
        a = nf.fit_allan(cc, d.hr.dt, have, cur.quant_q, d.hr.white_sigma)
        b = nf.fit_allan(cc, d.hr.dt, have | {"rate_random_walk"}, cur.quant_q, d.hr.white_sigma)
        return a.chi2 - b.chi2 > nf.RRW_CHI2

    lo, hi = 0.01, 100.0
    if not passes(hi):
        return None
    for _ in range(14):
        mid = math.sqrt(lo * hi)
        lo, hi = (lo, mid) if passes(mid) else (mid, hi)
    return hi


def limits(fx: Fitter, cur: Fitted) -> dict[str, dict[str, Any]]:
    """The random walk's limit (white and flicker noise are always in the bins' model)."""
    if cur.structure.has("rate_random_walk"):
        return {}
    return {
        "rate_random_walk": limit_entry(
            "rate_random_walk", rrw_limit(fx, cur), "Allan Δχ² with K²τ/3 added"
        )
    }


def params(fx: Fitter, f: Fitted) -> dict[str, dict[str, float]]:
    """Fitted simulator parameters of the Allan-curve terms ``f`` has."""
    return {k: v for k, v in f.noise.sim_params().items() if k in f.structure.effects}
