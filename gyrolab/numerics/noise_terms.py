"""IEEE 952 noise terms read from an Allan deviation curve, only where it identifies them.

Noise terms follow IEEE Std 952-1997 Annex C (rate units ``u``, e.g. deg/s; tau in s)::

    avar(tau) = 3 Q^2 / tau^2 + N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3 + R^2 tau^2 / 2

    Q  quantization noise       [u s]        slope -1   read at tau = sqrt(3) s
    N  angle random walk        [u sqrt(s)]  slope -1/2 read at tau = 1 s
    B  bias instability         [u]          slope 0    sigma_min / 0.664
    K  rate random walk         [u / sqrt(s)] slope +1/2 read at tau = 3 s
    R  rate ramp                [u / s]      slope +1   read at tau = sqrt(2) s

For u = deg/s: ARW in deg/sqrt(h) = 60 N (sqrt(h) = 60 sqrt(s)); B in deg/h = 3600 B;
K in deg/h/sqrt(h) = 216 000 K; R in deg/h^2 = 3600^2 R; Q in arcsec = 3600 Q.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy import optimize, stats

from gyrolab.errors import InputError
from gyrolab.numerics.allan import DeviationResult

__all__ = ["FLICKER_FLOOR", "NoiseTerms", "filter_corner_tau", "noise_terms"]

#: sqrt(2 ln 2 / pi): sigma of flicker rate noise B on the flat part of the curve.
FLICKER_FLOOR = math.sqrt(2.0 * math.log(2.0) / math.pi)  # 0.6643

# name: (log-log slope of the deviation, tau (s) at which the line reads the coefficient)
_SLOPE_RULES = {
    "Q": (-1.0, math.sqrt(3.0)),
    "N": (-0.5, 1.0),
    "K": (0.5, 3.0),
    "R": (1.0, math.sqrt(2.0)),
}
# the slopes a region of each term must be told apart from (its physical neighbours)
_NEIGHBOURS = {"Q": (-0.5,), "N": (-1.0, 0.0), "B": (-0.5, 0.5), "K": (0.0, 1.0), "R": (0.5,)}
# avar coefficient c_p of tau^p -> term: Q = sqrt(c/3), N = sqrt(c), B = sqrt(c/FLOOR^2) ...
_FIT_POWERS = {"Q": -2, "N": -1, "B": 0, "K": 1, "R": 2}
_FIT_SCALE = {"Q": 3.0, "N": 1.0, "B": FLICKER_FLOOR**2, "K": 1.0 / 3.0, "R": 0.5}
#: Confidence of the slope tests (two-sided 95 %): a region's local slopes must be
#: consistent with the term's slope, and its fitted slope inconsistent with the
#: neighbouring terms' slopes, at this level.
SLOPE_TEST_LEVEL = 0.95
#: Lag-1 autocorrelation of the raw samples above which a record is taken as low-passed
#: by the sensor's own filter (white noise: 0 ± 1/sqrt(n)); see :func:`filter_corner_tau`.
FILTERED_R1 = 0.02
#: How far (in log-log slope) a local slope may sit from a term's own where that term
#: dominates: the other terms then contribute a few per cent of the variance (a white-noise
#: curve with a flicker floor 10x below it bends by less than 0.1 over an octave).
DOMINANCE_TOL = 0.1


@dataclass(frozen=True)
class NoiseTerms:
    """IEEE 952 noise coefficients in the data's rate unit ``u`` (tau in seconds).

    Q [u s], N [u sqrt(s)], B [u], K [u/sqrt(s)], R [u/s]. A term the curve does not
    identify is NaN here, ``None`` in :meth:`to_dict` / :meth:`deg_h`, and ``reasons``
    says why; ``tau_ranges`` gives the (first, last) tau (s) each identified term was read
    on; ``upper_bounds`` holds sigma_min/0.664 when there is no floor (an upper bound on B).
    """

    Q: float
    N: float
    B: float
    K: float
    R: float
    method: str
    tau_b: float = float("nan")  #: tau (s) of the minimum of the curve (B read there)
    slopes: dict = field(default_factory=dict)  #: local slope actually used per term
    reasons: dict = field(default_factory=dict)  #: term -> why it is not identifiable
    tau_ranges: dict = field(default_factory=dict)  #: term -> (tau_lo, tau_hi) in s
    upper_bounds: dict = field(default_factory=dict)  #: term -> upper bound (rate units)
    tau_min: float = float("nan")  #: shortest tau (s) the terms were read on

    def value(self, name: str) -> float | None:
        """The term, or ``None`` when not identifiable."""
        v = float(getattr(self, name))
        return v if math.isfinite(v) else None

    def to_dict(self) -> dict:
        """JSON-ready: the raw terms (``None`` if not identifiable), the customary units,
        method, tau_b, slopes, reasons, tau ranges and upper bounds."""
        return {
            **{k: self.value(k) for k in "QNBKR"},
            **self.deg_h(),
            "method": self.method,
            "tau_b": self.tau_b,
            "slopes": dict(self.slopes),
            "reasons": dict(self.reasons),
            "tau_ranges": {k: list(v) for k, v in self.tau_ranges.items()},
            "upper_bounds": dict(self.upper_bounds),
            "tau_min": self.tau_min,
        }

    def deg_h(self) -> dict[str, float | None]:
        """The terms for data in deg/s, in the customary gyro units (``None``: not
        identifiable)."""
        scale = {
            "quantization_arcsec": ("Q", 3600.0),
            "arw_deg_per_sqrt_h": ("N", 60.0),
            "bias_instability_deg_per_h": ("B", 3600.0),
            "rrw_deg_per_h_per_sqrt_h": ("K", 216000.0),
            "rate_ramp_deg_per_h2": ("R", 3600.0**2),
        }
        out: dict[str, float | None] = {}
        for key, (name, f) in scale.items():
            v = self.value(name)
            out[key] = None if v is None else f * v
        return out


def _log_uncertainty(result: DeviationResult, ok: np.ndarray) -> np.ndarray:
    """One-sigma uncertainty of log10(adev) per point from the confidence bounds (NaN
    where the result has none): half the log width of the interval over its z."""
    lo = np.asarray(result.dev_lo, dtype=float)[ok]
    hi = np.asarray(result.dev_hi, dtype=float)[ok]
    z = stats.norm.ppf(0.5 + float(result.confidence) / 2.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = (np.log10(hi) - np.log10(lo)) / (2.0 * z)
    return np.where(np.isfinite(u) & (u > 0), u, np.nan)


def _region_slope(lt: np.ndarray, la: np.ndarray, u: np.ndarray) -> tuple[float, float]:
    """Weighted least-squares slope of log10 adev against log10 tau and its standard error
    (points taken as independent: conservative, adjacent overlapping estimates are
    positively correlated)."""
    w = 1.0 / u**2
    xm = float(np.sum(w * lt) / np.sum(w))
    sxx = float(np.sum(w * (lt - xm) ** 2))
    slope = float(np.sum(w * (lt - xm) * la) / sxx)
    return slope, 1.0 / math.sqrt(sxx)


def _best_region(
    lt: np.ndarray,
    la: np.ndarray,
    u: np.ndarray | None,
    slope: float,
    neighbours: tuple[float, ...],
    slope_tol: float,
    start: int | None = None,
    end: int | None = None,
    contains: int | None = None,
    min_points: int = 2,
) -> tuple[int, int] | None:
    """The longest run of consecutive points ``[i, j]`` (``min_points`` or more) on which
    the data identify ``slope``.

    Every local (pair) slope must be within ``slope_tol`` of it; with confidence bounds
    also within :data:`DOMINANCE_TOL` of it up to its own uncertainty (z at
    :data:`SLOPE_TEST_LEVEL`), and the run's fitted slope must exclude every neighbouring
    term's slope at that level. Optional constraints: the run starts at ``start``, ends
    at ``end``, contains ``contains``."""
    n = lt.size
    local = np.diff(la) / np.diff(lt)
    z = stats.norm.ppf(0.5 + SLOPE_TEST_LEVEL / 2.0)
    if u is not None:
        u_local = np.sqrt(u[:-1] ** 2 + u[1:] ** 2) / np.diff(lt)
        pair_ok = np.abs(local - slope) <= np.minimum(slope_tol, DOMINANCE_TOL + z * u_local)
    else:
        pair_ok = np.abs(local - slope) <= slope_tol
    best: tuple[int, int] | None = None
    for i in range(n - 1):
        if start is not None and i != start:
            continue
        for j in range(i + 1, n):
            if not pair_ok[j - 1]:
                break  # the run cannot extend past a pair of the wrong slope
            if end is not None and j != end:
                continue
            if contains is not None and not i <= contains <= j:
                continue
            if j - i + 1 < min_points:
                continue
            if u is not None:
                s_hat, s_err = _region_slope(lt[i : j + 1], la[i : j + 1], u[i : j + 1])
                if any(abs(s_hat - nb) <= z * s_err for nb in neighbours):
                    continue
            if best is None or j - i > best[1] - best[0]:
                best = (i, j)
    return best


def _nnls_terms(taus: np.ndarray, adev: np.ndarray, edf: np.ndarray, names: str) -> dict:
    """Coefficients c_p of avar = sum c_p tau^p (non-negative least squares), each point
    weighted by its relative uncertainty sqrt(edf / 2) / avar (unit weights where the EDF
    is unknown)."""
    powers = np.array([_FIT_POWERS[t] for t in names], dtype=float)
    avar = adev**2
    w = np.where(np.isfinite(edf) & (edf > 0), np.sqrt(np.maximum(edf, 1e-12) / 2.0), 1.0)
    w = w / avar
    a = (taus[:, None] ** powers[None, :]) * w[:, None]
    b = avar * w
    # scale columns so NNLS is well conditioned across decades of tau
    col = np.linalg.norm(a, axis=0)
    col[col == 0] = 1.0
    c, _ = optimize.nnls(a / col, b, maxiter=50 * len(names))
    return dict(zip(names, c / col, strict=True))


def _lag1(y: np.ndarray) -> float:
    y = y - y.mean()
    d = float(np.dot(y, y))
    return float(np.dot(y[1:], y[:-1]) / d) if d > 0 else 0.0


def filter_corner_tau(x: np.ndarray, rate_hz: float, max_octaves: int = 12) -> float:
    """Shortest averaging time (s) at which a static record is free of the sensor's own
    low-pass filter (decimation filter, digital averaging), from the lag-1
    autocorrelation ``r1(m)`` of its non-overlapping m-sample averages (m = 1, 2, 4, …).

    White rate noise gives ``r1 = 0`` at every m (± 1/√n); a filter with correlation time
    T_f makes adjacent samples alike, ``r1 > 0`` (or < 0 where it rings), decaying as the
    averages grow past T_f; coloured noise (flicker, random walk) raises ``r1`` again at
    long m. The Allan variance of m-averages is ``var(ȳ_m)·(1 − r1(m))``, and the filter
    also lowers ``var(ȳ_m)`` itself, so on ``τ < T_f`` σ(τ) lies below the white-noise
    line and an ARW read there comes out low (on a real ADIS16405 record at 100 Hz by
    15 %, issue 23). Rule: a record whose raw ``|r1(1)|`` is within
    max(:data:`FILTERED_R1`, 3/√n) of 0 is unfiltered (corner = one sample); otherwise the
    corner is one octave above the first m from which ``|r1(m)|`` stays within its own
    sampling scatter (3/√n) of its minimum over the octaves with ≥ 1000 averages (and m = 1), up to
    that minimum — where the filter's correlation has decayed and the coloured noise has
    not yet taken over (a filter that rings makes ``r1`` swing in sign over the first
    octaves and pass near 0 before it has settled: hence ``|r1|`` and "stays"; the
    ADIS16405's Z gyro does so) — so that the ARW is read where σ·√τ has reached its
    white-noise plateau. Returns seconds. NaN samples (gaps) are dropped."""
    y = np.asarray(x, dtype=float)
    y = y[np.isfinite(y)]
    dt = 1.0 / float(rate_hz)
    if y.size < 64:
        return dt
    if abs(_lag1(y)) <= max(FILTERED_R1, 3.0 / math.sqrt(y.size)):
        return dt
    ms, r1 = [], []
    m = 1
    for _ in range(max_octaves):
        n = y.size // m
        if n < 1000 and m > 1:  # the raw samples always count, however few
            break
        ms.append(m)
        r1.append(abs(_lag1(y[: n * m].reshape(n, m).mean(axis=1))))
        m *= 2
    k_lo = int(np.argmin(r1))
    near = [r1[k] <= r1[k_lo] + 3.0 / math.sqrt(y.size // ms[k]) for k in range(k_lo + 1)]
    k = k_lo
    while k > 0 and near[k - 1]:
        k -= 1  # the first octave of the run of settled octaves that ends at the minimum
    return 2.0 * ms[k] * dt


def _fmt_tau(t: float) -> str:
    return f"{t:.3g} s"


def noise_terms(
    result: DeviationResult,
    method: Literal["slope", "fit"] = "slope",
    slope_tol: float | None = 0.25,
    terms: tuple[str, ...] = ("Q", "N", "B", "K", "R"),
    b_max_tau_fraction: float = 0.1,
    tau_min: float | None = None,
) -> NoiseTerms:
    """IEEE 952 noise terms from an Allan deviation curve, only where the curve identifies
    them.

    Every term is read from taus with at least 1/``b_max_tau_fraction`` (default 10)
    independent averages: tau <= T/10, T the record length (the last points rest on a
    handful of averages and scatter).

    ``method="slope"`` (IEEE 952 C.2 slope rules, made testable): a term with slope s is
    read on the longest run of two or more consecutive taus whose local slopes are within
    ``slope_tol`` of s and — when the result has confidence bounds — on which the line of
    slope s is consistent with the points while the lines of the neighbouring terms'
    slopes (s ± 1/2) are rejected (chi-squared of the log deviations, 95 %). The line's
    value at the term's tau gives it (N at 1 s, K at 3 s, R at sqrt(2) s, Q at sqrt(3) s).
    Q (white angle noise falls fastest) must start at the shortest tau, R (rises fastest)
    must end at the longest usable one. B = sigma_min / 0.664 only at a true floor: a run
    through the minimum identified as slope 0 by the same test; otherwise B is not
    identifiable and sigma_min / 0.664 is reported as an upper bound. Terms that fail are
    NaN with a reason in ``NoiseTerms.reasons``.

    ``slope_tol=None`` is the single-point rule (always read, no confidence test): each
    term from the adjacent pair whose slope is closest to its own, B at the minimum
    (what the ``arw_deg_per_sqrt_h``/``bias_instability_deg_per_h`` metrics use).

    ``method="fit"``: non-negative least squares of avar(tau) = sum c_p tau^p over the terms
    asked for, on the usable taus, each point weighted by its relative uncertainty
    sqrt(edf / 2) / avar (unit weights where the EDF is unknown); Q, N, B, K, R follow from
    c_p (module docstring). A term whose fitted share of avar is below one half at every
    usable tau is not identifiable (it is never the term the data show). A fitted B above
    its own identifiability bound sigma_min / 0.664 (the curve cannot show a flicker floor
    higher than its lowest point) is withheld with that reason.

    ``tau_min`` (s): taus below it are not used by either method — the sensor's own
    low-pass filter lowers sigma there (:func:`filter_corner_tau` detects it from the raw
    samples); the shortest tau used is ``NoiseTerms.tau_min``.
    """
    taus = np.asarray(result.taus, dtype=float)
    adev = np.asarray(result.dev, dtype=float)
    ok = adev > 0
    u_all = _log_uncertainty(result, ok)
    taus, adev = taus[ok], adev[ok]
    edf = np.asarray(result.edf, dtype=float)[ok]
    if taus.size == 0:
        raise InputError(None, "Allan deviation curve is empty or zero")
    record_s = result.duration_s if np.isfinite(result.duration_s) else np.inf
    usable = taus <= b_max_tau_fraction * record_s
    t_max = b_max_tau_fraction * record_s
    if tau_min is not None and np.isfinite(tau_min):
        usable &= taus >= float(tau_min) * (1.0 - 1e-9)
    if not usable.any():
        usable[:] = True
    taus, adev, edf, u_all = taus[usable], adev[usable], edf[usable], u_all[usable]
    imin = int(np.argmin(adev))
    tau_b = float(taus[imin])
    out = dict.fromkeys("QNBKR", float("nan"))
    slopes: dict[str, float] = {}
    reasons: dict[str, str] = {}
    ranges: dict[str, tuple[float, float]] = {}
    bounds: dict[str, float] = {}
    few = f"tau <= T/{1 / b_max_tau_fraction:.0f} = {_fmt_tau(t_max)}"
    if method == "slope":
        lt, la = np.log10(taus), np.log10(adev)
        local = np.diff(la) / np.diff(lt) if taus.size >= 2 else np.zeros(0)
        have_ci = bool(np.all(np.isfinite(u_all))) and slope_tol is not None
        u = u_all if have_ci else None
        if slope_tol is None:
            # single-point rule: always read
            if "B" in terms:
                out["B"] = float(adev[imin] / FLICKER_FLOOR)
                slopes["B"] = 0.0
                ranges["B"] = (tau_b, tau_b)
            for name, (slope, tau_read) in _SLOPE_RULES.items():
                if name not in terms or local.size == 0:
                    continue
                i = int(np.argmin(np.abs(local - slope)))
                slopes[name] = float(local[i])
                lt_mid = 0.5 * (lt[i] + lt[i + 1])
                la_mid = 0.5 * (la[i] + la[i + 1])
                out[name] = float(10.0 ** (la_mid + slope * (math.log10(tau_read) - lt_mid)))
                ranges[name] = (float(taus[i]), float(taus[i + 1]))
        else:
            tol = float(slope_tol)
            how = "whose confidence intervals separate it from the neighbouring slopes"
            how = how if have_ci else ""
            # every term is looked for (the joint fit below needs to know which the curve
            # shows, whatever was asked); those not asked are dropped at the end
            for name in ("Q", "N", "B", "K", "R"):
                slope, tau_read = (0.0, float("nan")) if name == "B" else _SLOPE_RULES[name]
                kw: dict = {}
                if name == "Q":
                    kw["start"] = 0
                elif name == "R":
                    kw["end"] = taus.size - 1
                elif name == "B":
                    # a floor spans at least two octaves: over one, any V-shaped minimum
                    # between a falling and a rising term looks flat
                    kw.update(contains=imin, min_points=3)
                reg = (
                    _best_region(lt, la, u, slope, _NEIGHBOURS[name], tol, **kw)
                    if taus.size >= 2
                    else None
                )
                if reg is None:
                    if name == "B":
                        bounds["B"] = float(adev[imin] / FLICKER_FLOOR)
                        reasons["B"] = (
                            f"no floor within the record: the minimum at {_fmt_tau(tau_b)} "
                            f"(of {few}) is not on a flat stretch {how}".rstrip()
                            + f"; sigma_min/0.664 = {bounds['B']:.4g} is an upper bound"
                        )
                    else:
                        where = {"Q": " starting at the shortest tau", "R": " ending at T/10"}
                        reasons[name] = (
                            f"no run of taus with slope {slope:+g}{where.get(name, '')} in "
                            f"{few} {how}".rstrip()
                        )
                    continue
                i, j = reg
                ranges[name] = (float(taus[i]), float(taus[j]))
                slopes[name] = float((la[j] - la[i]) / (lt[j] - lt[i]))
                if name == "B":
                    out["B"] = float(adev[imin] / FLICKER_FLOOR)
                    continue
                w = None if u is None else 1.0 / u[i : j + 1] ** 2
                c = float(np.average(la[i : j + 1] - slope * lt[i : j + 1], weights=w))
                out[name] = float(10.0 ** (c + slope * math.log10(tau_read)))
            if have_ci:
                # the values of the identified terms from a joint fit of all five on the
                # usable taus: a single-slope line through a region also carries the
                # neighbouring terms' share of it (K read next to a white-noise region
                # comes out ~40 % high); B stays the IEEE sigma_min / 0.664. The fit starts
                # at the first identified region: below it the curve is none of the five
                # terms (a sensor filter's roll-off lowers sigma there, issue 23). A term
                # tested and found nowhere on the curve is left out of the fit (B, the
                # floor's bend, stays): else it takes a share it does not have (a Q term
                # took 7 % of N on a real ADIS16405 Z gyro whose filter rings)
                first = min((r[0] for r in ranges.values()), default=float(taus[0]))
                fit_at = taus >= first * (1.0 - 1e-9)
                model = "".join(t for t in "QNBKR" if t == "B" or t not in reasons)
                joint = dict.fromkeys("QNBKR", 0.0)
                joint.update(_nnls_terms(taus[fit_at], adev[fit_at], edf[fit_at], model))
                for name in ("Q", "N", "K", "R"):
                    if np.isfinite(out[name]) and joint[name] > 0:
                        out[name] = float(math.sqrt(joint[name] / _FIT_SCALE[name]))
    elif method == "fit":
        # a flicker floor cannot lie above the curve's lowest point (its upper confidence
        # bound where the curve has one: the lowest of many scattered points is biased
        # low, so the point alone would withhold a true floor)
        hi_b = float(np.asarray(result.dev_hi, dtype=float)[ok][usable][imin])
        b_limit = hi_b if np.isfinite(hi_b) and hi_b > 0 else float(adev[imin])
        names = [t for t in "QNBKR" if t in terms]
        model_names = list(names)
        while True:
            # a term never half of the fit anywhere is not in evidence: refit without it
            # (B, the floor's bend, stays), else it takes a share from the terms that are
            # (a Q term took 4 % of N on a real ADIS16405 Z gyro, issue 23)
            fitted = dict.fromkeys(names, 0.0)
            fitted.update(_nnls_terms(taus, adev, edf, "".join(model_names)))
            c = np.array([fitted[t] for t in names])
            powers = np.array([_FIT_POWERS[t] for t in names], dtype=float)
            model = taus[:, None] ** powers[None, :] * c[None, :]
            total = np.maximum(model.sum(axis=1, keepdims=True), np.finfo(float).tiny)
            share = model / total
            weak = [
                t
                for k, t in enumerate(names)
                if t in model_names and t != "B" and c[k] > 0 and not (share[:, k] >= 0.5).any()
            ]
            if not weak or len(model_names) - len(weak) < 1:
                break
            model_names = [t for t in model_names if t not in weak]
        for k, (t, cp) in enumerate(zip(names, c, strict=True)):
            slopes[t] = _FIT_POWERS[t] / 2.0
            if t not in model_names:
                reasons[t] = f"never half of the fitted Allan variance at {few}: refitted without"
                continue
            if not cp > 0:
                reasons[t] = f"fitted to zero on {few}"
                continue
            dom = share[:, k] >= 0.5
            if not dom.any():
                reasons[t] = f"never half of the fitted Allan variance at {few}"
                continue
            val = float(math.sqrt(cp / _FIT_SCALE[t]))
            if t == "B" and val > b_limit / FLICKER_FLOOR:
                bounds["B"] = float(adev[imin] / FLICKER_FLOOR)
                reasons["B"] = (
                    f"fitted {val:.4g} is above its identifiability bound sigma_min/0.664 = "
                    f"{bounds['B']:.4g} (the curve's lowest point, at {_fmt_tau(tau_b)}, "
                    "up to its confidence interval): withheld"
                )
                continue
            out[t] = val
            ranges[t] = (float(taus[dom][0]), float(taus[dom][-1]))
    else:
        raise InputError(None, f"unknown noise-term method {method!r} (slope or fit)")
    for name in set("QNBKR") - set(terms):
        out[name] = float("nan")
        for d in (slopes, reasons, ranges, bounds):
            d.pop(name, None)
    return NoiseTerms(
        **out,
        method=method,
        tau_b=tau_b,
        slopes=slopes,
        reasons=reasons,
        tau_ranges=ranges,
        upper_bounds=bounds,
        tau_min=float(taus[0]),
    )
