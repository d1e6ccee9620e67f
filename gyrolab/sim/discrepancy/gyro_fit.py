"""Deterministic gyro terms: regressors from the recorded temperatures and time, fitted by
AR-noise least squares on the low-frequency output (see :mod:`.gls`).

Every vocabulary effect that is a function of the temperature history and time becomes
columns of a design matrix evaluated at the bin centres (``x = T − 25 °C``; ``T`` the
bias-setting temperature: the case, or with ``thermal_lag`` the die)::

    bias_poly     1, x, x²  (+ x³, x⁴ when the starting model uses them)   → c0, c1, c2 …
    cubic_temp    x³                                                       → c3
    thermal_rate  60 · dT/dt   (dT/dt in °C/s; the column is °C/min)       → k
    hysteresis    s/2, s = (T − p)/(w/2), p the play operator of width w   → h   [w]
    warmup        exp(−t/τw)                                               → A   [τw]
    aging_ramp    t / 3600                                                 → r
    periodic      sin(2πt/P), cos(2πt/P)                                   → A, φ [P]
    thermal_lag   T ← Td, τ dTd/dt = Tc − Td, dT/dt ← (Tc − Td)/τ          [τ]

(brackets: nonlinear parameters, chosen by a grid scan and a bounded 1-D refinement with
the noise model held fixed, then refitted with the full GLS). The case temperature is the
PT100 reading minus the model's PT100 offset; its rate of change comes from the fitted case
model, ``dTc/dt = (PV + ΔT_self − Tc)/τ_case``, which is smooth where a numerical
derivative of the reading would be noisy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import minimize_scalar

from gyrolab.sim.discrepancy.gls import GlsResult, ar_whiten, gls_ar, gls_cov
from gyrolab.sim.effects import hysteresis_width, play, play_var

AR_ORDER = 8
GYRO_EFFECTS = (
    "bias_poly",
    "cubic_temp",
    "thermal_rate",
    "thermal_lag",
    "hysteresis",
    "warmup",
    "aging_ramp",
    "periodic",
)
WARMUP2 = "warmup.tau2"
"""theta key of a second warm-up exponential's time constant (the two-exponential form)."""
HYST_TC = "hysteresis.width_tc"
"""theta key of a temperature-dependent hysteresis width's slope (°C/°C)."""
FORM_KEYS = (WARMUP2, HYST_TC)


def n_nonlinear(struct: GyroStructure) -> int:
    """Nonlinear parameters of a structure (the wider forms' extra shape parameters too)."""
    return sum(1 for n in struct.names if n in NONLINEAR) + sum(
        1 for k in FORM_KEYS if k in struct.theta and k.split(".")[0] in struct.names
    )


NONLINEAR = {
    "thermal_lag": "tau_s",
    "hysteresis": "width_c",
    "warmup": "tau_s",
    "periodic": "period_s",
}


@dataclass
class GyroContext:
    """Arrays the regressors are built from."""

    t: np.ndarray  # bin centres, s
    y: np.ndarray  # bin means, °/s
    grid_t: np.ndarray  # 1 s thermal grid, s
    case_c: np.ndarray  # case temperature on the grid, °C
    dcase: np.ndarray  # dTc/dt on the grid, °C/s
    duration_s: float
    bin_s: float
    poly_order: int = 2


def nonlinear_grid(name: str, ctx: GyroContext) -> np.ndarray:
    """Scan grid of an effect's nonlinear parameter."""
    if name == "thermal_lag":
        return np.geomspace(20.0, max(200.0, ctx.duration_s / 3), 36)
    if name == "hysteresis":
        return np.geomspace(0.05, 20.0, 30)
    if name == "warmup":
        # a warm-up settles within the run; slower drifts are aging_ramp's business
        return np.geomspace(max(30.0, 3 * ctx.bin_s), max(300.0, ctx.duration_s / 6), 40)
    if name == "periodic":
        # uniform in frequency, 2× oversampled against the run's resolution 1/T
        # compressor-like cycles: minutes to two hours, and at least six per run
        f_lo = max(1.0 / 7200.0, 6.0 / ctx.duration_s)
        f_hi = 1.0 / max(120.0, 4.0 * ctx.bin_s)
        nf = int(min(2000, max(20, 2 * (f_hi - f_lo) * ctx.duration_s)))
        return 1.0 / np.linspace(f_lo, f_hi, nf)
    raise KeyError(name)


def _bounds(name: str, ctx: GyroContext) -> tuple[float, float]:
    g = nonlinear_grid(name, ctx)
    return float(g.min()), float(g.max())


@dataclass
class GyroStructure:
    """Active gyro effects and their nonlinear parameters."""

    names: list[str]
    theta: dict[str, float] = field(default_factory=dict)

    def with_effect(self, name: str, value: float | None = None) -> GyroStructure:
        th = dict(self.theta)
        if value is not None:
            th[name] = value
        return GyroStructure(self.names + [name], th)


def _temps(struct: GyroStructure, ctx: GyroContext) -> tuple[np.ndarray, np.ndarray]:
    """Bias-setting temperature and its rate on the grid."""
    if "thermal_lag" in struct.names:
        tau = struct.theta["thermal_lag"]
        alpha = 1.0 - math.exp(-1.0 / tau)
        from gyrolab.sim.discrepancy.thermal_fit import lowpass

        die = lowpass(ctx.case_c, alpha, float(ctx.case_c[0]))
        return die, (ctx.case_c - die) / tau
    return ctx.case_c, ctx.dcase


def design(struct: GyroStructure, ctx: GyroContext) -> tuple[np.ndarray, list[str]]:
    """Design matrix at the bin centres and the names of its columns."""
    temp_g, dtemp_g = _temps(struct, ctx)
    T = np.interp(ctx.t, ctx.grid_t, temp_g)
    x = T - 25.0
    cols: list[np.ndarray] = []
    names: list[str] = []
    for name in struct.names:
        if name == "bias_poly":
            for i in range(ctx.poly_order + 1):
                cols.append(x**i)
                names.append(f"bias_poly.c{i}")
        elif name == "cubic_temp":
            cols.append(x**3)
            names.append("cubic_temp.c3")
        elif name == "thermal_rate":
            cols.append(60.0 * np.interp(ctx.t, ctx.grid_t, dtemp_g))
            names.append("thermal_rate.k")
        elif name == "hysteresis":
            s = np.empty(temp_g.size)
            tc = struct.theta.get(HYST_TC, 0.0)
            if tc == 0.0:
                play(temp_g, float(temp_g[0]), 0.5 * struct.theta["hysteresis"], s)
            else:
                half = 0.5 * hysteresis_width(temp_g, struct.theta["hysteresis"], tc)
                tg = np.ascontiguousarray(temp_g, dtype=np.float64)
                play_var(tg, float(temp_g[0]), half, s)
            cols.append(0.5 * np.interp(ctx.t, ctx.grid_t, s))
            names.append("hysteresis.h")
        elif name == "warmup":
            cols.append(np.exp(-ctx.t / struct.theta["warmup"]))
            names.append("warmup.A")
            if WARMUP2 in struct.theta:
                cols.append(np.exp(-ctx.t / struct.theta[WARMUP2]))
                names.append("warmup.A2")
        elif name == "aging_ramp":
            cols.append(ctx.t / 3600.0)
            names.append("aging_ramp.r")
        elif name == "periodic":
            w = 2.0 * np.pi / struct.theta["periodic"]
            cols += [np.sin(w * ctx.t), np.cos(w * ctx.t)]
            names += ["periodic.a_sin", "periodic.a_cos"]
        elif name == "thermal_lag":
            pass  # changes the temperature the other columns see
        else:
            raise KeyError(name)
    return np.column_stack(cols), names


@dataclass
class GyroFit:
    """A fitted deterministic structure."""

    struct: GyroStructure
    gls: GlsResult
    columns: list[str]
    pred: np.ndarray

    @property
    def bic(self) -> float:
        return self.gls.bic

    def coef(self) -> dict[str, float]:
        return dict(zip(self.columns, map(float, self.gls.beta), strict=True))


def _fit_fixed(struct: GyroStructure, ctx: GyroContext, phi: np.ndarray | None = None) -> GyroFit:
    X, cols = design(struct, ctx)
    g = gls_ar(ctx.y, X, AR_ORDER, extra_params=n_nonlinear(struct), phi=phi)
    return GyroFit(struct, g, cols, X @ g.beta)


def _periodic_scan(
    struct: GyroStructure, ctx: GyroContext, phi: np.ndarray, periods: np.ndarray
) -> np.ndarray:
    """Whitened RSS of the structure with its sine/cosine pair at each period, vectorized:
    the other columns are whitened and orthogonalized once (QR), each pair is projected
    out of their complement, and RSS = ‖r‖² − (Zᵀr)ᵀ(ZᵀZ)⁻¹(Zᵀr) with Z ⟂ the base."""
    base = GyroStructure([n for n in struct.names if n != "periodic"], struct.theta)
    X, _ = design(base, ctx)
    scale = np.sqrt(np.mean(X * X, axis=0))
    scale[scale == 0] = 1.0
    Xw = ar_whiten(X / scale, phi)
    yw = ar_whiten(ctx.y, phi)
    Q, _ = np.linalg.qr(Xw)
    r = yw - Q @ (Q.T @ yw)
    rss0 = float(r @ r)
    out = np.empty(periods.size)
    for i0 in range(0, periods.size, 256):
        w = 2.0 * np.pi / periods[i0 : i0 + 256]
        ph = np.outer(ctx.t, w)
        S = ar_whiten(np.sin(ph), phi)
        C = ar_whiten(np.cos(ph), phi)
        S -= Q @ (Q.T @ S)
        C -= Q @ (Q.T @ C)
        a, b = S.T @ r, C.T @ r
        ss, cc, sc = (S * S).sum(0), (C * C).sum(0), (S * C).sum(0)
        det = ss * cc - sc * sc
        red = (cc * a * a - 2 * sc * a * b + ss * b * b) / np.where(det > 0, det, np.inf)
        out[i0 : i0 + 256] = rss0 - red
    return out


def fit_structure(
    struct: GyroStructure,
    ctx: GyroContext,
    passes: int = 2,
    scan: tuple[str, ...] = (),
    whitener: Any = None,
) -> GyroFit:
    """Fit a structure's nonlinear parameters by coordinate search, then its linear ones.

    With ``scan`` (a candidate being tried) only those parameters move — a grid scan, then
    a bounded 1-D refinement — and the others stay where the current model has them, so
    a candidate's score is its own. Without, every nonlinear parameter is refined locally
    (a periodic term within ± one frequency-resolution cell, whose likelihood is
    multimodal in P). The scan uses an AR(8) noise model held fixed; the refinement the
    known-covariance ``whitener`` when given (the criterion the score uses).
    """
    nl = [n for n in struct.names if n in NONLINEAR]
    need = set(scan) | {n for n in nl if n not in struct.theta}
    move = [n for n in nl if n in need] if scan else nl
    theta = dict(struct.theta)
    for n in nl:
        if n not in theta:
            g = nonlinear_grid(n, ctx)
            theta[n] = float(g[g.size // 2])
    struct = GyroStructure(struct.names, theta)
    cur = _fit_fixed(struct, ctx)
    for _ in range(passes if move else 0):
        phi = cur.gls.phi
        for name in move:
            lo, hi = _bounds(name, ctx)

            def rss(
                v: float, name: str = name, th: dict = cur.struct.theta, phi: np.ndarray = phi
            ) -> float:
                s = GyroStructure(struct.names, {**th, name: v})
                if whitener is None:
                    return _fit_fixed(s, ctx, phi).gls.rss
                X, _ = design(s, ctx)
                return gls_cov(ctx.y, X, whitener).rss

            if name in need:
                grid = nonlinear_grid(name, ctx)
                if name == "periodic":
                    costs = _periodic_scan(cur.struct, ctx, phi, grid)
                else:

                    def ar_rss(
                        v: float, name: str = name, th: dict = cur.struct.theta, phi=phi
                    ) -> float:
                        s = GyroStructure(struct.names, {**th, name: v})
                        return _fit_fixed(s, ctx, phi).gls.rss

                    costs = np.array([ar_rss(float(v)) for v in grid])
                i = int(np.argmin(costs))
                a = float(grid[max(i - 1, 0)])
                b = float(grid[min(i + 1, grid.size - 1)])
                start = float(grid[i])
            else:
                start = cur.struct.theta[name]
                if name == "periodic":
                    half = start * start / ctx.duration_s
                    a, b = max(lo, start - half), min(hi, start + half)
                else:
                    a, b = max(lo, start / 1.5), min(hi, start * 1.5)
            best = start
            if b > a:
                r = minimize_scalar(
                    lambda lv, c=rss: c(math.exp(lv)),
                    bounds=(math.log(a), math.log(b)),
                    method="bounded",
                    options={"xatol": 1e-4},
                )
                if r.fun <= rss(start):
                    best = math.exp(float(r.x))
            cur = _fit_fixed(GyroStructure(struct.names, {**cur.struct.theta, name: best}), ctx)
        need = set()
    return cur


def effect_params(fit: GyroFit) -> dict[str, dict[str, float]]:
    """Simulator parameters of every gyro effect of a fit (°/s units as in effects.py)."""
    c = fit.coef()
    th = fit.struct.theta
    out: dict[str, dict[str, float]] = {}
    for name in fit.struct.names:
        if name == "bias_poly":
            p = {f"c{i}": c[f"bias_poly.c{i}"] for i in range(5) if f"bias_poly.c{i}" in c}
            p["t_ref_c"] = 25.0
            out[name] = p
        elif name == "cubic_temp":
            out[name] = {"c3": c["cubic_temp.c3"], "t_ref_c": 25.0}
        elif name == "thermal_rate":
            out[name] = {"k": c["thermal_rate.k"]}
        elif name == "thermal_lag":
            out[name] = {"tau_s": th["thermal_lag"]}
        elif name == "hysteresis":
            out[name] = {
                "h": c["hysteresis.h"],
                "width_c": th["hysteresis"],
                "width_tc": th.get(HYST_TC, 0.0),
            }
        elif name == "warmup":
            out[name] = {"A": c["warmup.A"], "tau_s": th["warmup"]}
            if WARMUP2 in th:
                out[name].update({"A2": c["warmup.A2"], "tau2_s": th[WARMUP2]})
        elif name == "aging_ramp":
            out[name] = {"r": c["aging_ramp.r"]}
        elif name == "periodic":
            a, b = c["periodic.a_sin"], c["periodic.a_cos"]
            out[name] = {
                "A": float(math.hypot(a, b)),
                "period_s": th["periodic"],
                "phase_rad": float(math.atan2(b, a)),
            }
    return out


def widen_form(fit: GyroFit, ctx: GyroContext, name: str, score: Any) -> tuple[GyroFit, str]:
    """The wider form of ``name`` within its vocabulary name, when ``score`` (a BIC:
    lower is better, parameters counted) prefers it: warm-up as two exponentials (the
    second time constant scanned on the warm-up grid, then the first re-scanned; signs
    free), hysteresis with a width that changes linearly with temperature (slope scanned
    over ±2 %/°C of the width at 25 °C). Returns the chosen fit and the form's label."""
    st = fit.struct
    best, best_bic, label = fit, score(fit.struct), "single"
    if name == "warmup":
        grid = nonlinear_grid("warmup", ctx)
        phi = fit.gls.phi if fit.gls.phi.size else _fit_fixed(st, ctx).gls.phi
        t1 = st.theta["warmup"]
        cands = [v for v in grid if abs(math.log(v / t1)) > 0.3]

        def rss(t1: float, t2: float) -> float:
            s2 = GyroStructure(st.names, {**st.theta, "warmup": t1, WARMUP2: t2})
            return _fit_fixed(s2, ctx, phi).gls.rss

        if cands:
            t2 = float(min(cands, key=lambda v: rss(t1, float(v))))
            c1 = [v for v in grid if abs(math.log(v / t2)) > 0.3]
            t1 = float(min(c1, key=lambda v: rss(float(v), t2)))
            s2 = GyroStructure(st.names, {**st.theta, "warmup": t1, WARMUP2: t2})
            b = score(s2)
            if b < best_bic:
                best, best_bic, label = _fit_fixed(s2, ctx), b, "two exponentials"
    elif name == "hysteresis":
        w0 = st.theta["hysteresis"]
        for rel in (-0.02, -0.01, -0.005, 0.005, 0.01, 0.02):
            s2 = GyroStructure(st.names, {**st.theta, HYST_TC: rel * w0})
            b = score(s2)
            if b < best_bic:
                best, best_bic, label = _fit_fixed(s2, ctx), b, "temperature-dependent width"
    return best, label
