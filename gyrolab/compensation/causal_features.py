"""Causal drift-model features: a state machine that runs reading by reading (firmware)
and its vectorised offline twin, bit for bit the same.

The drift of a MEMS gyro follows the temperature of its die, which lags the case where
the PT100 sits; it also depends on how fast that temperature changes (thermal gradients)
and on whether it last rose or fell (hysteresis), and it settles after power-on
(warm-up). Every feature below is computed from the *past* PT100 readings only, with a
state of four numbers carried from one reading to the next, so the same equations run on
a live stream, offline over a whole run, or in float32 C on the device.

Inputs per PT100 reading ``n``: the measured case temperature ``T_n`` (°C) and the time
since the previous reading ``Δt_n`` (s; ``Δt_0 = 0``). Parameters (:class:`CausalParams`):
``tau_s`` = τ ≥ 0 (die lag), ``rate_tau_min_s`` = τ_min > 0 (smoothing floor of the rate),
``width_c`` = w > 0 (hysteresis play width), ``warmup_tau_s`` = τ_w > 0,
``start_branch`` = s₀ ∈ [−1, 1] (hysteresis branch at power-on, default 0),
``self_heating_c`` = δ (°C, the die's settled self-heating rise that the play follows,
default 0), ``die_heating_c`` = δ_d (°C, the die's settled self-heating rise that the die
temperature F itself carries, default 0).

State (:class:`State`): ``F`` die-temperature estimate (°C), ``G`` rate filter (°C),
``p`` play-operator position (°C), ``t`` time since power-on (s). :func:`initial_state`
starts at rest: ``F = G = T_0``, ``p = T_0 − s₀ w/2``, ``t = t_0``. ``s₀ = +1`` starts the
play on its heating branch: at power-on the die warms above the case by its own
self-heating before the chamber moves, so its hysteresis is on the heating branch while
the PT100 — and with ``s₀ = 0`` the play — has not moved (issue 23, the break family:
without it the lag absorbed that first heating, fitted τ 963/824/635 s against the true
782/525/570 s on units 7, 8, 10). ``δ > 0`` models that warm-up as it happens: the play
follows ``H = F + δ (1 − E)``, the die rising by δ with the warm-up's time constant after
power-on, and keeps that offset once warmed up (issue 23: on the break family's unit 10,
whose die runs 0.5 °C above its case, least squares on the noiseless drift with the play
on ``F`` leaves its held-out runs at 1.22–1.31× the oracle, with the play on ``H``
1.00–1.03×; a static start s₀ = δ/(w/2) does as well there, but on noisy calibrations it
met the break family's targets on 6 of 16 draws against δ's 10: docs/results.md).

Equations, evaluated in this order at every reading (τ_r = max(τ, τ_min))::

    a_n = −expm1(−Δt_n / τ)      (a_n = 1 when τ = 0)   exact step of τ dF/dt = T − F
    F_n = F_{n−1} + a_n (T_n − F_{n−1})                  die temperature, °C
    b_n = −expm1(−Δt_n / τ_r)
    G_n = G_{n−1} + b_n (T_n − G_{n−1})                  (G = F whenever τ ≥ τ_min)
    R_n = (T_n − G_n) / τ_r                              rate dG/dt, °C/s
    t_n = t_{n−1} + Δt_n
    E_n = exp(−t_n / τ_w)                                warm-up, 1 at power-on
    D_n = F_n + δ_d (1 − exp(−t_n / τ))  (D_n = F_n + δ_d when τ = 0)   die, °C
    H_n = D_n + δ (1 − E_n)                              die with its self-heating, °C
    p_n = min(max(p_{n−1}, H_n − w/2), H_n + w/2)        play (backlash) operator, °C
    S_n = (H_n − p_n) / (w/2)                            branch: +1 heating, −1 cooling

The features are ``(D, R, S, E)``; with δ_d = 0 (every model fitted before it existed)
``D = F``. ``δ_d > 0`` is the die's self-heating as a die model has it (issue 23): after
power-on the die, at rest at its case temperature, rises by δ_d with its own time
constant τ — the step response of ``τ dD/dt = T + δ_d − D`` from ``D = T`` — so that
every term of the drift model, the temperature series included, sees the die's own
temperature. An additive warm-up ``A E`` is the same transient at the power-on
temperature only; after a cold power-on the series' slope there, not at 25 °C, scales
it (the break family's unit 28, docs/results.md). The state keeps ``F``; ``D`` is
computed from it.

``R`` is the exact derivative of the lagged temperature ``G`` (τ_r dG/dt = T − G), so for
τ ≥ τ_min it is dF/dt, the rate the die sees; below τ_min it is the rate of T smoothed by
τ_min (a one-second difference of a PT100 reading with 5 mK noise would be all noise).

The structured drift model of :mod:`gyrolab.compensation.causal` is linear in its
parameters on these features::

    d_n = Σ_{i=0}^{P} c_i L_i(u_n) + k R_n + h S_n + A E_n,
    u_n = (2 F_n − (lo + hi)) / (hi − lo)

(``L_i`` Legendre polynomials; ``lo``/``hi`` the calibration range of F; beyond it the
polynomial part continues linearly from the edge). Between readings the drift estimate is
held (zero-order hold): the gyro output ``y(t) = raw(t) − d_n`` for readings at or before t.

Bit-for-bit: :func:`step` (pure Python floats) and :func:`features` (one numba loop over
arrays) perform the same IEEE-754 double operations in the same order with the same
libm functions (``expm1``, ``exp``); ``tests/test_causal.py`` checks equality sample for
sample.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numba
import numpy as np

FEATURES = ("F", "R", "S", "E")  # column order of :func:`features`
#: the play width ``w (1 + κ (H − WIDTH_REF_C))``, not below ``WIDTH_FLOOR w``, when κ
#: (``width_temp_per_c``) is not 0: a hysteresis whose width changes with temperature
WIDTH_REF_C = 25.0
WIDTH_FLOOR = 0.1
FEATURE_UNITS = {"F": "degC", "R": "degC/s", "S": "1", "E": "1"}
#: the parameters written only when not 0 (absent: 0, as before each existed)
OPTIONAL = ("start_branch", "self_heating_c", "width_temp_per_c", "die_heating_c")


@dataclass(frozen=True)
class CausalParams:
    """The nonlinear (time-constant) parameters of the feature state machine."""

    tau_s: float = 0.0  # die lag τ behind the measured case temperature
    rate_tau_min_s: float = 30.0  # smoothing floor τ_min of the rate feature
    width_c: float = 1.0  # hysteresis play width w
    warmup_tau_s: float = 600.0  # warm-up time constant τ_w
    start_branch: float = 0.0  # hysteresis branch s₀ at power-on (−1 cooling … +1 heating)
    self_heating_c: float = 0.0  # δ: the die's self-heating rise above F, settled, °C
    width_temp_per_c: float = 0.0  # κ: the play width's change per °C about 25 °C
    die_heating_c: float = 0.0  # δ_d: the self-heating rise the die temperature carries, °C

    def __post_init__(self) -> None:
        ok = (
            math.isfinite(self.tau_s)
            and self.tau_s >= 0
            and self.rate_tau_min_s > 0
            and self.width_c > 0
            and self.warmup_tau_s > 0
            and -1.0 <= self.start_branch <= 1.0
            and math.isfinite(self.self_heating_c)
            and math.isfinite(self.width_temp_per_c)
            and math.isfinite(self.die_heating_c)
            and all(
                math.isfinite(v) for v in (self.rate_tau_min_s, self.width_c, self.warmup_tau_s)
            )
        )
        if not ok:
            raise ValueError(f"invalid causal feature parameters {self}")

    @property
    def rate_tau_s(self) -> float:
        """τ_r = max(τ, τ_min)."""
        return max(self.tau_s, self.rate_tau_min_s)

    def to_dict(self) -> dict[str, Any]:
        """The parameters; ``start_branch``, ``self_heating_c``, ``width_temp_per_c`` and
        ``die_heating_c`` only when not 0 (model.json and exports of models without them
        stay as they were)."""
        d = asdict(self)
        for k in OPTIONAL:
            if not d[k]:
                del d[k]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> CausalParams:
        return cls(**{k: float(d[k]) for k in cls.__dataclass_fields__ if k in d})


@dataclass
class State:
    """The four numbers carried from one PT100 reading to the next."""

    F: float  # die temperature estimate, °C
    G: float  # rate filter, °C
    p: float  # play-operator position, °C
    t: float  # time since power-on, s


def initial_state(T0: float, t0: float = 0.0, params: CausalParams | None = None) -> State:
    """At rest at the first reading ``T0`` (°C), ``t0`` s after power-on; the play at
    ``T0 − s₀ w/2`` (``params``' start branch; at ``T0`` without ``params``)."""
    p = float(T0)
    if params is not None and params.start_branch:
        p = p - params.start_branch * (0.5 * params.width_c)
    return State(F=float(T0), G=float(T0), p=p, t=float(t0))


def step(state: State, T: float, dt: float, params: CausalParams) -> tuple[float, ...]:
    """Advance ``state`` (in place) by one PT100 reading ``T`` (°C) taken ``dt`` s after
    the previous one; return the features ``(F, R, S, E)`` (module docstring)."""
    tau = params.tau_s
    tau_r = max(tau, params.rate_tau_min_s)
    half = 0.5 * params.width_c
    a = -math.expm1(-dt / tau) if tau > 0.0 else 1.0
    F = state.F + a * (T - state.F)
    b = -math.expm1(-dt / tau_r)
    G = state.G + b * (T - state.G)
    R = (T - G) / tau_r
    t = state.t + dt
    E = math.exp(-t / params.warmup_tau_s)
    D = F
    dd = params.die_heating_c
    if dd != 0.0:
        D = F + dd * (-math.expm1(-t / tau) if tau > 0.0 else 1.0)
    H = D + params.self_heating_c * (1.0 - E)
    k = params.width_temp_per_c
    if k != 0.0:
        half = half * max(1.0 + k * (H - WIDTH_REF_C), WIDTH_FLOOR)
    p = state.p
    if p < H - half:
        p = H - half
    elif p > H + half:
        p = H + half
    S = (H - p) / half
    state.F, state.G, state.p, state.t = F, G, p, t
    return D, R, S, E


@numba.njit(cache=True, nogil=True)
def _features_kernel(
    T: np.ndarray,
    dt: np.ndarray,
    tau: float,
    tau_r: float,
    half: float,
    tau_w: float,
    shift: float,
    k: float,
    dd: float,
    st: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled; same operations as step()
    F, G, p, t = st[0], st[1], st[2], st[3]
    for i in range(T.size):
        Ti = T[i]
        d = dt[i]
        a = -math.expm1(-d / tau) if tau > 0.0 else 1.0
        F = F + a * (Ti - F)
        b = -math.expm1(-d / tau_r)
        G = G + b * (Ti - G)
        R = (Ti - G) / tau_r
        t = t + d
        E = math.exp(-t / tau_w)
        D = F
        if dd != 0.0:
            D = F + dd * (-math.expm1(-t / tau) if tau > 0.0 else 1.0)
        H = D + shift * (1.0 - E)
        hh = half
        if k != 0.0:
            hh = half * max(1.0 + k * (H - WIDTH_REF_C), WIDTH_FLOOR)
        if p < H - hh:
            p = H - hh
        elif p > H + hh:
            p = H + hh
        S = (H - p) / hh
        out[i, 0] = D
        out[i, 1] = R
        out[i, 2] = S
        out[i, 3] = E
    st[0], st[1], st[2], st[3] = F, G, p, t


def features(
    T: np.ndarray,
    dt: np.ndarray,
    params: CausalParams,
    state: State | None = None,
) -> np.ndarray:
    """Features ``(N, 4)`` = columns ``F, R, S, E`` for readings ``T`` (°C) with
    ``dt`` (s) since the previous reading, from ``state`` (default: at rest at ``T[0]``,
    t = 0; updated in place). The same numbers :func:`step` gives one reading at a time."""
    T = np.ascontiguousarray(T, dtype=np.float64)
    dt = np.ascontiguousarray(dt, dtype=np.float64)
    if T.shape != dt.shape or T.ndim != 1:
        raise ValueError("T and dt must be 1-D arrays of the same length")
    if state is None:
        state = initial_state(float(T[0]) if T.size else 0.0, 0.0, params)
    st = np.array([state.F, state.G, state.p, state.t], dtype=np.float64)
    out = np.empty((T.size, 4))
    _features_kernel(
        T,
        dt,
        float(params.tau_s),
        float(params.rate_tau_s),
        0.5 * float(params.width_c),
        float(params.warmup_tau_s),
        float(params.self_heating_c),
        float(params.width_temp_per_c),
        float(params.die_heating_c),
        st,
        out,
    )
    state.F, state.G, state.p, state.t = (float(v) for v in st)
    return out


def power_on_edges(pt_t: np.ndarray, power_ons: tuple[float, ...]) -> list[int]:
    """Where each power-on's stretch of the readings at ``pt_t`` (s, increasing) begins
    and the last ends: ``[0, i_1, …, i_k, n]``, ``i_j`` the first reading at or after the
    ``j``-th of the later ``power_ons`` (s)."""
    cuts = np.searchsorted(np.asarray(pt_t, dtype=float), np.asarray(power_ons, dtype=float))
    return [0, *(int(c) for c in cuts), int(np.size(pt_t))]


def reading_features(
    pt_t: np.ndarray,
    pt_c: np.ndarray,
    params: CausalParams,
    t_power_on: float = 0.0,
    power_ons: tuple[float, ...] = (),
) -> np.ndarray:
    """:func:`features` over a run's PT100 readings at times ``pt_t`` (s, increasing) with
    values ``pt_c`` (°C); power-on at ``t_power_on`` (the recording's t = 0 for simulated
    and gyrolab-acquired runs). ``power_ons``: later power-ons (s, increasing, after
    ``t_power_on``), e.g. a calibration made of two runs on one time axis: at the first
    reading at or after each, the state starts again at rest there, its time since
    power-on counted from that power-on — the features of each stretch are those of
    that stretch alone."""
    pt_t = np.asarray(pt_t, dtype=float)
    pt_c = np.asarray(pt_c, dtype=float)
    if power_ons:
        edges = power_on_edges(pt_t, power_ons)
        starts = [t_power_on, *power_ons]
        parts = [
            reading_features(pt_t[a:b], pt_c[a:b], params, t0)
            for a, b, t0 in zip(edges[:-1], edges[1:], starts, strict=True)
            if b > a
        ]
        return np.vstack(parts) if parts else np.empty((0, 4))
    dt = np.diff(pt_t, prepend=pt_t[0]) if pt_t.size else pt_t
    st = initial_state(float(pt_c[0]), float(pt_t[0] - t_power_on), params) if pt_t.size else None
    return features(pt_c, dt, params, st)


def hold(t: np.ndarray, pt_t: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Zero-order hold of per-reading ``values`` at times ``t``: the last reading at or
    before ``t`` (the first one before it). Causal."""
    i = np.searchsorted(pt_t, t, side="right") - 1
    return values[np.clip(i, 0, len(values) - 1)]
