"""Designed short calibration profiles (issue 30): ``gyrolab profile design --hours H``.

A short run must show the structured drift model (:mod:`gyrolab.compensation.prior`'s
reference basis: a polynomial in the die temperature F plus rate, hysteresis, warm-up
and the issue-23 terms) as much as a chamber can in H hours. The chamber is the limit:
the simulator's nominal chamber heats at most 3 °C/min but cools at 1.5 °C/min above
40 °C and slower below (``r_cool ∝ T_air − T_floor``: ≈ 0.5 °C/min at −10 °C), and the
case follows the air with τ_case ≈ 39 min, so in 3 h the case cannot reach −40 °C.

**Candidates.** A power-on hold at the ambient (the warm-up is seen at constant
temperature), then three legs: to one extreme setpoint, to the other, and back to the
ambient — so the die temperature rises *and* falls (both hysteresis branches) and the
rate term is seen in both signs. Both orders (hot first, cold first), the power-on hold
10 or 20 min, the legs' durations on a 5-min grid, the total exactly H.

**Criterion** (Bayesian I-optimality: what the short run leaves unknown of the drift where
the full temperature test would have put the unit): the case trace of each candidate from
the chamber's thermal model (:mod:`gyrolab.sim.thermal`, the chamber's heating and cooling
limits), its causal features at the prior's feature parameters, the design ``A`` of 36 s
means on the reference basis, the posterior precision ``H = AᵀA / s² + Σ⁻¹`` and

    u = sqrt(tr(W H⁻¹))   (°/s),   W = A_paperᵀ A_paper / n

the RMS posterior sd of the drift along the 13 h ``paper`` profile's trajectory in the
same chamber. Σ is the prior's covariance (without a prior: each component's sd 1e-2 °/s
at its regressor's largest value, weakly informative and scale-free) and ``s²`` the
variance of a 36 s mean inflated for correlated noise (:data:`S2_36S`). The candidate of
least ``u`` wins (the earlier one on a tie: deterministic). On synthetic units of one part
number (tests/test_prior.py's fleet) the weighting matters: a weight that counts each term
at its largest value picked a cold-first schedule whose MAP fits were 1.4× worse on the
staircase than the hot-first one this criterion picks.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from gyrolab.compensation.causal_features import CausalParams, hold, reading_features
from gyrolab.compensation.prior import Basis, FleetPrior
from gyrolab.profiles.profile import BUILTIN, Profile, Step
from gyrolab.sim.thermal import ThermalParams, kernel_params, thermal_kernel

#: variance of one 36 s mean of the residual (°/s)²: a 0.002 °/s 3.6 s scatter averaged
#: over 10 blocks, inflated ×20 for the flicker's correlation (n/n_eff on the suites)
S2_36S = (0.002**2 / 10.0) * 20.0
DEFAULT_SD_DPS = 1e-2
BLOCK_S = 36.0
GRID_S = 300.0
POWER_ON_S = (600.0, 1200.0)
MIN_LEG_S = 900.0
SOAK_S = 3 * 3600.0
#: what the criterion's drift is wanted over: ``paper`` (the 13 h profile's trajectory)
#: or ``soaks`` (that and a 3 h soak at each of its extreme setpoints)
WEIGHTS = ("paper", "soaks")


def case_trace(
    setpoints: list[tuple[float, float]], thermal: ThermalParams, ambient_c: float = 25.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(t, air, case)`` at 1 s of a schedule of ``(setpoint °C, duration s)`` from rest
    at ``ambient_c``: the unit is powered on at the room's temperature, as the simulator
    starts (:class:`gyrolab.sim.physics.Physics`)."""
    p = kernel_params(thermal)
    state = np.array([ambient_c, 0.0, ambient_c, ambient_c])
    air, case = [], []
    for sp, d in setpoints:
        n = int(round(d))
        a, c, di, dc = (np.empty(n) for _ in range(4))
        thermal_kernel(n, 1.0, float(sp), state, p, a, c, di, dc)
        air.append(a)
        case.append(c)
    a, c = np.concatenate(air), np.concatenate(case)
    return np.arange(a.size, dtype=float), a, c


@dataclass
class DesignBasis:
    """What a design is scored against: the reference basis, feature parameters, Σ."""

    basis: Basis
    params: CausalParams
    cov: np.ndarray

    def weight(
        self,
        thermal: ThermalParams,
        ambient_c: float = 25.0,
        soaks: bool = False,
    ) -> np.ndarray:
        """W = AᵀA / n of the full ``paper`` profile's trajectory in this chamber: the
        drift is wanted where the 13 h temperature test would have put the unit.
        ``soaks``: then also where the unit settles at the paper profile's extreme
        setpoints — a 3 h soak at each, after it (the case reaches the top setpoint plus
        the unit's self-heating, beyond the paper's 1 h at 60 °C)."""
        sched = [(s.setpoint_c, s.duration_s) for s in BUILTIN["paper"].steps]
        if soaks:
            sps = [s for s, _ in sched]
            sched += [(max(sps), SOAK_S), (min(sps), SOAK_S)]
        t, _, case = case_trace(sched, thermal, ambient_c)
        A = self.design(t, case)
        return A.T @ A / A.shape[0]

    def design(self, t: np.ndarray, case: np.ndarray) -> np.ndarray:
        """The design of 36 s means of a case trace on the reference basis."""
        tb = np.arange(BLOCK_S / 2, t[-1], BLOCK_S)
        return self.basis.design(hold(tb, t, reading_features(t, case, self.params)))

    @classmethod
    def of(cls, prior: FleetPrior | None, lo: float, hi: float) -> DesignBasis:
        if prior is not None:
            big = max(prior.clusters, key=lambda c: len(c.members))
            return cls(prior.basis, big.params(), big.cov)
        b = Basis(lo, hi, 4)
        return cls(b, CausalParams(tau_s=300.0), np.diag((DEFAULT_SD_DPS / b.scale()) ** 2))


def drift_uncertainty(t: np.ndarray, case: np.ndarray, db: DesignBasis, W: np.ndarray) -> float:
    """The criterion (module docstring) of a case trace ``case`` (°C) at times ``t``: the
    RMS posterior sd (°/s) of the drift along the reference trajectory, ``sqrt(tr(W H⁻¹))``."""
    A = db.design(t, case)
    H = A.T @ A / S2_36S + np.linalg.inv(db.cov)
    return float(np.sqrt(np.trace(np.linalg.solve(H, W))))


def candidates(
    hours: float, setpoint_min_c: float, setpoint_max_c: float, ambient_c: float
) -> list[list[tuple[float, float]]]:
    """Every schedule of the candidate family (module docstring) lasting ``hours``."""
    total = round(hours * 3600.0)
    out = []
    for first, second in ((setpoint_max_c, setpoint_min_c), (setpoint_min_c, setpoint_max_c)):
        for p0 in POWER_ON_S:
            rest = total - p0
            n = int((rest - 3 * MIN_LEG_S) // GRID_S)
            for i in range(n + 1):
                for j in range(n + 1 - i):
                    d1 = MIN_LEG_S + i * GRID_S
                    d2 = MIN_LEG_S + j * GRID_S
                    d3 = rest - d1 - d2
                    if d3 >= MIN_LEG_S:
                        out.append([(ambient_c, p0), (first, d1), (second, d2), (ambient_c, d3)])
    return out


def design_profile(
    hours: float,
    *,
    thermal: ThermalParams | None = None,
    setpoint_min_c: float = -40.0,
    setpoint_max_c: float = 60.0,
    ambient_c: float = 25.0,
    prior: FleetPrior | None = None,
    name: str | None = None,
    weight: str = "paper",
) -> tuple[Profile, dict[str, Any]]:
    """The profile of largest information gain in ``hours`` (module docstring) and a
    record of the design (criterion, case range, the chamber's limits)."""
    if not 3 * MIN_LEG_S / 3600.0 + POWER_ON_S[0] / 3600.0 <= hours <= 24.0:
        raise ValueError(
            f"--hours {hours:g}: a designed profile needs 0.92 to 24 h (three legs of at "
            "least 15 min after a 10 min power-on hold)"
        )
    if not setpoint_min_c < ambient_c < setpoint_max_c:
        raise ValueError("the ambient must lie between the setpoint limits")
    if weight not in WEIGHTS:
        raise ValueError(f"weight {weight!r}: one of {', '.join(WEIGHTS)}")
    thermal = thermal or ThermalParams()
    db = DesignBasis.of(prior, setpoint_min_c, setpoint_max_c)
    W = db.weight(thermal, ambient_c, soaks=weight == "soaks")
    best: tuple[float, list[tuple[float, float]], np.ndarray] | None = None
    cands = candidates(hours, setpoint_min_c, setpoint_max_c, ambient_c)
    for sched in cands:
        t, _, case = case_trace(sched, thermal, ambient_c)
        u = drift_uncertainty(t, case, db, W)
        if best is None or u < best[0] * (1.0 - 1e-9):
            best = (u, sched, case)
    assert best is not None
    unc, sched, case = best
    labels = ["power-on", "first extreme", "second extreme", "back to ambient"]
    steps = tuple(
        Step(float(sp), float(d), lab) for (sp, d), lab in zip(sched, labels, strict=True)
    )
    nm = name or f"design-{hours:g}h"
    record = {
        "hours": hours,
        "weight": weight,
        "candidates": len(cands),
        "drift_sd_deg_per_s": unc,
        "case_range_c": [float(case.min()), float(case.max())],
        "chamber": {
            "heat_rate_c_per_min": 60.0 * thermal.heat_rate_c_per_s,
            "cool_rate_c_per_min": 60.0 * thermal.cool_rate_c_per_s,
            "cool_knee_c": thermal.cool_knee_c,
            "cool_floor_c": thermal.cool_floor_c,
            "case_tau_s": thermal.case_tau_s,
        },
        "prior": None if prior is None else {"units": len(prior.units)},
    }
    desc = (
        f"designed by gyrolab profile design --hours {hours:g}: expected drift sd "
        f"{unc:.2g} deg/s over the range, simulated case {case.min():.1f}..{case.max():.1f} °C"
    )
    return Profile(nm, steps, ambient_c=ambient_c, description=desc), record


__all__ = ["candidates", "case_trace", "design_profile", "drift_uncertainty"]
