"""Detection limits: the smallest amplitude of each effect not in the model that this run
would have revealed (``discrepancy.json`` → ``detection_limits``).

A run that names nothing does not say "not there"; it says "smaller than this". For an
effect whose signature is linear in its amplitude ``a`` (columns ``x`` of the gyro
design, or a constant on the PT100 channel), the expected score when it is present is the
non-centrality of its whitened signature after projecting out the current model::

    λ(a) = a² ‖P⊥ L⁻¹ x‖² / σ²,     E[ΔBIC] ≈ λ + 1 − k ln n

(``L⁻¹`` the whitener of the noise covariance the candidates are judged with, ``σ²``
the innovation variance, k the candidate's parameters, n the bins). The limit is the
``a`` at which the expected score reaches the significance threshold (the median
detection point: at 2× the limit λ is four times larger, at ½× four times smaller).
Nonlinear shape parameters are held at a stated reference value (``at``);
``thermal_lag`` is linearized for τ ≪ τ_case
(``bias(T_d) ≈ bias(T_c) − τ·bias′(T_c)·dT_c/dt``). Stochastic and sample-level effects
use their own criteria: the Allan Δχ² for ``rate_random_walk`` (found by bisection on
the measured curve plus K²τ/3), the lattice rule for ``quantization``, the amplitude
rule for ``outliers``; ``rtd_self_heating`` its channel's ΔBIC (on the effective number
of readings) and RMS-gain rules. ``oven_overshoot`` has no single amplitude (a second-order
chamber differs from the first-order one in speed as well as in overshoot): its limit is
stated at the reference period without the first-order refit's absorption, an
optimistic bound.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from gyrolab.sim.discrepancy import noise_fit as nf
from gyrolab.sim.discrepancy.gyro_fit import GyroStructure, design
from gyrolab.sim.discrepancy.thermal_fit import OVEN_FLOOR_C, air_model, effective_n

if TYPE_CHECKING:  # pragma: no cover
    from gyrolab.sim.discrepancy.workflow import Fitted, Workflow

REFERENCE = {
    "hysteresis": ("width_c", 1.0),
    "warmup": ("tau_s", 600.0),
    "periodic": ("period_s", 900.0),
}
"""Shape parameters the limits of nonlinear effects are stated at (simulator defaults)."""

PARAM = {
    "cubic_temp": ("c3", "deg/s/degC^3"),
    "thermal_rate": ("k", "deg/s per degC/min"),
    "thermal_lag": ("tau_s", "s"),
    "hysteresis": ("h", "deg/s"),
    "warmup": ("A", "deg/s"),
    "aging_ramp": ("r", "deg/s/h"),
    "periodic": ("A", "deg/s"),
    "rate_random_walk": ("K", "deg/h/sqrt(h)"),
    "quantization": ("q", "deg/s"),
    "outliers": ("amplitude", "deg/s"),
    "rtd_self_heating": ("offset_c", "degC"),
    "oven_overshoot": ("overshoot", "fraction"),
}


def _entry(name: str, value: float | None, method: str, **at: float) -> dict[str, Any]:
    p, unit = PARAM[name]
    e: dict[str, Any] = {"parameter": p, "unit": unit, "limit": value, "method": method}
    if at:
        e["at"] = at
    return e


def gyro_limits(wf: Workflow, cur: Fitted, threshold: float) -> dict[str, dict[str, Any]]:
    """Limits of the deterministic gyro effects not in ``cur`` (module docstring)."""
    from gyrolab.sim.discrepancy.gyro_fit import GYRO_EFFECTS

    ctx = cur.ctx
    base = cur.gyro.struct
    # the noise model the candidates are judged with (the saturated model's, the better
    # of it and its random-walk alternative for the current model)
    _, noises = wf.judging_noises(cur)
    n = ctx.y.size
    ln_n = math.log(n)
    fits = [(wf.cov_fit(base, ctx, w), w, k) for w, k in noises]
    gfit, w, _ = min(fits, key=lambda f: f[0].bic + f[2] * ln_n)
    X0, _ = design(base, ctx)
    s0 = np.sqrt(np.mean(X0 * X0, axis=0))
    s0[s0 == 0] = 1.0
    Q, _ = np.linalg.qr(w(X0 / s0))
    sigma2 = gfit.gls.rss / gfit.gls.n

    def energy(cols: np.ndarray) -> np.ndarray:
        z = w(cols.reshape(n, -1))
        z = z - Q @ (Q.T @ z)
        return (z * z).sum(axis=0)

    out: dict[str, dict[str, Any]] = {}
    for name in GYRO_EFFECTS:
        if name in base.names or name == "bias_poly":
            continue
        if name == "cubic_temp" and ctx.poly_order >= 3:
            continue
        at: dict[str, float] = {}
        if name == "thermal_lag":
            c = cur.gyro.coef()
            T = np.interp(ctx.t, ctx.grid_t, ctx.case_c) - 25.0
            slope = np.zeros_like(T)
            for i in range(1, 5):
                slope += i * c.get(f"bias_poly.c{i}", 0.0) * T ** (i - 1)
            slope += 3.0 * c.get("cubic_temp.c3", 0.0) * T**2
            x = -slope * np.interp(ctx.t, ctx.grid_t, ctx.dcase)
            e = float(energy(x)[0])
            k = 1
        else:
            th = dict(base.theta)
            if name in REFERENCE:
                key, val = REFERENCE[name]
                th[name] = val
                at[key] = val
            X, cols = design(GyroStructure(base.names + [name], th), ctx)
            sel = [i for i, c in enumerate(cols) if c.startswith(name + ".")]
            en = energy(X[:, sel])
            e = float(np.mean(en))  # periodic: sin and cos averaged over the phase
            k = len(sel) + int(name in REFERENCE)
        need = max(threshold + k * ln_n - 1.0, 1e-9)
        lim = math.sqrt(need * sigma2 / e) if e > 0 else None
        out[name] = _entry(name, lim, "expected ΔBIC of the whitened signature", **at)
    return out


def rtd_limit(wf: Workflow, cur: Fitted, threshold: float, min_gain: float) -> float | None:
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
    v1 = max(float(np.mean(cur.case.resid**2)), (0.5 * wf.pt_noise) ** 2)
    ne = effective_n(cur.case.resid, floor=0.5 * wf.pt_noise)
    if e <= 0:
        return None
    # ΔBIC: ne·ln(1 + δ²e/v1) − ln ne > threshold;  gain: v1/(v1 + δ²e) < (1 − g)²
    d_bic = math.sqrt(v1 * math.expm1((threshold + math.log(ne)) / ne) / e)
    d_gain = math.sqrt(v1 * (1.0 / (1.0 - min_gain) ** 2 - 1.0) / e)
    return max(d_bic, d_gain)


def overshoot_limit(
    wf: Workflow, cur: Fitted, threshold: float, min_gain: float, period_s: float = 1200.0
) -> float | None:
    """Smallest overshoot (at the reference damped period) whose extra air response over
    the current first-order model passes the oven channel's rules; the first-order
    refit's partial absorption of it is neglected (the limit is optimistic by that)."""
    d = wf.d
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
        return dbic > threshold and 1.0 - math.sqrt(v1 / v0) > min_gain

    lo, hi = 1e-3, 0.9
    if not passes(hi) or passes(lo):
        return None  # no amplitude separates detected from not: see the module docstring
    for _ in range(12):
        mid = math.sqrt(lo * hi)
        lo, hi = (lo, mid) if passes(mid) else (mid, hi)
    return hi


def rrw_limit(wf: Workflow, cur: Fitted) -> float | None:
    """Smallest K (°/h/√h) whose K²τ/3 added to the measured Allan curve makes the
    random-walk term pass its Δχ² rule."""
    c = cur.noise.curve
    have = wf._noise_terms(cur)
    d = wf.d

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


def detection_limits(wf: Workflow, cur: Fitted) -> dict[str, dict[str, Any]]:
    """``detection_limits`` of ``discrepancy.json``: every vocabulary effect not in the
    model, in its parameter's units."""
    from gyrolab.sim.discrepancy.workflow import GYRO_SIG, TEMP_MIN_GAIN, TEMP_SIG

    st = cur.structure
    out = gyro_limits(wf, cur, GYRO_SIG)
    if not st.has("rate_random_walk"):
        out["rate_random_walk"] = _entry(
            "rate_random_walk", rrw_limit(wf, cur), "Allan Δχ² with K²τ/3 added"
        )
    if not st.has("quantization"):
        hr = wf.d.hr
        q = max(nf.LATTICE_RATIO * wf.lsb, nf.LATTICE_NOISE_RATIO * hr.white_sigma)
        out["quantization"] = _entry("quantization", q, "lattice rule (ADC LSB, sample noise)")
    if not st.has("outliers"):
        # the amplitude rule A > 4σ_e is the binding one at any rate the tail test sees
        # (a few spikes beyond 4σ_e already give a likelihood ratio ≫ 40 on a clean tail)
        out["outliers"] = _entry(
            "outliers", 4.0 * wf.d.hr.e_sigma, "amplitude rule (4 σ of the second difference)"
        )
    if not st.has("rtd_self_heating"):
        out["rtd_self_heating"] = _entry(
            "rtd_self_heating",
            rtd_limit(wf, cur, TEMP_SIG, TEMP_MIN_GAIN),
            "PT100 ΔBIC (effective readings) and RMS gain",
        )
    if not st.has("oven_overshoot"):
        out["oven_overshoot"] = _entry(
            "oven_overshoot",
            overshoot_limit(wf, cur, TEMP_SIG, TEMP_MIN_GAIN),
            "oven ΔBIC (effective readings) and RMS gain, no refit absorption; none when a "
            "second-order chamber at this period differs at any overshoot",
            period_s=1200.0,
        )
    return out
