"""Deterministic gyro terms: regressors from the recorded temperatures and time, fitted by
AR-noise least squares on the low-frequency output (see :mod:`.gls`).

Every vocabulary effect that is a function of the temperature history and time becomes
columns of a design matrix evaluated at the bin centres (``x = T − 25 °C``; ``T`` the
bias-setting temperature: the case, or with ``thermal_lag`` the die). Each effect declares
its own columns, shape parameter and scan grid beside its physics (``terms`` in
``sim/effects.py``, :mod:`gyrolab.sim.candidate`); this module is generic over them. The
built-in ones::

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

from gyrolab.sim.candidate import Bins
from gyrolab.sim.discrepancy import catalogue as cat
from gyrolab.sim.discrepancy.gls import GlsResult, ar_whiten, gls_ar, gls_cov
from gyrolab.sim.effects import EFFECTS

AR_ORDER = 8


def n_nonlinear(struct: GyroStructure) -> int:
    """Nonlinear parameters of a structure (the wider forms' extra shape parameters too)."""
    keys = {cat.form_key(n) for n in struct.names}
    return sum(1 for n in struct.names if cat.shape_of(n)) + sum(
        1 for k in struct.theta if k in keys
    )


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
    """Scan grid of an effect's nonlinear parameter (its declared ``terms.grid``)."""
    grid = cat.terms(name).grid
    if grid is None:
        raise KeyError(name)
    return grid(ctx.duration_s, ctx.bin_s)


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


def bins_of(struct: GyroStructure, ctx: GyroContext) -> Bins:
    """What the structure's terms are evaluated on: the bias-setting temperature (the case,
    or what a temperature-changing term such as ``thermal_lag`` makes of it) and its rate,
    on the grid and at the bin centres."""
    temp_g, dtemp_g = ctx.case_c, ctx.dcase
    for name in struct.names:
        change = cat.terms(name).temperature
        if change is not None:
            temp_g, dtemp_g = change(ctx.case_c, cat.shape_values(name, struct.theta))
    return Bins(
        t=ctx.t,
        temp_c=np.interp(ctx.t, ctx.grid_t, temp_g),
        dtemp_c_per_s=np.interp(ctx.t, ctx.grid_t, dtemp_g),
        grid_t=ctx.grid_t,
        grid_temp_c=temp_g,
        grid_dtemp_c_per_s=dtemp_g,
        poly_order=ctx.poly_order,
    )


def design(struct: GyroStructure, ctx: GyroContext) -> tuple[np.ndarray, list[str]]:
    """Design matrix at the bin centres and the names of its columns (``effect.coef``)."""
    b = bins_of(struct, ctx)
    cols: list[np.ndarray] = []
    names: list[str] = []
    for name in struct.names:
        columns = cat.terms(name).columns
        if columns is None:
            continue  # changes the temperature the other columns see
        for coef, col in columns(b, cat.shape_values(name, struct.theta)):
            cols.append(col)
            names.append(f"{name}.{coef}")
    return np.column_stack(cols), names


def redundant(name: str, struct: GyroStructure, ctx: GyroContext) -> bool:
    """Whether candidate ``name``'s regressors are already columns of ``struct``'s design
    (``cubic_temp`` when the starting model's polynomial has x³): not a candidate then."""
    t = cat.terms(name)
    if t.columns is None or t.shape is not None:
        return False
    X, _ = design(struct, ctx)
    new = [c for _, c in t.columns(bins_of(struct, ctx), cat.shape_values(name, struct.theta))]
    return all(any(np.array_equal(c, X[:, j]) for j in range(X.shape[1])) for c in new)


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


def _frequency_scan(
    struct: GyroStructure, ctx: GyroContext, phi: np.ndarray, periods: np.ndarray, name: str
) -> np.ndarray:
    """Whitened RSS of the structure with term ``name``'s sine/cosine pair at each period,
    vectorized: the other columns are whitened and orthogonalized once (QR), each pair is
    projected out of their complement, and RSS = ‖r‖² − (Zᵀr)ᵀ(ZᵀZ)⁻¹(Zᵀr) with Z ⟂ the
    base."""
    base = GyroStructure([n for n in struct.names if n != name], struct.theta)
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
    nl = [n for n in struct.names if cat.shape_of(n)]
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
                if cat.terms(name).scan == "frequency":
                    costs = _frequency_scan(cur.struct, ctx, phi, grid, name)
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
                if cat.terms(name).scan == "frequency":
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
    """Simulator parameters of every gyro term of a fit (°/s units as in effects.py): its
    fitted coefficients, shape and held values (or what the term ``derive``s from them),
    in the order of the effect's parameter table."""
    c = fit.coef()
    out: dict[str, dict[str, float]] = {}
    for name in fit.struct.names:
        t = cat.terms(name)
        pre = name + "."
        v = {k[len(pre) :]: x for k, x in c.items() if k.startswith(pre)}
        v.update(cat.shape_values(name, fit.struct.theta))
        if t.derive is not None:
            v.update(t.derive(v))
        out[name] = {p: v[p] for p in EFFECTS[name].PARAMS if p in v}
    return out


def widen_form(fit: GyroFit, ctx: GyroContext, name: str, score: Any) -> tuple[GyroFit, str]:
    """The wider form of ``name`` within its vocabulary name (its declared ``wider``), when
    ``score`` (a BIC: lower is better, parameters counted) prefers it: ``second`` — a
    second component of the same shape, its shape scanned on the term's grid, then the
    first re-scanned (signs free; the warm-up's two exponentials); ``slope`` — the shape
    parameter linear in temperature, the declared relative slopes tried (the hysteresis
    width over ±2 %/°C). Returns the chosen fit and the form's label."""
    st = fit.struct
    best, best_bic, label = fit, score(fit.struct), "single"
    wider = cat.terms(name).wider
    key = cat.form_key(name)
    if wider is None or key is None:
        return best, label
    if wider.kind == "second":
        grid = nonlinear_grid(name, ctx)
        phi = fit.gls.phi if fit.gls.phi.size else _fit_fixed(st, ctx).gls.phi
        t1 = st.theta[name]
        cands = [v for v in grid if abs(math.log(v / t1)) > 0.3]

        def rss(t1: float, t2: float) -> float:
            s2 = GyroStructure(st.names, {**st.theta, name: t1, key: t2})
            return _fit_fixed(s2, ctx, phi).gls.rss

        if cands:
            t2 = float(min(cands, key=lambda v: rss(t1, float(v))))
            c1 = [v for v in grid if abs(math.log(v / t2)) > 0.3]
            t1 = float(min(c1, key=lambda v: rss(float(v), t2)))
            s2 = GyroStructure(st.names, {**st.theta, name: t1, key: t2})
            b = score(s2)
            if b < best_bic:
                best, best_bic, label = _fit_fixed(s2, ctx), b, wider.label
    elif wider.kind == "slope":
        w0 = st.theta[name]
        for rel in wider.tries:
            s2 = GyroStructure(st.names, {**st.theta, key: rel * w0})
            b = score(s2)
            if b < best_bic:
                best, best_bic, label = _fit_fixed(s2, ctx), b, wider.label
    return best, label
