"""Thermal model of the oven test: chamber air → gyro case → gyro die (lumped masses).

Chamber air ``Ta`` (°C) under the oven's setpoint controller, first order with rate limits::

    dTa/dt = clip((SP − Ta) / τ_air, −r_cool(Ta), +r_heat)
    r_cool(Ta) = r_cool0 · clip((Ta − T_floor) / (T_knee − T_floor), 0, 1)

Cooling slows below ``T_knee`` and stops at ``T_floor``, the way a compressor chamber's
capacity falls with its evaporator temperature. With the ``oven_overshoot`` effect the
controller is second order (natural angular frequency ω, damping ζ), velocity still
rate-limited::

    dv/dt = ω² (SP − Ta) − 2 ζ ω v,   v ← clip(v, −r_cool(Ta), r_heat),   dTa/dt = v

Gyro case ``Tc`` (metal shell, PCBs and rubber pad as one heat capacity ``C_case``, J/K)
exchanges heat with the air through ``R_case`` (K/W) and is warmed by the gyro's own
electrical power ``P`` (W)::

    C_case dTc/dt = (Ta − Tc) / R_case + P      →  τ_case = R_case C_case

The die ``Td`` lags the case through ``τ_die``: ``dTd/dt = (Tc − Td) / τ_die``. The PT100
sits on the case and reads ``Tc``.

Integration is per ADC sample (Δt = 1/rate): exact exponential steps for case and die,
semi-implicit Euler for the air (Δt ≤ 1 s ≪ τ_air). The state after any number of
``advance`` calls depends only on the samples elapsed and the setpoints commanded, so a
bench that changes the setpoint between blocks gets the same physics as a schedule.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numba
import numpy as np


@dataclass(frozen=True)
class ThermalParams:
    """Thermal parameters, SI units (temperatures °C, rates °C/s, times s)."""

    air_tau_s: float = 240.0
    heat_rate_c_per_s: float = 3.0 / 60.0
    cool_rate_c_per_s: float = 1.5 / 60.0
    cool_knee_c: float = 40.0
    cool_floor_c: float = -41.0
    case_capacity_j_per_k: float = 580.0
    case_resistance_k_per_w: float = 4.0
    gyro_power_w: float = 1.0
    die_tau_s: float = 120.0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"thermal {f.name} must be a finite number")
        for name in (
            "air_tau_s",
            "heat_rate_c_per_s",
            "cool_rate_c_per_s",
            "case_capacity_j_per_k",
            "case_resistance_k_per_w",
        ):
            if not getattr(self, name) > 0:
                raise ValueError(f"thermal {name} must be > 0")
        if self.die_tau_s < 0 or self.gyro_power_w < 0:
            raise ValueError("thermal die_tau_s and gyro_power_w must be >= 0")
        if not self.cool_knee_c > self.cool_floor_c:
            raise ValueError("thermal cool_knee_c must be above cool_floor_c")

    @property
    def case_tau_s(self) -> float:
        """τ_case = R_case · C_case (s)."""
        return self.case_resistance_k_per_w * self.case_capacity_j_per_k

    @property
    def self_heating_c(self) -> float:
        """Steady case rise above the air from the gyro's power, P · R_case (°C)."""
        return self.gyro_power_w * self.case_resistance_k_per_w

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@numba.njit(cache=True, nogil=True, inline="always")
def air_rate(
    v: float,
    a: float,
    setpoint: float,
    tau_air: float,
    r_heat: float,
    r_cool: float,
    w: float,
    zeta: float,
    dt: float,
) -> float:  # pragma: no cover - compiled
    """The chamber air's next rate of change (°C/s): the controller's demand — first order
    ``(SP − a)/τ_air`` (ω = 0) or the second-order loop ``v̇ = ω²(SP − a) − 2ζωv`` — clamped
    to the heating limit and to the cooling limit ``r_cool`` at the air's temperature."""
    if w > 0.0:
        v += dt * (w * w * (setpoint - a) - 2.0 * zeta * w * v)
    else:
        v = (setpoint - a) / tau_air
    if v > r_heat:
        return r_heat
    if v < -r_cool:
        return -r_cool
    return v


# state vector: [air, air_velocity, case, die]
@numba.njit(cache=True, nogil=True)
def thermal_kernel(
    n: int,
    dt: float,
    setpoint: float,
    state: np.ndarray,
    p: np.ndarray,
    air: np.ndarray,
    case: np.ndarray,
    die: np.ndarray,
    dcase: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Advance ``state`` by ``n`` samples; write per-sample air/case/die and dTc/dt.

    ``p`` = [τ_air, r_heat, r_cool0, T_knee, T_floor, τ_case, ΔT_self, τ_die, ω, ζ]
    (ω = 0: first-order controller). Values are those at each sample's time, before the
    step to the next sample.
    """
    tau_air, r_heat, r_cool0, knee, floor = p[0], p[1], p[2], p[3], p[4]
    tau_case, dself, tau_die, w, zeta = p[5], p[6], p[7], p[8], p[9]
    kc = 1.0 - math.exp(-dt / tau_case)
    kd = 1.0 - math.exp(-dt / tau_die) if tau_die > 0 else 1.0
    a, v, c, d = state[0], state[1], state[2], state[3]
    for i in range(n):
        air[i] = a
        case[i] = c
        die[i] = d
        dcase[i] = (a + dself - c) / tau_case
        frac = (a - floor) / (knee - floor)
        if frac > 1.0:
            frac = 1.0
        elif frac < 0.0:
            frac = 0.0
        v = air_rate(v, a, setpoint, tau_air, r_heat, r_cool0 * frac, w, zeta, dt)
        c_next = c + (a + dself - c) * kc
        d += (c - d) * kd
        a += dt * v
        c = c_next
    state[0], state[1], state[2], state[3] = a, v, c, d


def kernel_params(
    tp: ThermalParams, *, die_tau_s: float | None = None, omega: float = 0.0, zeta: float = 0.0
) -> np.ndarray:
    """Pack the kernel's parameter vector (see :func:`thermal_kernel`)."""
    return np.array(
        [
            tp.air_tau_s,
            tp.heat_rate_c_per_s,
            tp.cool_rate_c_per_s,
            tp.cool_knee_c,
            tp.cool_floor_c,
            tp.case_tau_s,
            tp.self_heating_c,
            tp.die_tau_s if die_tau_s is None else die_tau_s,
            omega,
            zeta,
        ],
        dtype=np.float64,
    )


def lowpass(u: np.ndarray, alpha: float, c0: float) -> np.ndarray:
    """A first-order lag sampled on a uniform grid: ``c_{k+1} = c_k + α (u_k − c_k)``,
    ``c_0 = c0`` (a node following ``u`` with ``α = 1 − e^{−Δt/τ}``)."""
    from scipy.signal import lfilter  # not on the simulator's import path

    c = np.empty(u.size)
    c[0] = c0
    if u.size > 1:
        c[1:], _ = lfilter([alpha], [1.0, alpha - 1.0], u[:-1], zi=[(1.0 - alpha) * c0])
    return c
