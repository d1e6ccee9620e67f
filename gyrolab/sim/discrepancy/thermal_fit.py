"""Fit the simulator's thermal model to the oven and PT100 channels.

Two stages, each driven by what the bench measured (docs/sim-model.md has the model):

1. **Oven air** from the setpoint channel: the recorded process value ``PV`` against the
   simulator's controller, first order with rate limits (nominal) or second order
   (``oven_overshoot``), integrated with the simulator's own kernel on a 0.5 s grid;
   parameters by nonlinear least squares (``scipy.optimize.least_squares``).
2. **Gyro case** from the recorded air: ``τ_case dTc/dt = PV + ΔT_self − Tc`` with the case
   at the air temperature at power-on, and the PT100 reading ``Tc + δ·R(T)/R0`` (``δ`` is
   the ``rtd_self_heating`` error at 0 °C, the multimeter's ``θ·I²·R0``; 0 in the nominal
   model). For a fixed ``τ_case`` the reading is linear in ``(ΔT_self, δ)``:
   ``PT100 = F_τ[PV] + ΔT_self·(1 − e^{−t/τ}) + δ·R(T)/R0``, so ``τ_case`` is a
   one-dimensional search. ``δ`` and the gyro's self-heating differ in the power-on
   transient (at power-on the case is at the air temperature and only ``δ`` is already
   there) and, on any profile that moves the temperature, in ``δ``'s growth with the
   sensor's resistance (0.39 %/°C), which no case parameter has.

The scores are Gaussian log-likelihoods with the residual variance floored at
``(resolution)²`` (the oven's process value is assumed known to 0.02 °C, the PT100 to its
fitted white-noise level) so that an exact fit cannot make a meaningless gain.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numba
import numpy as np
from scipy.optimize import least_squares, minimize_scalar

from gyrolab.sim.discrepancy.data import BenchData
from gyrolab.sim.effects import overshoot_omega_zeta, self_heating_c
from gyrolab.sim.thermal import ThermalParams, air_rate, lowpass, thermal_kernel

OVEN_DT_S = 0.5
OVEN_MAX_POINTS = 6000
"""The oven fit uses at most this many (evenly spaced) process-value samples."""
OVEN_FLOOR_C = 0.02
"""Resolution floor of the oven process value in the likelihood, °C."""


@dataclass
class OvenFit:
    """Fitted oven air model."""

    params: dict[str, float]
    overshoot: tuple[float, float] | None
    pred: np.ndarray
    resid: np.ndarray
    form: str = "knee"
    """Cooling rate limit: ``"knee"`` (the simulator's linear knee) or ``"smooth"``
    (:func:`_air_kernel_smooth`); ``params`` always hold the knee form (what a
    ``model.toml`` can express), ``smooth`` the smooth form's when it was chosen."""
    x: np.ndarray | None = None
    """The fitted vector of :func:`air_model` for ``form``."""
    smooth: dict[str, float] | None = None

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(self.resid**2)))

    def loglik(self) -> float:
        n = self.resid.size
        return -0.5 * n * math.log(max(np.mean(self.resid**2), OVEN_FLOOR_C**2))

    @property
    def k(self) -> int:
        return 5 + (2 if self.overshoot else 0)


@numba.njit(cache=True, nogil=True)
def _air_kernel_smooth(
    n: int, dt: float, setpoint: float, state: np.ndarray, p: np.ndarray, air: np.ndarray
) -> None:  # pragma: no cover - compiled
    """The air part of :func:`gyrolab.sim.thermal.thermal_kernel` with a cooling rate
    limit that derates smoothly towards the chamber's floor instead of with a knee:
    ``r_cool(T) = r_cool0 · (1 − exp(−max(T − T_floor, 0)/s))`` (a saturating
    exponential: full rate well above the floor, slope ``r_cool0/s`` at it).
    ``p`` = [τ_air, r_heat, r_cool0, T_floor, s, ω, ζ]; ``state`` as the kernel's."""
    tau_air, r_heat, r_cool0, floor, scale, w, zeta = p[0], p[1], p[2], p[3], p[4], p[5], p[6]
    a, v = state[0], state[1]
    for i in range(n):
        air[i] = a
        u = a - floor
        r_cool = r_cool0 * (1.0 - math.exp(-u / scale)) if u > 0.0 else 0.0
        v = air_rate(v, a, setpoint, tau_air, r_heat, r_cool, w, zeta, dt)
        a += dt * v
    state[0], state[1] = a, v


def air_model(
    t_obs: np.ndarray,
    sp_t: np.ndarray,
    sp: np.ndarray,
    a0: float,
    x: np.ndarray,
    overshoot: tuple[float, float] | None,
    form: str = "knee",
) -> np.ndarray:
    """Air temperature at ``t_obs`` from the setpoint history (kernel on a 0.5 s grid).
    ``x`` = [τ_air, r_heat, r_cool0, T_knee, T_knee − T_floor] (``form="knee"``) or
    [τ_air, r_heat, r_cool0, T_floor, s] (``form="smooth"``)."""
    tau, rh, rc, knee, gap = x[:5]
    w = z = 0.0
    if overshoot is not None:
        w, z = overshoot_omega_zeta(*overshoot)
    smooth = form == "smooth"
    if smooth:
        p = np.array([tau, rh, rc, knee, gap, w, z])
    else:
        p = np.array([tau, rh, rc, knee, knee - gap, 1000.0, 0.0, 0.0, w, z])
    state = np.array([a0, 0.0, a0, a0])
    t_end = float(t_obs[-1])
    n_tot = int(math.ceil((t_end - t_obs[0]) / OVEN_DT_S)) + 1
    air = np.empty(n_tot)
    scratch = np.empty((3, n_tot))
    # setpoint segments on the grid
    k_sp = np.clip(np.round((sp_t - t_obs[0]) / OVEN_DT_S).astype(np.int64), 0, n_tot)
    change = np.flatnonzero(np.abs(np.diff(sp)) > 1e-9) + 1
    starts = np.concatenate([[0], k_sp[change]])
    values = np.concatenate([[sp[0]], sp[change]])
    ends = np.concatenate([starts[1:], [n_tot]])
    for s0, s1, v in zip(starts, ends, values, strict=True):
        if s1 > s0 and smooth:
            _air_kernel_smooth(int(s1 - s0), OVEN_DT_S, float(v), state, p, air[s0:s1])
        elif s1 > s0:
            thermal_kernel(
                int(s1 - s0),
                OVEN_DT_S,
                float(v),
                state,
                p,
                air[s0:s1],
                scratch[0, s0:s1],
                scratch[1, s0:s1],
                scratch[2, s0:s1],
            )
    grid_t = t_obs[0] + np.arange(n_tot) * OVEN_DT_S
    return np.interp(t_obs, grid_t, air)


INIT_WINDOW_S = 120.0
"""Window at power-on from which initial temperatures are estimated, s."""


@dataclass
class Initial:
    """An initial condition estimated from a window: value and standard uncertainty."""

    value: float
    sigma: float
    n: int


def value_resolution(v: np.ndarray) -> float:
    """Spacing of a channel's values when they sit on a lattice (a register that rounds,
    e.g. to 0.1 °C): the smallest gap between distinct values when every gap is a
    multiple of it, else 0."""
    u = np.unique(np.round(np.asarray(v, dtype=float), 9))
    if u.size < 2 or u.size > 0.5 * max(np.asarray(v).size, 1) + 2:
        return 0.0  # a continuum: (almost) every reading distinct
    du = np.diff(u)
    q = float(np.min(du))
    r = du / q
    return q if q > 1e-6 and bool(np.all(np.abs(r - np.rint(r)) < 0.05)) else 0.0


def initial_value(t: np.ndarray, v: np.ndarray, window_s: float = INIT_WINDOW_S) -> Initial:
    """The channel's value at ``t[0]`` from a line fitted over the first ``window_s``
    (at least 5 samples): intercept and its standard error, with the channel's value
    resolution ``r`` adding ``r/√12`` (a rounding register is biased by up to r/2 however
    many samples are averaged). No single sample decides it."""
    t = np.asarray(t, dtype=float)
    v = np.asarray(v, dtype=float)
    m = t <= t[0] + window_s
    if m.sum() < 5:
        m = np.arange(t.size) < min(5, t.size)
    tt, vv = t[m] - t[0], v[m]
    res = value_resolution(v)
    if tt.size >= 3 and np.ptp(tt) > 0:
        A = np.column_stack([np.ones_like(tt), tt])
        coef, *_ = np.linalg.lstsq(A, vv, rcond=None)
        r = vv - A @ coef
        s2 = float(r @ r) / max(1, tt.size - 2)
        cov = s2 * np.linalg.pinv(A.T @ A)
        value, se = float(coef[0]), float(math.sqrt(max(cov[0, 0], 0.0)))
    else:
        value, se = float(np.mean(vv)), 0.0
    sigma = math.sqrt(se * se + res * res / 12.0 + 1e-8)
    return Initial(value, sigma, int(tt.size))


def effective_n(resid: np.ndarray, rho_stop: float = 0.05, floor: float = 0.0) -> float:
    """Number of independent samples in a residual series: ``n / (1 + 2 Σ_k ρ_k)``, the
    autocorrelations ``ρ_k`` (by FFT) summed from lag 1 until they first fall below
    ``rho_stop`` (an initial-positive-sequence estimate of the integrated correlation
    time). A smooth misfit between a model and a real chamber is correlated over
    thousands of readings, and a likelihood that treated them as independent would turn
    it into hundreds of BIC units; white reading noise keeps ``n``. ``floor`` (the
    channel's resolution) counts as white noise beside the residual: a misfit below the
    resolution is not evidence of anything, correlated or not."""
    r = np.asarray(resid, dtype=float)
    n = r.size
    if n < 3:
        return float(n)
    r = r - r.mean()
    den = float(r @ r)
    if den <= 0:
        return float(n)
    m = 1 << int(math.ceil(math.log2(2 * n)))
    f = np.fft.rfft(r, m)
    acf = np.fft.irfft(f * np.conj(f), m)[: n // 2] / (den + n * floor * floor)
    below = np.flatnonzero(acf[1:] < rho_stop)
    k = int(below[0]) if below.size else acf.size - 1
    s = float(np.sum(acf[1 : k + 1]))
    return max(2.0, n / (1.0 + 2.0 * s))


def delta_bic_channel(
    r0: np.ndarray, r1: np.ndarray, floor: float, extra_params: int
) -> tuple[float, float]:
    """ΔBIC of a richer model (residual ``r1``) over the current one (``r0``) on a
    temperature channel, Gaussian with variance floored at ``floor²`` and the readings
    counted as :func:`effective_n` of the richer model's residual. Returns (ΔBIC, n_eff)."""
    ne = effective_n(r1, floor=floor)
    v0 = max(float(np.mean(r0**2)), floor**2)
    v1 = max(float(np.mean(r1**2)), floor**2)
    return ne * math.log(v0 / v1) - extra_params * math.log(ne), ne


def fit_oven(
    d: BenchData,
    th: ThermalParams,
    overshoot: tuple[float, float] | None = None,
    with_overshoot: bool = False,
    form: str | None = None,
    x_start: np.ndarray | None = None,
) -> OvenFit:
    """Least-squares fit of the oven air model to the recorded process value.

    ``form=None`` fits both cooling rate limits (the simulator's linear knee and the
    smooth saturating one of :func:`_air_kernel_smooth`, five parameters each) and keeps
    the one with the better BIC — with equal parameter counts, the smaller floored
    residual variance. ``x_start`` starts the fit of the given ``form`` (e.g. the
    first-order fit's vector when adding the overshoot)."""
    if form is None:
        knee = fit_oven(d, th, overshoot, with_overshoot, "knee")
        sm = fit_oven(d, th, overshoot, with_overshoot, "smooth")
        if sm.loglik() > knee.loglik():
            return replace(sm, params=knee.params)  # model.toml keeps the knee form
        return knee
    return _fit_oven_form(d, th, overshoot, with_overshoot, form, x_start)


def _fit_oven_form(
    d: BenchData,
    th: ThermalParams,
    overshoot: tuple[float, float] | None,
    with_overshoot: bool,
    form: str,
    x_start: np.ndarray | None,
) -> OvenFit:
    """:func:`fit_oven` for one cooling form."""
    t, sp, pv = d.oven_t, d.oven_sp, d.oven_pv
    step = max(1, t.size // OVEN_MAX_POINTS)
    to, pvo = t[::step], pv[::step]
    x0 = np.array(
        [
            th.air_tau_s,
            th.heat_rate_c_per_s,
            th.cool_rate_c_per_s,
            th.cool_knee_c,
            th.cool_knee_c - th.cool_floor_c,
        ]
    )
    if form == "smooth":  # [.., T_floor, s]: the knee's floor, s half the knee-floor gap
        x0[3], x0[4] = th.cool_floor_c, 0.5 * (th.cool_knee_c - th.cool_floor_c)
    if x_start is not None:
        x0 = np.asarray(x_start, dtype=float).copy()
    lo = np.array([1.0, 1e-5, 1e-5, -150.0, 0.1])
    hi = np.array([1e4, 1.0, 1.0, 300.0, 400.0])
    # the air at power-on from a window (never one reading), as the case fit does
    a0 = initial_value(t, pv).value

    if not with_overshoot:

        def res1(x: np.ndarray) -> np.ndarray:
            return air_model(to, t, sp, a0, x, None, form) - pvo

        r = least_squares(res1, np.clip(x0, lo, hi), bounds=(lo, hi), x_scale="jac", max_nfev=40)
        x, os_ = r.x, None
    else:
        # coarse start for (overshoot, period), then all seven parameters together
        starts = [overshoot] if overshoot else []
        starts += [(o, p) for o in (0.05, 0.15, 0.35) for p in (400.0, 1200.0, 3000.0)]
        best = None
        for o, p in starts:
            e = air_model(to, t, sp, a0, x0, (o, p), form) - pvo
            c = float(e @ e)
            if best is None or c < best[0]:
                best = (c, o, p)
        assert best is not None
        lo7 = np.concatenate([lo, [1e-3, 30.0]])
        hi7 = np.concatenate([hi, [0.95, 2e4]])

        def res2(x: np.ndarray) -> np.ndarray:
            return air_model(to, t, sp, a0, x[:5], (x[5], x[6]), form) - pvo

        x7 = np.clip(np.concatenate([x0, [best[1], best[2]]]), lo7, hi7)
        r = least_squares(res2, x7, bounds=(lo7, hi7), x_scale="jac", max_nfev=60)
        x, os_ = r.x[:5], (float(r.x[5]), float(r.x[6]))
    pred = air_model(t, t, sp, a0, x, os_, form)
    if form == "smooth":
        sm = {"air_tau_s": float(x[0]), "heat_rate_c_per_s": float(x[1])}
        sm |= {"cool_rate_c_per_s": float(x[2]), "cool_floor_c": float(x[3])}
        sm["cool_derate_scale_c"] = float(x[4])
        # the knee form's fields: the same floor, the knee where the derating is 86 %
        x = np.array([x[0], x[1], x[2], x[3] + 2.0 * x[4], 2.0 * x[4]])
        smooth: dict[str, float] | None = sm
    else:
        smooth = None
    xf = np.array(r.x[:5])
    params = {
        "air_tau_s": float(x[0]),
        "heat_rate_c_per_s": float(x[1]),
        "cool_rate_c_per_s": float(x[2]),
        "cool_knee_c": float(x[3]),
        "cool_floor_c": float(x[3] - x[4]),
    }
    return OvenFit(params, os_, pred, pred - pv, form, xf, smooth)


@dataclass
class CaseFit:
    """Fitted case model and the PT100 reading it predicts."""

    tau_s: float
    self_heating_c: float
    offset_c: float
    with_offset: bool
    grid_t: np.ndarray
    case_c: np.ndarray
    """Model case temperature on ``grid_t`` (true case, without the PT100 offset)."""
    dcase_c_per_s: np.ndarray
    resid: np.ndarray = field(default_factory=lambda: np.empty(0))
    time_shift_s: float = 0.0
    """Fitted PT100 time-stamp offset (reading time = logged time + shift)."""
    initial_c: float = float("nan")
    """Fitted case temperature at power-on (prior: the air over the first window)."""
    design: np.ndarray | None = None
    """Linear columns (ΔT_self, initial case) at the PT100 times, with the prior row."""
    offset_column: np.ndarray | None = None
    """The PT100 error per unit ``δ`` at each reading, ``R(T)/R0``."""
    die_tau_s: float | None = None
    """A die sensor's lag behind the case (None: a PT100 on the case)."""
    die_c: np.ndarray | None = None
    """A die sensor's model die temperature on ``grid_t`` (without its offset)."""

    def offset_at(self, reading_c: np.ndarray) -> np.ndarray:
        """The fitted PT100 self-heating error at readings ``reading_c`` (°C)."""
        return self_heating_c(self.offset_c, reading_c)

    def measured_case(self, d: BenchData) -> np.ndarray:
        """The case temperature on ``grid_t`` from the readings: a PT100's, less its
        self-heating; a die sensor's, less its offset, carried back to the case by the
        model (case + what the die model misses)."""
        reading = np.asarray(d.pt100_c, dtype=float)
        if self.die_c is None:
            return np.interp(self.grid_t, d.pt100_t, reading - self.offset_at(reading))
        return self.case_c + np.interp(self.grid_t, d.pt100_t, reading - self.offset_c) - self.die_c

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(self.resid**2)))

    def loglik(self, floor_c: float) -> float:
        n = self.resid.size
        return -0.5 * n * math.log(max(float(np.mean(self.resid**2)), floor_c**2))

    @property
    def k(self) -> int:
        return 4 + int(self.with_offset)


MAX_TIME_SHIFT_S = 5.0
"""Bound of the PT100 time-stamp offset fitted as a nuisance parameter, s."""


def fit_case(d: BenchData, tau0: float, with_offset: bool = False) -> CaseFit:
    """The case model of :func:`fit_pt100_case`, or of :func:`fit_die_case` when the
    recording's temperature is a unit's internal (die) sensor."""
    if d.temperature_source == "die":
        return fit_die_case(d, tau0)
    return fit_pt100_case(d, tau0, with_offset)


def _case_grid(d: BenchData) -> tuple[np.ndarray, np.ndarray, Initial, float]:
    """The case models' 1 s grid (the readings and the bins, with room for the time
    skew), the recorded air at its interval midpoints, the air at power-on (a window's
    estimate with its uncertainty, :func:`initial_value`) and the weight of its prior row.
    The case starts at that air temperature, fitted as a parameter with a Gaussian prior
    (one row in the least squares, in units of the reading noise) so that no single
    reading decides an offset."""
    t0 = float(min(d.pt100_t[0], d.oven_t[0]))
    t1 = float(max(d.pt100_t[-1], d.t[-1] + d.bin_s)) + MAX_TIME_SHIFT_S
    grid = np.arange(t0, t1 + 1.0, 1.0)
    air = np.interp(grid, d.oven_t, d.oven_pv)
    a_mid = np.concatenate([0.5 * (air[:-1] + air[1:]), [air[-1]]])
    init = initial_value(d.oven_t, d.oven_pv)
    return grid, a_mid, init, max(pt100_noise_c(d), 1e-4) / init.sigma


def fit_pt100_case(d: BenchData, tau0: float, with_offset: bool = False) -> CaseFit:
    """Fit ``τ_case``, ``ΔT_self`` (and the PT100 offset ``δ``) to the PT100 channel.

    A time-stamp offset of the PT100 readings against the oven's (a multimeter integrates
    and answers after the query is logged) is fitted too, within ±5 s, as a nuisance
    parameter of both the nominal and the candidate model: during a 0.9 °C/min ramp one
    second of skew is 15 mK, three times the reading noise, and would otherwise pass for
    a constant offset.
    """
    grid, a_mid, init, w_prior = _case_grid(d)
    pt_c = d.pt100_c
    # δ's column: the self-heating per unit δ, R(T)/R0, at the reading (0.3 °C of error
    # changes R by 0.1 %: the reading is the sensor's temperature to that order)
    unit_offset = np.asarray(self_heating_c(1.0, pt_c), dtype=float)

    def solve(log_tau: float, shift: float) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        tau = math.exp(log_tau)
        alpha = 1.0 - math.exp(-1.0 / tau)
        f = lowpass(a_mid, alpha, init.value)
        g = lowpass(np.ones_like(a_mid), alpha, 0.0)
        e0 = (1.0 - alpha) ** np.arange(a_mid.size)  # response to the initial case state
        pt_t = d.pt100_t + shift
        cols = [np.interp(pt_t, grid, g), np.interp(pt_t, grid, e0)]
        if with_offset:
            cols.append(unit_offset)
        A = np.column_stack(cols)
        rhs = pt_c - np.interp(pt_t, grid, f)
        prior = np.zeros((1, A.shape[1]))
        prior[0, 1] = w_prior
        Ap = np.vstack([A, prior])
        coef, *_ = np.linalg.lstsq(Ap, np.concatenate([rhs, [0.0]]), rcond=None)
        r = A @ coef - rhs
        rp = w_prior * coef[1]
        return float(r @ r + rp * rp), coef, f + coef[1] * e0, g

    lt_bounds = (math.log(max(5.0, tau0 / 20)), math.log(tau0 * 20))
    lt, shift = math.log(tau0), 0.0
    for _ in range(2):  # coordinate search: τ, then the time skew
        lt = float(
            minimize_scalar(
                lambda v, sh=shift: solve(v, sh)[0],
                bounds=lt_bounds,
                method="bounded",
                options={"xatol": 1e-4},
            ).x
        )
        shift = float(
            minimize_scalar(
                lambda v, l0=lt: solve(l0, v)[0],
                bounds=(-MAX_TIME_SHIFT_S, MAX_TIME_SHIFT_S),
                method="bounded",
                options={"xatol": 1e-3},
            ).x
        )
    lt = float(
        minimize_scalar(
            lambda v: solve(v, shift)[0],
            bounds=lt_bounds,
            method="bounded",
            options={"xatol": 1e-4},
        ).x
    )
    # polish (τ, skew) jointly: a coordinate search stops short on the ridge between them,
    # and a candidate with one more linear parameter would otherwise be scored for
    # landing nearer the optimum rather than for its parameter
    from scipy.optimize import minimize

    r0 = solve(lt, shift)[0]
    pol = minimize(
        lambda v: solve(v[0], v[1])[0] / r0,
        [lt, shift],
        method="Nelder-Mead",
        options={
            "xatol": 1e-5,
            "fatol": 1e-9,
            "initial_simplex": [[lt, shift], [lt + 0.02, shift], [lt, shift + 0.1]],
        },
    )
    lt = float(np.clip(pol.x[0], *lt_bounds))
    shift = float(np.clip(pol.x[1], -MAX_TIME_SHIFT_S, MAX_TIME_SHIFT_S))
    _, coef, f, g = solve(lt, shift)
    tau = math.exp(lt)
    dself = float(coef[0])
    off = float(coef[2]) if with_offset else 0.0
    case = f + dself * g
    dcase = (a_mid + dself - case) / tau
    resid = np.interp(d.pt100_t + shift, grid, case) + off * unit_offset - pt_c
    # the case temperature on the PT100's clock, as the gyro regressors use it
    grid_pt = grid - shift
    alpha = 1.0 - math.exp(-1.0 / tau)
    e0 = (1.0 - alpha) ** np.arange(a_mid.size)
    pt_t = d.pt100_t + shift
    dm = np.column_stack([np.interp(pt_t, grid, g), np.interp(pt_t, grid, e0)])
    dm = np.vstack([dm, [[0.0, w_prior]]])
    return CaseFit(
        tau,
        dself,
        off,
        with_offset,
        grid_pt,
        case,
        dcase,
        resid,
        shift,
        init.value + coef[1],
        dm,
        unit_offset,
    )


def pt100_noise_c(d: BenchData) -> float:
    """White noise of the PT100 channel from its second differences, °C."""
    e = d.pt100_c[1:-1] - 0.5 * (d.pt100_c[:-2] + d.pt100_c[2:])
    return float(1.4826 * np.median(np.abs(e - np.median(e))) / math.sqrt(1.5))


DIE_TAU0_S = 120.0
"""Start of the die lag search (the simulator's default die time constant), s."""


def fit_die_case(d: BenchData, tau0: float, die_tau0: float = DIE_TAU0_S) -> CaseFit:
    """Fit a unit's internal (die) temperature: the case as :func:`fit_pt100_case` has it
    (``τ_case dTc/dt = PV + ΔT_self − Tc``, at the air temperature at power-on with its
    prior), the die behind it (``τ_die dTd/dt = Tc − Td``, starting at the case), and the
    reading ``Td + δ_die``: the sensor's own offset ``δ_die`` a nuisance parameter of the
    model, never an effect. For fixed (τ_case, τ_die, time skew) the reading is linear in
    (ΔT_self, initial case, δ_die); the three are searched coordinate-wise, then polished
    together."""
    from scipy.optimize import minimize

    grid, a_mid, init, w_prior = _case_grid(d)
    reading = d.pt100_c

    def chain(p: np.ndarray) -> tuple[np.ndarray, ...]:
        ac = 1.0 - math.exp(-1.0 / math.exp(p[0]))
        ad = 1.0 - math.exp(-1.0 / math.exp(p[2]))
        f = lowpass(a_mid, ac, init.value)
        g = lowpass(np.ones_like(a_mid), ac, 0.0)
        e0 = (1.0 - ac) ** np.arange(a_mid.size)
        return f, g, e0, *(lowpass(u, ad, float(u[0])) for u in (f, g, e0))

    def solve(p: np.ndarray) -> tuple[float, np.ndarray, tuple[np.ndarray, ...]]:
        f, g, e0, fd, gd, ed = ch = chain(p)
        t = d.pt100_t + p[1]
        A = np.column_stack([np.interp(t, grid, gd), np.interp(t, grid, ed), np.ones_like(t)])
        rhs = reading - np.interp(t, grid, fd)
        Ap = np.vstack([A, [[0.0, w_prior, 0.0]]])
        coef, *_ = np.linalg.lstsq(Ap, np.concatenate([rhs, [0.0]]), rcond=None)
        r = A @ coef - rhs
        return float(r @ r + (w_prior * coef[1]) ** 2), coef, ch

    bounds = [
        (math.log(max(5.0, tau0 / 20)), math.log(tau0 * 20)),
        (-MAX_TIME_SHIFT_S, MAX_TIME_SHIFT_S),
        (math.log(5.0), math.log(die_tau0 * 30)),
    ]
    p = np.array([math.log(tau0), 0.0, math.log(die_tau0)])
    for _ in range(2):  # coordinate search: τ_case, skew, τ_die
        for i in (0, 1, 2):

            def cost(v: float, i: int = i) -> float:
                q = p.copy()
                q[i] = v
                return solve(q)[0]

            p[i] = float(minimize_scalar(cost, bounds=bounds[i], method="bounded").x)
    r0 = solve(p)[0]
    simplex = [p, p + [0.02, 0, 0], p + [0, 0.1, 0], p + [0, 0, 0.05]]
    pol = minimize(
        lambda v: solve(v)[0] / r0,
        p,
        method="Nelder-Mead",
        options={"xatol": 1e-5, "fatol": 1e-9, "initial_simplex": simplex},
    )
    p = np.array([np.clip(v, *b) for v, b in zip(pol.x, bounds, strict=True)])
    _, coef, (f, g, e0, fd, gd, ed) = solve(p)
    tau, shift, die_tau = math.exp(p[0]), float(p[1]), math.exp(p[2])
    dself, off = float(coef[0]), float(coef[2])
    case = f + dself * g + coef[1] * e0
    die = fd + dself * gd + coef[1] * ed
    t = d.pt100_t + shift
    resid = np.interp(t, grid, die) + off - reading
    dm = np.column_stack([np.interp(t, grid, gd), np.interp(t, grid, ed)])
    return CaseFit(
        tau_s=tau,
        self_heating_c=dself,
        offset_c=off,
        with_offset=True,
        grid_t=grid - shift,
        case_c=case,
        dcase_c_per_s=(a_mid + dself - case) / tau,
        resid=resid,
        time_shift_s=shift,
        initial_c=init.value + float(coef[1]),
        design=np.vstack([dm, [[0.0, w_prior]]]),
        die_tau_s=die_tau,
        die_c=die,
    )
