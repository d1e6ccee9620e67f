"""The discrepancy loop: fit the current model, compare, localize, name, add, repeat.

Channels and their candidate effects (each scored against the current model by a
likelihood criterion on the data it lives in):

=================  ==========================================  ==================
channel            candidates                                  score
=================  ==========================================  ==================
temperature        ``oven_overshoot`` (oven PV),               ΔBIC
                   ``rtd_self_heating`` (PT100)
gyro, < 0.01 Hz    ``cubic_temp`` ``thermal_rate``             ΔBIC, AR(4) noise
                   ``thermal_lag`` ``hysteresis`` ``warmup``
                   ``aging_ramp`` ``periodic``
gyro noise         ``rate_random_walk`` (Allan curve),         Δχ², LR, lattice
                   ``outliers`` (spike tail),
                   ``quantization`` (value lattice)
=================  ==========================================  ==================

``ΔBIC = BIC(current) − BIC(current + candidate)``. Each iteration looks at the channels in
that order (temperatures feed the gyro regressors; the deterministic fit feeds the Allan
curve of the residual) and adds the best candidate of the first channel that has a
significant one. Candidates whose score is within :data:`AMBIGUITY_MARGIN` of the best are
reported with it as an ``ambiguous`` set (at most three, best first): the data cannot tell
them apart, and the best is the one added. The loop stops when no channel has a
significant candidate.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from gyrolab.sim.discrepancy import noise_fit as nf
from gyrolab.sim.discrepancy.data import BenchData
from gyrolab.sim.discrepancy.gls import CovWhitener, bin_noise_autocov, gls_cov
from gyrolab.sim.discrepancy.gyro_fit import (
    FORM_KEYS,
    GYRO_EFFECTS,
    HYST_TC,
    NONLINEAR,
    WARMUP2,
    GyroContext,
    GyroFit,
    GyroStructure,
    design,
    effect_params,
    fit_structure,
    n_nonlinear,
    widen_form,
)
from gyrolab.sim.discrepancy.thermal_fit import (
    OVEN_FLOOR_C,
    CaseFit,
    OvenFit,
    delta_bic_channel,
    fit_case,
    fit_oven,
    pt100_noise_c,
)
from gyrolab.sim.model import SimModel, make_effect_spec
from gyrolab.sim.thermal import ThermalParams

GYRO_SIG = 10.0
"""ΔBIC above which a gyro-channel candidate is significant."""
TEMP_SIG = 25.0
"""ΔBIC above which a temperature-channel candidate is significant."""
TEMP_MIN_GAIN = 0.3
"""…and it must also cut that channel's residual RMS by at least this fraction."""
AMBIGUITY_MARGIN = 10.0
"""Candidates within this many score units of the best are reported as ambiguous."""
MAX_ITER = 6
LF_WINDOW_S = 100.0
"""Moving-average window of the low-frequency residual (0.01 Hz)."""

STOCHASTIC_BASE = ("arw", "bias_instability")
PRIMARY_GAP = {
    **{n: "lf_residual_rms_dps" for n in GYRO_EFFECTS},
    "oven_overshoot": "temperature_rms_c",
    "rtd_self_heating": "temperature_rms_c",
    "rate_random_walk": "allan_log_distance",
    "arw": "allan_log_distance",
    "bias_instability": "allan_log_distance",
    "outliers": "spike_log_ratio",
    "quantization": "lattice_tv_distance",
}


@dataclass
class Structure:
    """Which effects the model has, plus the values carried between iterations."""

    effects: list[str]
    theta: dict[str, float] = field(default_factory=dict)
    overshoot: tuple[float, float] | None = None

    def has(self, name: str) -> bool:
        return name in self.effects

    def plus(self, name: str) -> Structure:
        return Structure(self.effects + [name], dict(self.theta), self.overshoot)


@dataclass
class Fitted:
    """Everything fitted for one structure."""

    structure: Structure
    oven: OvenFit
    case: CaseFit
    gyro: GyroFit
    ctx: GyroContext
    noise: nf.NoiseFit
    outliers: nf.OutlierFit | None
    quant_q: float
    gaps: dict[str, float]
    whitener: CovWhitener | None = None
    cov_noise: nf.CovNoise | None = None
    """The bins' noise model the whitener comes from (learned from this residual)."""

    @property
    def resid(self) -> np.ndarray:
        return self.ctx.y - self.gyro.pred


def _poly_order(model: SimModel) -> int:
    bp = model.get("bias_poly")
    if bp is None:
        return 2
    return 4 if bp.params.get("c4", 0.0) else 3 if bp.params.get("c3", 0.0) else 2


def moving_average(x: np.ndarray, k: int) -> np.ndarray:
    """Centred moving average of ``k`` samples (edges use what is there)."""
    if k <= 1:
        return x
    c = np.concatenate([[0.0], np.cumsum(x)])
    i = np.arange(x.size)
    lo = np.clip(i - k // 2, 0, x.size)
    hi = np.clip(i - k // 2 + k, 0, x.size)
    return (c[hi] - c[lo]) / (hi - lo)


class Workflow:
    """Runs the discrepancy analysis of one recording against a starting model."""

    def __init__(self, data: BenchData, model: SimModel) -> None:
        self.d = data
        self.model0 = model
        self.pt_noise = max(pt100_noise_c(data), 1e-4)
        self.lsb = model.sensors.adc.lsb_dps
        self.poly_order = _poly_order(model)
        self._oven_cache: dict[Any, OvenFit] = {}
        self._case_cache: dict[bool, CaseFit] = {}

    # ------------------------------------------------------------------ fitting
    def _oven(self, st: Structure) -> OvenFit:
        key = ("os", st.overshoot) if st.has("oven_overshoot") else "first"
        if key not in self._oven_cache:
            th = self.model0.thermal
            if st.has("oven_overshoot"):
                base = self._oven_cache.get("first") or fit_oven(self.d, th)
                th = replace(th, **base.params)
                self._oven_cache[key] = fit_oven(
                    self.d, th, st.overshoot, True, form=base.form, x_start=base.x
                )
            else:
                self._oven_cache[key] = fit_oven(self.d, th)
        return self._oven_cache[key]

    def _case(self, st: Structure) -> CaseFit:
        k = st.has("rtd_self_heating")
        if k not in self._case_cache:
            self._case_cache[k] = fit_case(self.d, self.model0.thermal.case_tau_s, k)
        return self._case_cache[k]

    def _ctx(self, case: CaseFit) -> GyroContext:
        d = self.d
        # measured case temperature (reading minus the model's PT100 offset) on the grid
        meas = np.interp(case.grid_t, d.pt100_t, d.pt100_c) - case.offset_c
        return GyroContext(
            t=d.t,
            y=d.y,
            grid_t=case.grid_t,
            case_c=meas,
            dcase=case.dcase_c_per_s,
            duration_s=d.duration_s,
            bin_s=d.bin_s,
            poly_order=self.poly_order,
        )

    def _gyro_struct(self, st: Structure) -> GyroStructure:
        names = [n for n in st.effects if n in GYRO_EFFECTS]
        if "bias_poly" not in names:
            names = ["bias_poly"] + names
        theta = {
            k: v
            for k, v in st.theta.items()
            if (k in NONLINEAR and k in names) or (k in FORM_KEYS and k.split(".")[0] in names)
        }
        return GyroStructure(names, theta)

    def fit(self, st: Structure, scan: tuple[str, ...] = ()) -> Fitted:
        oven = self._oven(st)
        if st.has("oven_overshoot"):
            st.overshoot = oven.overshoot
        case = self._case(st)
        ctx = self._ctx(case)
        gyro = fit_structure(self._gyro_struct(st), ctx, scan=scan)
        st.theta.update(gyro.struct.theta)
        curve = nf.measured_allan(self.d, ctx.y - gyro.pred)
        q = self.d.hr.lattice_step if st.has("quantization") else 0.0
        terms = {n for n in st.effects if n in ("arw", "bias_instability", "rate_random_walk")}
        noise = nf.fit_allan(curve, self.d.hr.dt, terms, q=q, white0=self.d.hr.white_sigma)
        outl = nf.fit_outliers(self.d, self.coarse_lattice()) if st.has("outliers") else None
        # Final deterministic fit and its score with the covariance of the noise model
        # learned from this residual's own Allan curve in the bins' band (white, flicker,
        # random walk when the model has it, and a Gauss–Markov part when the data want
        # one): white and flicker noise are always there physically, whatever the starting
        # model says, and what happens faster than a bin does not enter.
        cov = nf.fit_cov_noise(curve, self.d.bin_s, rrw=st.has("rate_random_walk"))
        w = self.whitener(cov)
        if any(n in NONLINEAR for n in gyro.struct.names):
            gyro = fit_structure(gyro.struct, ctx, passes=1, whitener=w)
            st.theta.update(gyro.struct.theta)
        gyro = self.cov_fit(gyro.struct, ctx, w)
        f = Fitted(st, oven, case, gyro, ctx, noise, outl, q, {}, w, cov)
        f.gaps = self.gaps(f)
        return f

    def whitener(self, noise: nf.CovNoise) -> CovWhitener:
        """Whitener of the bins' noise covariance implied by a learned noise model."""
        r = bin_noise_autocov(
            self.d.t.size,
            self.d.bin_s,
            noise.n_white,
            noise.b_floor,
            noise.k_rrw,
            noise.gm_sigma,
            noise.gm_tau_s,
        )
        return CovWhitener(r)

    @staticmethod
    def noise_penalty(noise: nf.CovNoise) -> int:
        """Parameters of a noise model beyond white + flicker (BIC units of ln n)."""
        return int(noise.k_rrw > 0) + 2 * int(noise.gm_sigma > 0)

    @staticmethod
    def cov_fit(struct: GyroStructure, ctx: GyroContext, w: CovWhitener) -> GyroFit:
        """GLS of a structure (nonlinear parameters fixed) with a known noise covariance."""
        X, cols = design(struct, ctx)
        g = gls_cov(ctx.y, X, w, n_nonlinear(struct))
        return GyroFit(struct, g, cols, X @ g.beta)

    # --------------------------------------------------------------------- gaps
    def gaps(self, f: Fitted) -> dict[str, float]:
        d = self.d
        k = max(1, int(round(LF_WINDOW_S / d.bin_s)))
        lf = moving_average(f.resid, k)
        ratio = np.log10(f.noise.curve.adev / f.noise.model_adev())
        obs, gauss = nf.spike_counts(d)
        model_spikes = 0.0
        if f.outliers is not None:
            sp = f.outliers.sim_params(d.hr.dt)
            model_spikes = nf.expected_spike_excess(d, sp["rate_per_h"], sp["amplitude"])
        q_data = d.hr.lattice_step
        if q_data > 0:
            # a lattice that is not a quantizer of its own is the ADC's: every model has it
            q_model = f.quant_q if f.quant_q > 0 else q_data
            if f.quant_q <= 0 and self.lattice_significant():
                q_model = 0.0
            h = nf.lattice_phase_hist(d, q_data)
            hm = nf.model_phase_hist(q_data, q_model)
            tv = 0.5 * float(np.sum(np.abs(h - hm)))
        else:
            tv = 0.0
        return {
            "lf_residual_rms_dps": float(np.sqrt(np.mean(lf**2))),
            "allan_log_distance": float(np.sqrt(np.mean(ratio**2))),
            "temperature_rms_c": float(math.sqrt(0.5 * (f.oven.rms**2 + f.case.rms**2))),
            "oven_rms_c": f.oven.rms,
            "pt100_rms_c": f.case.rms,
            "spike_log_ratio": float(abs(math.log((obs + 1.0) / (gauss + model_spikes + 1.0)))),
            "lattice_tv_distance": tv,
        }

    # --------------------------------------------------------------- candidates
    def score_temperature(self, cur: Fitted) -> list[dict[str, Any]]:
        out = []
        st = cur.structure
        if not st.has("oven_overshoot"):
            cand = self.fit_oven_candidate(st)
            dbic, ne = delta_bic_channel(cur.oven.resid, cand.resid, OVEN_FLOOR_C, 2)
            gain = 1.0 - cand.rms / max(cur.oven.rms, 1e-12)
            out.append(
                {
                    "effect": "oven_overshoot",
                    "channel": "temperature",
                    "score": dbic,
                    "significant": dbic > TEMP_SIG and gain > TEMP_MIN_GAIN,
                    "evidence": {
                        "oven_rms_c": [cur.oven.rms, cand.rms],
                        "effective_n": ne,
                        "overshoot": cand.overshoot[0] if cand.overshoot else None,
                        "period_s": cand.overshoot[1] if cand.overshoot else None,
                    },
                }
            )
        if not st.has("rtd_self_heating"):
            if True not in self._case_cache:  # the same data every iteration: fit once
                self._case_cache[True] = fit_case(self.d, self.model0.thermal.case_tau_s, True)
            cand_c = self._case_cache[True]
            fl = 0.5 * self.pt_noise
            dbic, ne = delta_bic_channel(cur.case.resid, cand_c.resid, fl, 1)
            gain = 1.0 - cand_c.rms / max(cur.case.rms, 1e-12)
            out.append(
                {
                    "effect": "rtd_self_heating",
                    "channel": "temperature",
                    "score": dbic,
                    "significant": dbic > TEMP_SIG and gain > TEMP_MIN_GAIN,
                    "evidence": {
                        "pt100_rms_c": [cur.case.rms, cand_c.rms],
                        "offset_c": cand_c.offset_c,
                        "pt100_noise_c": self.pt_noise,
                        "effective_n": ne,
                        "initial_case_c": cand_c.initial_c,
                    },
                }
            )
        return out

    def fit_oven_candidate(self, st: Structure) -> OvenFit:
        tmp = st.plus("oven_overshoot")
        return self._oven(tmp)

    def score_gyro(self, cur: Fitted) -> list[dict[str, Any]]:
        """ΔBIC of each gyro term not in the model, every one judged with one noise model:
        the one learned from the residual of the *saturated* model (current terms plus
        every candidate, each at its own best shape). A missing slow term inflates the
        current residual's long-τ Allan curve, and a noise model learned from that would
        swallow the very terms being tested (two of them at once all the more); the
        saturated residual is free of them, and since the noise scale is profiled out of
        the BIC, only the learned *shape* of the spectrum matters. Unless the model has
        it, a random-walk alternative learned from the same residual competes (the better
        of the two for each model, its parameter counted): slow wander must not pass for
        a ramp or a step."""
        out = []
        ln_n = math.log(cur.ctx.y.size)
        fits, noises = self.judging_noises(cur)

        def best_bic(struct: GyroStructure) -> tuple[float, int]:
            bics = [self.cov_fit(struct, cur.ctx, w).bic + extra * ln_n for w, extra in noises]
            i = int(np.argmin(bics))
            return bics[i], i

        base_bic, base_noise = best_bic(cur.gyro.struct)
        for name, g in fits.items():
            form = "single"
            if name in ("warmup", "hysteresis"):
                g, form = widen_form(g, cur.ctx, name, lambda s: best_bic(s)[0])
            cand_bic, cand_noise = best_bic(g.struct)
            dbic = base_bic - cand_bic
            params = effect_params(g).get(name, {})
            out.append(
                {
                    "effect": name,
                    "channel": "gyro",
                    "score": float(dbic),
                    "significant": bool(dbic > GYRO_SIG),
                    "evidence": {
                        "delta_bic": float(dbic),
                        "params": params,
                        "noise_with_rrw": [bool(base_noise), bool(cand_noise)],
                        "form": form,
                    },
                    "_theta": g.struct.theta.get(name),
                    "_form": {k: v for k, v in g.struct.theta.items() if k in FORM_KEYS},
                }
            )
        return out

    def judging_noises(
        self, cur: Fitted
    ) -> tuple[dict[str, GyroFit], list[tuple[CovWhitener, int]]]:
        """Each gyro candidate fitted alone (its shape scanned), and the whiteners of the
        noise models learned from the saturated model's residual (see
        :meth:`score_gyro`), each with its parameter penalty."""
        st = cur.structure
        base_struct = self._gyro_struct(st)
        assert cur.whitener is not None
        fits: dict[str, GyroFit] = {}
        for name in GYRO_EFFECTS:
            if name in base_struct.names or name == "bias_poly":
                continue
            if name == "cubic_temp" and self.poly_order >= 3:
                continue
            s2 = GyroStructure(base_struct.names + [name], dict(cur.gyro.struct.theta))
            fits[name] = fit_structure(
                s2,
                cur.ctx,
                scan=(name,) if name in NONLINEAR else (),
                whitener=cur.whitener,
            )
        sat_names = list(base_struct.names) + [n for n in fits if n != "thermal_lag"]
        sat_theta = dict(cur.gyro.struct.theta)
        for n, g in fits.items():
            if n in NONLINEAR and n != "thermal_lag":
                sat_theta[n] = g.struct.theta[n]
        sat = self.cov_fit(GyroStructure(sat_names, sat_theta), cur.ctx, cur.whitener)
        curve = nf.measured_allan(self.d, cur.ctx.y - sat.pred)
        has_k = st.has("rate_random_walk")
        learned = [nf.fit_cov_noise(curve, self.d.bin_s, rrw=has_k)]
        if not has_k:
            learned.append(nf.fit_cov_noise(curve, self.d.bin_s, rrw=True))
        return fits, [(self.whitener(c), self.noise_penalty(c)) for c in learned]

    def own_noise_bic(self, cur: Fitted, g: GyroFit) -> float:
        """BIC of a candidate fit under the noise model learned from its own residual
        (parameters of that noise model counted as for the base models)."""
        curve = nf.measured_allan(self.d, cur.ctx.y - g.pred)
        cov = nf.fit_cov_noise(curve, self.d.bin_s, rrw=cur.structure.has("rate_random_walk"))
        w = self.whitener(cov)
        fit = self.cov_fit(g.struct, cur.ctx, w)
        return fit.bic + self.noise_penalty(cov) * math.log(cur.ctx.y.size)

    def _noise_terms(self, cur: Fitted) -> set[str]:
        return {n for n in cur.structure.effects if n in STOCHASTIC_BASE + ("rate_random_walk",)}

    def _rrw_alt(self, cur: Fitted) -> nf.CovNoise:
        """The current learned noise model with a rate random walk added."""
        return nf.fit_cov_noise(cur.noise.curve, self.d.bin_s, rrw=True)

    def score_rrw(self, cur: Fitted) -> list[dict[str, Any]]:
        """Allan-curve terms missing from the model: χ² drop when each is added."""
        out = []
        d = self.d
        have = self._noise_terms(cur)
        for name in STOCHASTIC_BASE + ("rate_random_walk",):
            if name in have:
                continue
            alt = nf.fit_allan(
                cur.noise.curve, d.hr.dt, have | {name}, cur.quant_q, d.hr.white_sigma
            )
            dchi = cur.noise.chi2 - alt.chi2
            out.append(
                {
                    "effect": name,
                    "channel": "noise",
                    "score": float(dchi),
                    "significant": bool(dchi > nf.RRW_CHI2),
                    "evidence": {
                        "allan_chi2": [cur.noise.chi2, alt.chi2],
                        "params": alt.sim_params()[name],
                    },
                }
            )
        return out

    def lattice_significant(self, q: float | None = None) -> bool:
        """Whether the output's lattice (measured from its values or first differences)
        is a quantizer of its own: on most differences, at least
        :data:`~.noise_fit.LATTICE_RATIO` ADC LSBs, and at least
        :data:`~.noise_fit.LATTICE_NOISE_RATIO` of the sample noise. The second rule
        needs no assumed ADC: a lattice fine against the noise is the ADC's."""
        hr = self.d.hr
        q = hr.lattice_step if q is None else q
        return (
            hr.lattice_fraction > nf.LATTICE_FRACTION
            and q >= nf.LATTICE_RATIO * self.lsb
            and q >= nf.LATTICE_NOISE_RATIO * hr.white_sigma
        )

    def coarse_lattice(self) -> float:
        """The output's lattice step when it is a quantizer of its own, else 0."""
        return self.d.hr.lattice_step if self.lattice_significant() else 0.0

    def score_sample(self, cur: Fitted) -> list[dict[str, Any]]:
        """Sample-level effects, read off the full-rate stream (independent of the fits)."""
        out = []
        st = cur.structure
        d = self.d
        if not st.has("outliers"):
            o = nf.fit_outliers(d, self.coarse_lattice())
            obs, gauss = nf.spike_counts(d)
            out.append(
                {
                    "effect": "outliers",
                    "channel": "noise",
                    "score": float(o.lr),
                    "significant": bool(o.lr > nf.OUTLIER_LR and o.amplitude > 4.0 * o.sigma),
                    "evidence": {
                        "likelihood_ratio": o.lr,
                        "exceedances_5sigma": obs,
                        "gaussian_expectation_5sigma": gauss,
                        **o.sim_params(d.hr.dt),
                    },
                }
            )
        if not st.has("quantization"):
            q, frac = d.hr.lattice_step, d.hr.lattice_fraction
            sig = self.lattice_significant()
            out.append(
                {
                    "effect": "quantization",
                    "channel": "noise",
                    "score": float(1e3 * frac if sig else 0.0),
                    "significant": bool(sig),
                    "evidence": {
                        "lattice_step_dps": q,
                        "adc_lsb_dps": self.lsb,
                        "white_sigma_dps": d.hr.white_sigma,
                        "fraction_on_lattice": frac,
                    },
                }
            )
        return out

    # --------------------------------------------------------------- localize
    def localize(self, f: Fitted) -> dict[str, Any]:
        d = self.d
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

    # ----------------------------------------------------------------- the loop
    def run(self, log: Any = None) -> Result:
        t_start = time.perf_counter()
        names0 = self.model0.effect_names()
        st = Structure(
            [n for n in names0 if n != "thermal_lag"]
            + (["thermal_lag"] if "thermal_lag" in names0 else [])
        )
        for n in NONLINEAR:
            spec = self.model0.get(n)
            if spec is not None:
                st.theta[n] = float(spec.params[{"periodic": "period_s"}.get(n, NONLINEAR[n])])
        wu = self.model0.get("warmup")
        if wu is not None and wu.params.get("A2", 0.0) != 0.0:
            st.theta[WARMUP2] = float(wu.params["tau2_s"])
        hy = self.model0.get("hysteresis")
        if hy is not None and hy.params.get("width_tc", 0.0) != 0.0:
            st.theta[HYST_TC] = float(hy.params["width_tc"])
        ovs = self.model0.get("oven_overshoot")
        if ovs is not None:
            st.overshoot = (ovs.params["overshoot"], ovs.params["period_s"])
        cur = self.fit(st)
        first = cur
        found: list[str] = []
        ambiguous: list[list[str]] = []
        steps: list[dict[str, Any]] = []
        for it in range(MAX_ITER):
            cands: list[dict[str, Any]] = []
            accepted: tuple[dict[str, Any], list[str], Fitted] | None = None
            rejected: list[dict[str, Any]] = []
            for scorer in (
                self.score_sample,
                self.score_temperature,
                self.score_gyro,
                self.score_rrw,
            ):
                cs = scorer(cur)
                cands += cs
                sig = sorted([c for c in cs if c["significant"]], key=lambda c: -c["score"])
                # the best significant candidate whose own gap metric shrinks when added
                # (issue 18: an effect is judged by the gap that belongs to it)
                while sig and accepted is None:
                    best, amb = select(sig)
                    new = cur.structure.plus(best["effect"])
                    if best.get("_theta") is not None:
                        new.theta[best["effect"]] = float(best["_theta"])
                    new.theta.update(best.get("_form") or {})
                    nxt = self.fit(new)
                    key = PRIMARY_GAP.get(best["effect"], "lf_residual_rms_dps")
                    if nxt.gaps[key] < cur.gaps[key]:
                        accepted = (best, amb, nxt)
                    else:
                        rejected.append(
                            {
                                "effect": best["effect"],
                                "gap_metric": key,
                                "gap_metric_before_after": [cur.gaps[key], nxt.gaps[key]],
                            }
                        )
                        sig = [c for c in sig if c is not best]
                if accepted is not None:
                    break
            entry: dict[str, Any] = {
                "iteration": it,
                "model_effects": list(cur.structure.effects),
                "gap": dict(cur.gaps),
                "localize": self.localize(cur),
                "candidates": [
                    {k: v for k, v in c.items() if not k.startswith("_")} for c in cands
                ],
            }
            if rejected:
                entry["rejected_gap_grew"] = rejected
            if accepted is None:
                entry["added"] = None
                steps.append(entry)
                break
            best, amb, nxt = accepted
            key = PRIMARY_GAP.get(best["effect"], "lf_residual_rms_dps")
            entry["added"] = best["effect"]
            entry["ambiguous_with"] = [a for a in amb[1:] if a not in rejected_names(rejected)]
            entry["gap_metric"] = key
            entry["gap_metric_before_after"] = [cur.gaps[key], nxt.gaps[key]]
            found.append(best["effect"])
            amb = [best["effect"]] + entry["ambiguous_with"]
            if len(amb) > 1:
                ambiguous.append(amb)
            if log:
                log(
                    f"iteration {it + 1}: added {best['effect']}"
                    + (f" (ambiguous: {amb})" if len(amb) > 1 else "")
                )
            cur = nxt
            # revisit earlier choices: drop-one and swap moves among the gyro terms
            revised = self.revisit(cur, found, best["effect"])
            if revised is not None:
                cur, moves = revised
                entry["revisions"] = moves
                for mv in moves:
                    if mv["move"] == "drop":
                        found.remove(mv["effect"])
                    else:
                        found[found.index(mv["effect"])] = mv["to"]
                    ambiguous = [s for s in ambiguous if mv["effect"] not in s]
                    if log:
                        log(f"iteration {it + 1}: revised {mv}")
            steps.append(entry)
        model = self.updated_model(cur)
        from gyrolab.sim.discrepancy.limits import detection_limits

        limits = detection_limits(self, cur)
        return Result(
            effects_found=found,
            ambiguous=ambiguous,
            gap_before=first.gaps,
            gap_after=cur.gaps,
            steps=steps,
            model=model,
            first=first,
            final=cur,
            detection_limits=limits,
            elapsed_s=time.perf_counter() - t_start,
        )

    # ------------------------------------------------------------- revisiting
    def _struct_bic(self, cur: Fitted, names: list[str], scan: tuple[str, ...]) -> tuple:
        """BIC of a gyro structure under the current learned noise model."""
        assert cur.whitener is not None
        theta = {k: v for k, v in cur.gyro.struct.theta.items() if k.split(".")[0] in names}
        g = fit_structure(GyroStructure(names, theta), cur.ctx, scan=scan, whitener=cur.whitener)
        return self.cov_fit(g.struct, cur.ctx, cur.whitener).bic, g.struct.theta

    def revisit(
        self, cur: Fitted, found: list[str], newest: str
    ) -> tuple[Fitted, list[dict[str, Any]]] | None:
        """After an addition, test each earlier-added gyro term: **drop** it when the model
        without it is within :data:`GYRO_SIG` of the model with it (the newer terms explain
        what it did), **swap** it for another gyro term not in the model when that scores
        better by more than :data:`GYRO_SIG`. One move (the best) per call; the refit
        model and the moves, or None."""
        earlier = [e for e in found if e in GYRO_EFFECTS and e != newest]
        if not earlier:
            return None
        names = self._gyro_struct(cur.structure).names
        bic_now = self.cov_fit(cur.gyro.struct, cur.ctx, cur.whitener).bic  # type: ignore[arg-type]
        best_move: tuple[float, dict[str, Any], list[str], dict[str, float]] | None = None
        for e in earlier:
            without = [n for n in names if n != e]
            b_drop, th = self._struct_bic(cur, without, ())
            if b_drop - bic_now < GYRO_SIG:
                gain = GYRO_SIG - (b_drop - bic_now)
                if best_move is None or gain > best_move[0]:
                    best_move = (gain, {"move": "drop", "effect": e}, without, th)
            for c in GYRO_EFFECTS:
                if c in names or c == "bias_poly":
                    continue
                if c == "cubic_temp" and self.poly_order >= 3:
                    continue
                swapped = [n if n != e else c for n in names]
                b_sw, th = self._struct_bic(cur, swapped, (c,) if c in NONLINEAR else ())
                gain = bic_now - b_sw - GYRO_SIG
                if gain > 0 and (best_move is None or gain > best_move[0]):
                    best_move = (gain, {"move": "swap", "effect": e, "to": c}, swapped, th)
        if best_move is None:
            return None
        _, mv, new_names, th = best_move
        effects = [n for n in cur.structure.effects if n not in GYRO_EFFECTS or n in new_names]
        effects += [n for n in new_names if n not in effects and n != "bias_poly"]
        st = Structure(effects, {**cur.structure.theta, **th}, cur.structure.overshoot)
        for k in list(st.theta):
            if k.split(".")[0] == mv["effect"]:
                st.theta.pop(k)
        return self.fit(st), [mv]

    # ------------------------------------------------------------- the model
    def updated_model(self, f: Fitted) -> SimModel:
        m0 = self.model0
        th = dict(m0.thermal.to_dict())
        th.update(f.oven.params)
        tau, dself = f.case.tau_s, f.case.self_heating_c
        p = th["gyro_power_w"]
        if dself > 1e-6 and p > 0:
            r = dself / p
        else:
            th["gyro_power_w"] = 0.0
            r = th["case_resistance_k_per_w"]
        th["case_resistance_k_per_w"] = r
        th["case_capacity_j_per_k"] = tau / r
        params: dict[str, dict[str, float]] = effect_params(f.gyro)
        params.update({k: v for k, v in f.noise.sim_params().items() if k in f.structure.effects})
        if f.outliers is not None:
            params["outliers"] = f.outliers.sim_params(self.d.hr.dt)
        if f.structure.has("quantization") and self.d.hr.lattice_step > 0:
            params["quantization"] = {"q": self.d.hr.lattice_step}
        if f.oven.overshoot is not None:
            params["oven_overshoot"] = {
                "overshoot": f.oven.overshoot[0],
                "period_s": f.oven.overshoot[1],
            }
        if f.structure.has("rtd_self_heating"):
            params["rtd_self_heating"] = {"offset_c": f.case.offset_c}
        order = [n for n in m0.effect_names()] + [
            n for n in f.structure.effects if n not in m0.effect_names()
        ]
        if "bias_poly" not in order:
            order.insert(0, "bias_poly")
        specs = []
        for n in order:
            base = m0.get(n).params if m0.get(n) is not None else {}
            specs.append(make_effect_spec(n, {**base, **params.get(n, {})}))
        return SimModel(thermal=ThermalParams(**th), sensors=m0.sensors, effects=tuple(specs))


def rejected_names(rejected: list[dict[str, Any]]) -> set[str]:
    return {r["effect"] for r in rejected}


def select(significant: list[dict[str, Any]]) -> tuple[dict[str, Any], list[str]]:
    """The best of one channel's significant candidates, and the set it cannot be told
    apart from: every candidate within :data:`AMBIGUITY_MARGIN` of the best score (best
    first, at most three)."""
    ranked = sorted(significant, key=lambda c: -c["score"])
    best = ranked[0]
    amb = [best["effect"]] + [
        c["effect"] for c in ranked[1:] if best["score"] - c["score"] < AMBIGUITY_MARGIN
    ]
    return best, amb[:3]


@dataclass
class Result:
    """Outcome of a discrepancy analysis (docs/cli.md ``discrepancy.json`` contract)."""

    effects_found: list[str]
    ambiguous: list[list[str]]
    gap_before: dict[str, float]
    gap_after: dict[str, float]
    steps: list[dict[str, Any]]
    model: SimModel
    first: Fitted
    final: Fitted
    detection_limits: dict[str, dict[str, Any]]
    elapsed_s: float

    def to_json(self) -> dict[str, Any]:
        return {
            "effects_found": self.effects_found,
            "ambiguous": self.ambiguous,
            "gap_before": self.gap_before,
            "gap_after": self.gap_after,
            "steps": self.steps,
            "detection_limits": self.detection_limits,
            "chamber_cooling": {"form": self.final.oven.form, "smooth": self.final.oven.smooth},
            "elapsed_s": self.elapsed_s,
        }


def run_discrepancy(data: BenchData, model: SimModel | None = None, log: Any = None) -> Result:
    """Analyse ``data`` against ``model`` (default: the simulator's nominal model)."""
    from gyrolab.sim.model import nominal_model

    return Workflow(data, model or nominal_model()).run(log)
