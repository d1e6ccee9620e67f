"""Localize a model's disagreement with the measurement (the ``localize`` entry of every
``steps`` item of ``discrepancy.json``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from gyrolab.sim.discrepancy.data import BenchData
from gyrolab.sim.discrepancy.fitting import LF_WINDOW_S, Fitted, moving_average


def localize(d: BenchData, f: Fitted) -> dict[str, Any]:
    """Where the current model and the measurement disagree (docs/discrepancy.md, step 5):
    the worst profile steps of the low-frequency residual, its mean and RMS per 10 °C band,
    its correlation with dT/dt, the τ range where the Allan curve leaves the model's, and
    the oven steps with the largest process-value residual."""
    r = moving_average(f.resid, max(1, int(round(LF_WINDOW_S / d.bin_s))))
    steps = []
    for s in d.steps:
        m = (d.t >= s.t0) & (d.t < s.t1)
        if m.sum() >= 2:
            steps.append(
                {
                    "step": s.index,
                    "setpoint_c": s.setpoint_c,
                    "lf_rms_dps": float(np.sqrt(np.mean(r[m] ** 2))),
                }
            )
    worst = sorted(steps, key=lambda x: -x["lf_rms_dps"])[:3]
    T = np.interp(d.t, f.ctx.grid_t, f.ctx.case_c)
    edges = np.arange(np.floor(T.min() / 10) * 10, np.ceil(T.max() / 10) * 10 + 10, 10)
    tbins = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        m = (T >= lo) & (T < hi)
        if m.sum() >= 3:
            tbins.append(
                {
                    "range_c": [float(lo), float(hi)],
                    "mean_dps": float(np.mean(r[m])),
                    "rms_dps": float(np.sqrt(np.mean(r[m] ** 2))),
                }
            )
    dT = 60.0 * np.interp(d.t, f.ctx.grid_t, f.ctx.dcase)
    corr = float(np.corrcoef(r, dT)[0, 1]) if np.std(dT) > 0 and np.std(r) > 0 else 0.0
    c = f.noise.curve
    z = np.log(c.adev / f.noise.model_adev()) * np.sqrt(c.edf / 2.0) * 2.0
    bad = np.abs(z) > 3.0
    tau_range = [float(c.tau[bad].min()), float(c.tau[bad].max())] if bad.any() else None
    ov = f.oven.resid
    oven_steps = []
    for s in d.steps:
        m = (d.oven_t >= s.t0) & (d.oven_t < s.t1)
        if m.any():
            oven_steps.append({"step": s.index, "max_abs_c": float(np.max(np.abs(ov[m])))})
    return {
        "worst_steps": worst,
        "temperature_bins": tbins,
        "corr_residual_dTdt": corr,
        "allan_tau_range_s": tau_range,
        "oven_worst_steps": sorted(oven_steps, key=lambda x: -x["max_abs_c"])[:3],
    }
