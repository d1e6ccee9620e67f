"""Physics of the break-the-model family: a MEMS gyro in a climatic chamber, written
without any of gyrolab's simulator or feature code (numpy and scipy only), with effects
outside the class of gyrolab's causal models (issue 23).

Time grid: the thermal state and the deterministic drift at 1 Hz (``dt = 1 s``), the
output at ``rate_hz`` (10 Hz) with the drift interpolated linearly between seconds.

**Chamber air** ``A`` follows the setpoint ``s`` at a limited rate::

    dA/dt = clip((s − A)/τ_c, −r_cool, +r_heat)       τ_c = 300 s, 3 / 1.5 °C/min

**Two-node thermal network**, package/case ``P`` (where the PT100 sits) and die ``D``
(what the drift follows), with self-heating ``q`` that grows with the die temperature
(I²R of the drive electronics)::

    dP/dt = (A − P)/τ_pa + (D − P)/τ_back
    dD/dt = (P − D)/τ_dp + q0 · (1 + β (D − 25)/50)

linear and time-invariant, so it is stepped exactly with the matrix exponential of the
augmented system (input A held over each second). At power-on ``P = D`` (the unit is at
rest, unpowered): the die then warms above the package by ≈ q0·τ_dp — the warm-up is the
self-heating transient, with the die's own time constants, not an exponential in t.

**Deterministic drift** (°/s), ``u = (D − 25)/50``, ``Ḋ`` in °C/min::

    quartic bias      Σ_{k=0..4} c_k u^k
    hysteresis        Σ_i h_i (D − p_i)/(w_i(D)/2),  p_i = clip(p_i, D − w_i/2, D + w_i/2),
                      w_i(D) = w_i0 · (1 + κ u)        (width depends on temperature)
    rate (asymmetric) k₊ max(Ḋ, 0) + k₋ min(Ḋ, 0) + k₂ Ḋ|Ḋ|
    thermal gradient  g (D − P)
    aging             a · log1p(t_abs / τ_age)         (t_abs: since the calibration run)

**Noise** (not in the true drift): synthetic (white, flicker, rate random walk,
Gauss–Markov; :func:`synthetic_noise`) or a real static record scaled to the unit's ARW
(:mod:`benchmarks.breakfam.realnoise`), in both cases multiplied by ``1 + γ u``
(temperature-dependent noise).

**PT100**: the package temperature through a first-order sensor lag τ_s, read once a
second with white noise σ_pt and a 1 mK resolution.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import expm

DT = 1.0  # s, thermal / drift grid
AIR_TAU_S = 300.0
AIR_HEAT_C_PER_S = 3.0 / 60.0
AIR_COOL_C_PER_S = 1.5 / 60.0


@dataclass(frozen=True)
class Unit:
    """One gyro of the family: its thermal network, drift and noise parameters."""

    tau_pa: float  # s, air → package
    tau_back: float  # s, die → package coupling
    tau_dp: float  # s, package → die
    q0: float  # °C/s, self-heating at 25 °C
    beta: float  # self-heating temperature coefficient (per 50 °C)
    tau_sensor: float  # s, PT100 lag
    pt_noise_c: float  # °C, PT100 white noise
    c: tuple[float, ...]  # quartic coefficients c0..c4, °/s
    h: tuple[float, ...]  # hysteresis weights, °/s
    w0: tuple[float, ...]  # hysteresis widths at 25 °C, °C
    kappa: float  # width temperature coefficient (per 50 °C)
    k_pos: float  # °/s per °C/min, heating
    k_neg: float  # °/s per °C/min, cooling
    k2: float  # °/s per (°C/min)²
    g: float  # °/s per °C of die − package
    age_a: float  # °/s
    age_tau_s: float
    arw: float  # °/√h
    flicker_b: float  # °/h (IEEE B)
    rrw_k: float  # °/h/√h
    gm_sigma: float  # °/h
    gm_tau_s: float
    gamma: float  # noise temperature coefficient (per 50 °C)
    real_noise: bool = False
    effects: tuple[str, ...] = field(default=())
    index: int = 0  # u of draw_unit (the die thermometer's offset is drawn from it)


def draw_unit(u: int, real_noise: bool) -> Unit:
    """Unit ``u`` of the family, drawn from ``default_rng([23, u])``. Every effect is
    present with probability 0.75, so some units lack some (term selection must not keep
    what a unit does not have)."""
    rng = np.random.default_rng([23, u])

    def on(name: str, present: list[str]) -> bool:
        keep = bool(rng.uniform() < 0.75)
        if keep:
            present.append(name)
        return keep

    present: list[str] = []
    hyst = on("hysteresis", present)
    rate = on("rate", present)
    grad = on("gradient", present)
    age = on("aging", present)
    quart = on("quartic", present)
    selfh = on("self_heating", present)
    tnoise = on("noise_vs_temperature", present)
    c = [
        float(rng.uniform(-0.05, 0.05)),
        0.0192 * float(rng.uniform(0.6, 1.4)),
        0.0085 * float(rng.uniform(-1.5, 1.5)),
        float(rng.normal(0.0, 0.002)),
        float(rng.normal(0.0, 0.002)) if quart else 0.0,
    ]
    nh = 3
    tau_dp = float(rng.uniform(40.0, 1000.0))
    dt_self = float(rng.uniform(0.5, 4.0)) if selfh else 0.0  # °C, die above package
    return Unit(
        tau_pa=float(rng.uniform(150.0, 900.0)),
        tau_back=float(rng.uniform(2000.0, 8000.0)),
        tau_dp=tau_dp,
        q0=dt_self / tau_dp,
        beta=float(rng.uniform(-0.3, 0.5)) if selfh else 0.0,
        tau_sensor=float(rng.uniform(5.0, 40.0)),
        pt_noise_c=0.003,
        c=tuple(c),
        h=tuple(float(rng.uniform(0.0, 1.2e-3)) if hyst else 0.0 for _ in range(nh)),
        w0=tuple(float(x) for x in np.sort(rng.uniform(0.3, 4.0, nh))),
        kappa=float(rng.uniform(-0.7, 0.7)) if hyst else 0.0,
        k_pos=float(rng.uniform(-3e-3, 3e-3)) if rate else 0.0,
        k_neg=float(rng.uniform(-3e-3, 3e-3)) if rate else 0.0,
        k2=float(rng.uniform(-6e-4, 6e-4)) if rate else 0.0,
        g=float(rng.uniform(-1.5e-3, 1.5e-3)) if grad else 0.0,
        age_a=float(rng.uniform(-1e-4, 1e-4)) if age else 0.0,
        age_tau_s=float(rng.uniform(3600.0, 86400.0)),
        arw=0.0523 * float(rng.uniform(0.8, 1.2)),
        flicker_b=float(rng.uniform(0.2, 0.7)),
        rrw_k=float(rng.uniform(0.0, 0.5)),
        gm_sigma=float(rng.uniform(0.0, 0.4)),
        gm_tau_s=float(rng.uniform(200.0, 2000.0)),
        gamma=float(rng.uniform(-0.3, 0.3)) if tnoise else 0.0,
        real_noise=real_noise,
        effects=tuple(present),
        index=u,
    )


def air_temperature(setpoints: np.ndarray, a0: float) -> np.ndarray:
    """Chamber air at 1 Hz for per-second setpoints (module docstring)."""
    a = np.empty(setpoints.size)
    x = float(a0)
    for i, s in enumerate(setpoints):
        v = (float(s) - x) / AIR_TAU_S
        x += DT * min(max(v, -AIR_COOL_C_PER_S), AIR_HEAT_C_PER_S)
        a[i] = x
    return a


def thermal(unit: Unit, air: np.ndarray, t0_c: float) -> tuple[np.ndarray, np.ndarray]:
    """Package and die temperature (°C) at 1 Hz: the network stepped exactly (matrix
    exponential of the augmented system [P, D, A, 1]); at rest at ``t0_c`` at power-on."""
    qb = unit.q0 * unit.beta / 50.0
    M = np.zeros((4, 4))
    M[0] = [-1.0 / unit.tau_pa - 1.0 / unit.tau_back, 1.0 / unit.tau_back, 1.0 / unit.tau_pa, 0.0]
    M[1] = [1.0 / unit.tau_dp, -1.0 / unit.tau_dp + qb, 0.0, unit.q0 - 25.0 * qb]
    step = expm(M * DT)
    x = np.array([t0_c, t0_c, 0.0, 1.0])
    P = np.empty(air.size)
    D = np.empty(air.size)
    for i, a in enumerate(air):
        x[2] = a
        x = step @ x
        P[i], D[i] = x[0], x[1]
    return P, D


def pt100(unit: Unit, P: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """1 Hz PT100 readings of the package: sensor lag, white noise, 1 mK resolution."""
    a = 1.0 - math.exp(-DT / unit.tau_sensor)
    s = np.empty(P.size)
    x = float(P[0])
    for i, p in enumerate(P):
        x += a * (float(p) - x)
        s[i] = x
    s = s + unit.pt_noise_c * rng.standard_normal(s.size)
    return np.round(s / 1e-3) * 1e-3


#: the gyro's own die thermometer, about as coarse as an ADIS16405's: its TEMP_OUT is a
#: 12-bit two's-complement word of ≈ 0.14 °C per LSB (as public drivers decode it, e.g.
#: rust-fc's devices.rs, TEMP2C = 0.14); 0.136 here. The unit's offset and the white
#: noise are this family's choices
DIE_LSB_C, DIE_NOISE_C, DIE_OFFSET_SD_C = 0.136, 0.05, 0.5


def die_sensor(index: int, D: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """1 Hz readings of unit ``index``'s die thermometer: its own offset (drawn once per
    unit), white noise, the register's resolution."""
    offset = DIE_OFFSET_SD_C * float(np.random.default_rng([71, index]).standard_normal())
    s = D + offset + DIE_NOISE_C * rng.standard_normal(D.size)
    return np.round(s / DIE_LSB_C) * DIE_LSB_C


def plays(unit: Unit, D: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The hysteresis play operators (module docstring), one column per play: ``D − p_i``
    and the half-width ``w_i(D)/2`` (their ratio is the play's output). Each play starts
    at the first die temperature; its width follows the die temperature, ``w_i(D) = w_i0
    (1 + κ u)``, not below 0.05 °C."""
    u = (D - 25.0) / 50.0
    half = 0.5 * np.maximum(np.outer(1.0 + unit.kappa * u, unit.w0), 0.05)
    p = np.full(len(unit.h), float(D[0]))
    dp = np.empty((D.size, len(unit.h)))
    for i in range(D.size):
        p = np.minimum(np.maximum(p, D[i] - half[i]), D[i] + half[i])
        dp[i] = D[i] - p
    return dp, half


def drift(unit: Unit, P: np.ndarray, D: np.ndarray, t_abs0: float) -> np.ndarray:
    """True deterministic drift (°/s) at 1 Hz (module docstring)."""
    u = (D - 25.0) / 50.0
    out = np.zeros(D.size)
    for k, ck in enumerate(unit.c):
        out += ck * u**k
    if any(unit.h):
        dp, half = plays(unit, D)
        out += np.sum(np.asarray(unit.h) * dp / half, axis=1)
    rate = np.gradient(D, DT) * 60.0  # °C/min
    out += unit.k_pos * np.maximum(rate, 0.0) + unit.k_neg * np.minimum(rate, 0.0)
    out += unit.k2 * rate * np.abs(rate)
    out += unit.g * (D - P)
    if unit.age_a:
        t = t_abs0 + DT * np.arange(D.size)
        out += unit.age_a * np.log1p(t / unit.age_tau_s)
    return out


def flicker(n: int, dt: float, b_dps: float, rng: np.random.Generator) -> np.ndarray:
    """1/f rate noise with Allan floor ``0.664·b_dps`` (IEEE B), shaped in frequency over
    twice the length (no circular wrap)."""
    m = 2 * n
    f = np.fft.rfftfreq(m, dt)
    psd = np.zeros_like(f)
    psd[1:] = b_dps**2 / (2.0 * math.log(2.0) * f[1:])
    z = rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size)
    return np.fft.irfft(z * np.sqrt(psd * m / (4.0 * dt)), m)[:n]


def synthetic_noise(unit: Unit, n: int, rate_hz: float, rng: np.random.Generator) -> np.ndarray:
    """White (ARW), flicker (B), rate random walk (K) and a Gauss–Markov process, °/s."""
    dt = 1.0 / rate_hz
    x = (unit.arw / 60.0) / math.sqrt(dt) * rng.standard_normal(n)
    x += flicker(n, dt, unit.flicker_b / 3600.0, rng)
    if unit.rrw_k > 0:
        x += np.cumsum(unit.rrw_k / 216000.0 * math.sqrt(dt) * rng.standard_normal(n))
    if unit.gm_sigma > 0:
        a = math.exp(-dt / unit.gm_tau_s)
        e = rng.standard_normal(n) * (unit.gm_sigma / 3600.0) * math.sqrt(1.0 - a * a)
        from scipy.signal import lfilter

        x += lfilter([1.0], [1.0, -a], e)
    return x
