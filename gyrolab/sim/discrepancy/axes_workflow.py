"""The discrepancy workflow on a recording with several gyro axes (or several units on one
bench) sharing the chamber and the temperature channels.

Each axis gets its own analysis (its own deterministic terms and noise), but the thermal
fits — chamber air from the setpoints, case from the air, PT100 — are done once and
shared, since every axis sees the same chamber and the same case sensor. An effect
named on every axis is reported once, as shared (the thermal-chain effects
``oven_overshoot`` and ``rtd_self_heating`` are properties of the bench and come out
shared by construction); the others are reported per axis.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from gyrolab.sim.discrepancy.data import BenchData, from_arrays
from gyrolab.sim.discrepancy.fitting import ThermalFits
from gyrolab.sim.discrepancy.workflow import Result, Workflow
from gyrolab.sim.model import SimModel


def from_arrays_axes(
    rate_t0: float,
    rate_dt: float,
    rates: np.ndarray,
    pt100_t: np.ndarray,
    pt100_c: np.ndarray,
    oven_t: np.ndarray,
    oven_sp: np.ndarray,
    oven_pv: np.ndarray,
    **kw: Any,
) -> list[BenchData]:
    """One :class:`BenchData` per column of ``rates`` (samples × axes, °/s), all with the
    same temperature channels (see :func:`~gyrolab.sim.discrepancy.data.from_arrays`)."""
    r = np.asarray(rates, dtype=float)
    if r.ndim == 1:
        r = r[:, None]
    return [
        from_arrays(rate_t0, rate_dt, r[:, k], pt100_t, pt100_c, oven_t, oven_sp, oven_pv, **kw)
        for k in range(r.shape[1])
    ]


@dataclass
class AxesResult:
    """Per-axis results and the effects they share."""

    axes: list[Result]
    shared: list[str]
    """Effects named on every axis (in the first axis's order), reported once."""
    by_axis: list[list[str]]
    """Effects named on that axis only (not shared)."""

    def to_json(self) -> dict[str, Any]:
        return {
            "effects_shared": self.shared,
            "effects_by_axis": self.by_axis,
            "axes": [r.to_json() for r in self.axes],
        }


def run_discrepancy_axes(
    data: list[BenchData], model: SimModel | None = None, log: Any = None
) -> AxesResult:
    """Analyse every axis of ``data`` (same temperature channels) against ``model``."""
    from gyrolab.sim.model import nominal_model

    if not data:
        raise ValueError("no axes")
    m = model or nominal_model()
    ref = data[0]
    results: list[Result] = []
    thermal: ThermalFits | None = None
    for k, d in enumerate(data):
        if not (np.array_equal(d.pt100_c, ref.pt100_c) and np.array_equal(d.oven_pv, ref.oven_pv)):
            raise ValueError(f"axis {k}: temperature channels differ from axis 0's")
        wf = Workflow(replace(d), m, thermal)
        thermal = wf.fitter.thermal  # one chamber, one case: the thermal fits are shared
        results.append(wf.run((lambda s, k=k: log(f"axis {k}: {s}")) if log else None))
    named = [set(r.effects_found) | {e for s in r.ambiguous for e in s} for r in results]
    common = set.intersection(*named)
    shared = [e for e in results[0].effects_found if e in common]
    by_axis = [[e for e in r.effects_found if e not in common] for r in results]
    return AxesResult(results, shared, by_axis)
