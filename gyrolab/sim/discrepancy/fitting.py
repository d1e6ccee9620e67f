"""Fit one model structure to a recording: the thermal chain, the deterministic gyro terms,
the noise terms, and the gap metrics that compare the result with the measurement
(docs/discrepancy.md, "Pipeline" and "Gap metrics").

:class:`Fitter` knows nothing of candidates or selection: the channels
(:mod:`.channels`) score what a structure lacks, the workflow chooses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from gyrolab.sim.discrepancy import catalogue as cat
from gyrolab.sim.discrepancy import noise_fit as nf
from gyrolab.sim.discrepancy.data import BenchData
from gyrolab.sim.discrepancy.gls import CovWhitener, bin_noise_autocov, gls_cov
from gyrolab.sim.discrepancy.gyro_fit import (
    GyroContext,
    GyroFit,
    GyroStructure,
    design,
    fit_structure,
    n_nonlinear,
)
from gyrolab.sim.discrepancy.thermal_fit import (
    CaseFit,
    OvenFit,
    fit_case,
    fit_oven,
    pt100_noise_c,
)
from gyrolab.sim.model import SimModel, make_effect_spec
from gyrolab.sim.thermal import ThermalParams

LF_WINDOW_S = 100.0
"""Moving-average window of the low-frequency residual (0.01 Hz)."""


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
    memo: dict[str, Any] = field(default_factory=dict)
    """What the channels computed on this fit and use again (scores, then limits)."""

    @property
    def resid(self) -> np.ndarray:
        return self.ctx.y - self.gyro.pred


def poly_order(model: SimModel) -> int:
    """Order of the starting model's temperature polynomial (2, or 3–4 when it uses them)."""
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


class ThermalFits:
    """The chamber-air and case fits of one bench, each fitted once per variant: every
    iteration, and every gyro axis of a recording (one chamber, one case sensor), shares
    them."""

    def __init__(self, data: BenchData, thermal: ThermalParams) -> None:
        self.d = data
        self.thermal = thermal
        self._oven: dict[Any, OvenFit] = {}
        self._case: dict[bool, CaseFit] = {}

    def oven(self, overshoot: bool, start: tuple[float, float] | None = None) -> OvenFit:
        """First-order chamber, or second order (``oven_overshoot``) started at ``start``
        (overshoot, period) and from the first-order fit."""
        key = ("os", start) if overshoot else "first"
        if key not in self._oven:
            th = self.thermal
            if overshoot:
                base = self._oven.get("first") or fit_oven(self.d, th)
                th = replace(th, **base.params)
                self._oven[key] = fit_oven(self.d, th, start, True, form=base.form, x_start=base.x)
            else:
                self._oven[key] = fit_oven(self.d, th)
        return self._oven[key]

    def case(self, offset: bool) -> CaseFit:
        """The case model, with or without the PT100 offset (``rtd_self_heating``)."""
        if offset not in self._case:
            self._case[offset] = fit_case(self.d, self.thermal.case_tau_s, offset)
        return self._case[offset]


class Fitter:
    """Fits structures of one recording against a starting model's thermal and sensor
    parameters (module docstring)."""

    def __init__(self, data: BenchData, model: SimModel, thermal: ThermalFits | None = None):
        self.d = data
        self.model0 = model
        self.pt_noise = max(pt100_noise_c(data), 1e-4)
        self.lsb = model.sensors.adc.lsb_dps
        self.poly_order = poly_order(model)
        self.thermal = thermal or ThermalFits(data, model.thermal)

    def context(self, case: CaseFit) -> GyroContext:
        """The gyro terms' context: the measured case temperature (a PT100's reading less
        the model's self-heating, or a die sensor's carried back to the case) and the case
        model's rate on the 1 s grid."""
        d = self.d
        meas = case.measured_case(d)
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

    def gyro_struct(self, st: Structure) -> GyroStructure:
        """The gyro terms of a structure (``bias_poly`` always) and their shape values."""
        names = [n for n in st.effects if cat.is_gyro_term(n)]
        if "bias_poly" not in names:
            names = ["bias_poly"] + names
        theta = {k: v for k, v in st.theta.items() if self._theta_in(k, names)}
        return GyroStructure(names, theta)

    @staticmethod
    def _theta_in(key: str, names: list[str]) -> bool:
        owner = cat.theta_owner(key)
        if owner not in names:
            return False
        return (key == owner and cat.shape_of(owner) is not None) or key == cat.form_key(owner)

    def noise_terms(self, st: Structure) -> set[str]:
        """The Allan-curve terms (noise channel) a structure has."""
        return {n for n in st.effects if n in cat.on_channel("noise")}

    def fit(self, st: Structure, scan: tuple[str, ...] = ()) -> Fitted:
        oven = self.thermal.oven(st.has("oven_overshoot"), st.overshoot)
        if st.has("oven_overshoot"):
            st.overshoot = oven.overshoot
        case = self.thermal.case(st.has("rtd_self_heating"))
        ctx = self.context(case)
        gyro = fit_structure(self.gyro_struct(st), ctx, scan=scan)
        st.theta.update(gyro.struct.theta)
        curve = nf.measured_allan(self.d, ctx.y - gyro.pred)
        q = self.d.hr.lattice_step if st.has("quantization") else 0.0
        terms = self.noise_terms(st)
        noise = nf.fit_allan(curve, self.d.hr.dt, terms, q=q, white0=self.d.hr.white_sigma)
        outl = nf.fit_outliers(self.d, self.coarse_lattice()) if st.has("outliers") else None
        # Final deterministic fit and its score with the covariance of the noise model
        # learned from this residual's own Allan curve in the bins' band (white, flicker,
        # random walk when the model has it, and a Gauss–Markov part when the data want
        # one): white and flicker noise are always there physically, whatever the starting
        # model says, and what happens faster than a bin does not enter.
        cov = nf.fit_cov_noise(curve, self.d.bin_s, rrw=st.has("rate_random_walk"))
        w = self.whitener(cov)
        if any(cat.shape_of(n) for n in gyro.struct.names):
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

    # --------------------------------------------------------------------- gaps
    def gaps(self, f: Fitted) -> dict[str, float]:
        """The gap metrics of a fit (docs/discrepancy.md, "Gap metrics")."""
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

    # ------------------------------------------------------------- the model
    def updated_model(self, f: Fitted, params: dict[str, dict[str, float]]) -> SimModel:
        """The starting model with the fitted thermal chain and every effect of ``f``'s
        structure at ``params`` (its channels' fitted simulator parameters)."""
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
        if f.case.die_tau_s is not None:  # measured through a die sensor
            th["die_tau_s"] = f.case.die_tau_s
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
