"""The gyro error model: named, parametric effects (the vocabulary of docs/sim-model.md).

Each effect is a class with a ``name`` from the vocabulary, a parameter table ``PARAMS``
(default, unit, meaning, constraint) and a ``target``:

- ``rate``: adds a term (°/s) to the gyro output — :meth:`Effect.rate`;
- ``post``: transforms the summed output (``quantization``) — :meth:`Effect.post`;
- ``thermal``/``air``/``pt100``: changes the thermal model or the PT100 reading
  (``thermal_lag``, ``oven_overshoot``, ``rtd_self_heating``), read by
  :class:`gyrolab.sim.physics.Physics`.

Beside its physics each effect declares how the discrepancy workflow looks for it
(``candidate``: channel, gap metric, detection-limit parameter) and, for a deterministic
gyro term, its fit terms (``terms``: regressors, shape parameter and its scan grid, wider
form) — :mod:`gyrolab.sim.candidate`; a new gyro term is one class here.

``T`` is the bias-setting temperature: the gyro case, or the die when ``thermal_lag`` is in
the model; ``t`` is seconds since power-on. Deterministic effects are functions of the
temperature history and time; stochastic ones draw from the private generator they are
given (see :func:`gyrolab.sim.noise.effect_rng`). All effects keep their state between
blocks, so the output never depends on how a run is cut into blocks. Equations and units:
docs/sim-model.md, and each class's docstring.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from gyrolab.numerics.play import play, play_var
from gyrolab.pt100 import R0_OHM, cvd_resistance
from gyrolab.sim.candidate import (
    GAP_ALLAN,
    GAP_LATTICE,
    GAP_LF,
    GAP_SPIKES,
    GAP_TEMPERATURE,
    Bins,
    Candidate,
    GyroTerms,
    WiderForm,
)
from gyrolab.sim.noise import FlickerStream
from gyrolab.sim.thermal import lowpass


@dataclass
class BlockContext:
    """What a block of ``n`` ADC samples looks like to the effects."""

    first_index: int
    dt: float
    t: np.ndarray  # s since power-on, per sample
    temp_c: np.ndarray  # bias-setting temperature T, °C
    dtemp_c_per_s: np.ndarray  # dT/dt, °C/s

    @property
    def n(self) -> int:
        return int(self.t.size)


@dataclass(frozen=True)
class Param:
    """One effect parameter: default value, unit, meaning, constraint."""

    default: float
    unit: str
    doc: str
    check: str = "any"  # any | pos | nonneg | frac (0 < x < 1)

    def validate(self, effect: str, name: str, value: object) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{effect}.{name} must be a number, got {value!r}")
        v = float(value)
        if not math.isfinite(v):
            raise ValueError(f"{effect}.{name} must be finite")
        bad = {
            "pos": not v > 0,
            "nonneg": not v >= 0,
            "frac": not 0 < v < 1,
        }.get(self.check, False)
        if bad:
            rule = {"pos": "> 0", "nonneg": ">= 0", "frac": "strictly between 0 and 1"}
            raise ValueError(f"{effect}.{name} must be {rule[self.check]}, got {v}")
        return v


class Effect:
    """Base class: an effect instance with validated parameters."""

    name: ClassVar[str] = ""
    target: ClassVar[str] = "rate"
    stochastic: ClassVar[bool] = False
    PARAMS: ClassVar[dict[str, Param]] = {}
    candidate: ClassVar[Candidate | None] = None
    """How the discrepancy workflow looks for it (None: never a candidate)."""
    terms: ClassVar[GyroTerms | None] = None
    """Its fit terms when it is a deterministic gyro term."""

    @classmethod
    def is_noise(cls) -> bool:
        """Part of the noise floor rather than the drift: a stochastic effect, or a
        transform of the summed output (``quantization``: the output's steps)."""
        return cls.stochastic or cls.target == "post"

    def __init__(
        self, params: dict[str, float], rng: np.random.Generator | None, rate_hz: float
    ) -> None:
        self.p = dict(params)
        self.rng = rng
        self.rate_hz = float(rate_hz)

    def rate(self, ctx: BlockContext) -> np.ndarray:
        """Additive output term (°/s) for the block."""
        return np.zeros(ctx.n)

    def post(self, out: np.ndarray, ctx: BlockContext) -> np.ndarray:
        """Transform of the summed output (only ``target == "post"`` effects)."""
        return out


def self_heating_c(offset_c: float, temp_c: float | np.ndarray) -> float | np.ndarray:
    """``rtd_self_heating``'s error at ``temp_c`` (°C): ``offset_c · R(T)/R0``."""
    return offset_c * cvd_resistance(temp_c) / R0_OHM


EFFECTS: dict[str, type[Effect]] = {}
"""The vocabulary: every effect class by name, in the order they were registered."""


def register(cls: type[Effect]) -> type[Effect]:
    """Add an effect class to the vocabulary (a class decorator). Its name is then known to
    ``SIM_MODEL.toml``, the simulator and, through its ``candidate``, the discrepancy
    workflow (docs/sim-model.md, "Adding an effect")."""
    if not cls.name or cls.name in EFFECTS:
        raise ValueError(f"effect name {cls.name!r} is empty or taken")
    EFFECTS[cls.name] = cls
    return cls


def _tpow(ctx: BlockContext, t_ref: float) -> np.ndarray:
    return ctx.temp_c - t_ref


@register
class BiasPoly(Effect):
    """``bias = Σ_i c_i (T − T_ref)^i`` (°/s), order 2 by default (c3, c4 default 0)."""

    name = "bias_poly"
    PARAMS = {
        "c0": Param(0.02, "deg/s", "bias at T_ref"),
        "c1": Param(3.84e-4, "deg/s/degC", "linear coefficient"),
        "c2": Param(3.4e-6, "deg/s/degC^2", "quadratic coefficient"),
        "c3": Param(0.0, "deg/s/degC^3", "cubic coefficient"),
        "c4": Param(0.0, "deg/s/degC^4", "quartic coefficient"),
        "t_ref_c": Param(25.0, "degC", "reference temperature T_ref"),
    }
    terms = GyroTerms(
        columns=lambda b, s: [(f"c{i}", (b.temp_c - 25.0) ** i) for i in range(b.poly_order + 1)],
        fixed={"t_ref_c": 25.0},
    )

    def rate(self, ctx: BlockContext) -> np.ndarray:
        x = _tpow(ctx, self.p["t_ref_c"])
        c = [self.p[f"c{i}"] for i in range(5)]
        top = max([i for i in range(5) if c[i] != 0.0], default=0)
        y = np.full(ctx.n, c[top])
        for i in range(top - 1, -1, -1):  # Horner, skipping the zero high orders
            y *= x
            y += c[i]
        return y


@register
class CubicTemp(Effect):
    """``bias += c3 (T − T_ref)³`` (°/s)."""

    name = "cubic_temp"
    PARAMS = {
        "c3": Param(2.0e-8, "deg/s/degC^3", "cubic coefficient"),
        "t_ref_c": Param(25.0, "degC", "reference temperature T_ref"),
    }
    candidate = Candidate("gyro", GAP_LF, "c3")
    terms = GyroTerms(
        columns=lambda b, s: [("c3", (b.temp_c - 25.0) ** 3)], fixed={"t_ref_c": 25.0}
    )

    def rate(self, ctx: BlockContext) -> np.ndarray:
        return self.p["c3"] * _tpow(ctx, self.p["t_ref_c"]) ** 3


@register
class ThermalRate(Effect):
    """``bias += k · dT/dt`` (°/s; dT/dt in °C/min): the thermal-gradient sensitivity."""

    name = "thermal_rate"
    PARAMS = {"k": Param(2.0e-3, "deg/s per degC/min", "temperature-rate sensitivity")}
    candidate = Candidate("gyro", GAP_LF, "k")
    terms = GyroTerms(columns=lambda b, s: [("k", 60.0 * b.dtemp_c_per_s)])

    def rate(self, ctx: BlockContext) -> np.ndarray:
        return self.p["k"] * 60.0 * ctx.dtemp_c_per_s


@register
class ThermalLag(Effect):
    """The die that sets the bias lags the case sensor: ``τ dTd/dt = Tc − Td``.

    With this effect every temperature-driven effect sees ``Td`` instead of ``Tc``.
    """

    name = "thermal_lag"
    target = "thermal"
    PARAMS = {"tau_s": Param(900.0, "s", "die time constant behind the case", "pos")}
    candidate = Candidate("gyro", GAP_LF, "tau_s")
    terms = GyroTerms(
        shape="tau_s",
        grid=lambda dur, bin_s: np.geomspace(20.0, max(200.0, dur / 3), 36),
        temperature=lambda case, s: _die(case, s["tau_s"]),
    )


def _die(case_c: np.ndarray, tau_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The die behind a case temperature on a 1 s grid, ``τ dTd/dt = Tc − Td`` (starting at
    the case), and its rate (°C, °C/s)."""
    die = lowpass(case_c, 1.0 - math.exp(-1.0 / tau_s), float(case_c[0]))
    return die, (case_c - die) / tau_s


HYST_MIN_WIDTH_C = 0.01
"""Floor of a temperature-dependent hysteresis width, °C."""


def hysteresis_width(temp: np.ndarray, width_c: float, width_tc: float) -> np.ndarray:
    """``w(T) = max(w_min, width_c + width_tc · (T − 25 °C))`` (°C)."""
    return np.maximum(HYST_MIN_WIDTH_C, width_c + width_tc * (np.asarray(temp) - 25.0))


def _branch(b: Bins, s: dict[str, float]) -> list[tuple[str, np.ndarray]]:
    """Hysteresis regressor: ``s/2`` of the play operator run on the 1 s grid (its
    history), at the bin centres."""
    g = b.grid_temp_c
    out = np.empty(g.size)
    if s["width_tc"] == 0.0:
        play(g, float(g[0]), 0.5 * s["width_c"], out)
    else:
        half = 0.5 * hysteresis_width(g, s["width_c"], s["width_tc"])
        play_var(np.ascontiguousarray(g, dtype=np.float64), float(g[0]), half, out)
    return [("h", 0.5 * np.interp(b.t, b.grid_t, out))]


@register
class Hysteresis(Effect):
    """``bias += (h/2) · s``, ``s = (T − p)/(w/2)`` with ``p`` the play operator of width w.

    ``p`` follows T with a backlash of ±w/2, so after any monotone excursion longer than
    ``w`` the bias sits at +h/2 while T rises and −h/2 while it falls (°/s). The width may
    depend on temperature, ``w(T) = width_c + width_tc·(T − 25 °C)`` (floored at 0.01 °C;
    ``width_tc`` = 0, the default, is the constant width).
    """

    name = "hysteresis"
    PARAMS = {
        "h": Param(2.0e-3, "deg/s", "full bias difference heating vs cooling"),
        "width_c": Param(
            1.0, "degC", "temperature reversal that flips the branch (at 25 °C)", "pos"
        ),
        "width_tc": Param(0.0, "degC/degC", "change of the width per °C from 25 °C"),
    }
    candidate = Candidate("gyro", GAP_LF, "h", {"width_c": 1.0})
    terms = GyroTerms(
        columns=_branch,
        shape="width_c",
        grid=lambda dur, bin_s: np.geomspace(0.05, 20.0, 30),
        wider=WiderForm(
            "slope",
            "width_tc",
            "width_tc",
            "temperature-dependent width",
            neutral=0.0,
            tries=(-0.02, -0.01, -0.005, 0.005, 0.01, 0.02),
        ),
    )

    def __init__(
        self, params: dict[str, float], rng: np.random.Generator | None, rate_hz: float
    ) -> None:
        super().__init__(params, rng, rate_hz)
        self._p: float | None = None

    def rate(self, ctx: BlockContext) -> np.ndarray:
        if self._p is None:
            self._p = float(ctx.temp_c[0]) if ctx.n else 0.0
        s = np.empty(ctx.n)
        if self.p["width_tc"] == 0.0:
            self._p = play(ctx.temp_c, self._p, 0.5 * self.p["width_c"], s)
        else:
            half = 0.5 * hysteresis_width(ctx.temp_c, self.p["width_c"], self.p["width_tc"])
            self._p = play_var(np.ascontiguousarray(ctx.temp_c, dtype=np.float64), self._p, half, s)
        return 0.5 * self.p["h"] * s


@register
class Warmup(Effect):
    """``bias += A · exp(−t/τw) + A2 · exp(−t/τ2)`` (°/s) after power-on: one or two
    exponentials (opposite signs allowed: a fast rise inside a slow settling). ``A2`` = 0,
    the default, is the single exponential."""

    name = "warmup"
    PARAMS = {
        "A": Param(5.0e-3, "deg/s", "warm-up amplitude at power-on"),
        "tau_s": Param(600.0, "s", "warm-up time constant", "pos"),
        "A2": Param(0.0, "deg/s", "second exponential's amplitude"),
        "tau2_s": Param(600.0, "s", "second exponential's time constant", "pos"),
    }
    candidate = Candidate("gyro", GAP_LF, "A", {"tau_s": 600.0})
    terms = GyroTerms(
        columns=lambda b, s: (
            [("A", np.exp(-b.t / s["tau_s"]))]
            + ([("A2", np.exp(-b.t / s["tau2_s"]))] if "tau2_s" in s else [])
        ),
        shape="tau_s",
        # a warm-up settles within the run; slower drifts are aging_ramp's business
        grid=lambda dur, bin_s: np.geomspace(max(30.0, 3 * bin_s), max(300.0, dur / 6), 40),
        wider=WiderForm("second", "tau2_s", "A2", "two exponentials"),
    )

    def rate(self, ctx: BlockContext) -> np.ndarray:
        y = self.p["A"] * np.exp(-ctx.t / self.p["tau_s"])
        if self.p["A2"] != 0.0:
            y = y + self.p["A2"] * np.exp(-ctx.t / self.p["tau2_s"])
        return y


@register
class AgingRamp(Effect):
    """``bias += r · t`` with r in °/s per hour (t in h): a rate ramp."""

    name = "aging_ramp"
    PARAMS = {"r": Param(5.0e-4, "deg/s/h", "bias ramp")}
    candidate = Candidate("gyro", GAP_LF, "r")
    terms = GyroTerms(columns=lambda b, s: [("r", b.t / 3600.0)])

    def rate(self, ctx: BlockContext) -> np.ndarray:
        return self.p["r"] * (ctx.t / 3600.0)


@register
class Periodic(Effect):
    """``bias += A · sin(2π t / P + φ)`` (°/s), e.g. chamber compressor cycling."""

    name = "periodic"
    PARAMS = {
        "A": Param(1.0e-3, "deg/s", "amplitude"),
        "period_s": Param(900.0, "s", "period P", "pos"),
        "phase_rad": Param(0.0, "rad", "phase at power-on"),
    }
    candidate = Candidate("gyro", GAP_LF, "A", {"period_s": 900.0})
    terms = GyroTerms(
        columns=lambda b, s: [
            ("a_sin", np.sin(2.0 * np.pi / s["period_s"] * b.t)),
            ("a_cos", np.cos(2.0 * np.pi / s["period_s"] * b.t)),
        ],
        shape="period_s",
        grid=lambda dur, bin_s: _period_grid(dur, bin_s),
        scan="frequency",
        derive=lambda v: {
            "A": float(math.hypot(v["a_sin"], v["a_cos"])),
            "phase_rad": float(math.atan2(v["a_cos"], v["a_sin"])),
        },
    )

    def rate(self, ctx: BlockContext) -> np.ndarray:
        return self.p["A"] * np.sin(2.0 * np.pi * ctx.t / self.p["period_s"] + self.p["phase_rad"])


def _period_grid(duration_s: float, bin_s: float) -> np.ndarray:
    """Periods of compressor-like cycles, minutes to two hours and at least six per run,
    uniform in frequency and 2× oversampled against the run's resolution 1/T."""
    f_lo = max(1.0 / 7200.0, 6.0 / duration_s)
    f_hi = 1.0 / max(120.0, 4.0 * bin_s)
    nf = int(min(2000, max(20, 2 * (f_hi - f_lo) * duration_s)))
    return 1.0 / np.linspace(f_lo, f_hi, nf)


@register
class Arw(Effect):
    """White rate noise of density N (°/√h): per-sample σ = (N/60) · √f_s (°/s).

    Allan deviation ``σ(τ) = (N/60)/√τ`` °/s (IEEE 952 angle random walk, −½ line).
    """

    name = "arw"
    stochastic = True
    candidate = Candidate("noise", GAP_ALLAN)
    PARAMS = {"N": Param(0.0523, "deg/sqrt(h)", "angle random walk coefficient", "nonneg")}

    def rate(self, ctx: BlockContext) -> np.ndarray:
        sigma = self.p["N"] / 60.0 * math.sqrt(self.rate_hz)
        return sigma * self.rng.standard_normal(ctx.n)  # type: ignore[union-attr]


@register
class BiasInstability(Effect):
    """Flicker (1/f) rate noise whose Allan deviation floor is B (°/h).

    One-sided PSD ``S(f) = B² / (2 ln 2 · f)`` (°/s)²/Hz with B in °/s, so that
    ``σ_Allan = B`` on the flat part. (IEEE 952's coefficient is B/0.664.) Generated by
    Kasdin's fractional-difference filter at 10 Hz and interpolated: see
    :class:`gyrolab.sim.noise.FlickerStream`.
    """

    name = "bias_instability"
    stochastic = True
    candidate = Candidate("noise", GAP_ALLAN)
    PARAMS = {"B": Param(0.25, "deg/h", "Allan deviation floor", "nonneg")}

    def __init__(
        self, params: dict[str, float], rng: np.random.Generator | None, rate_hz: float
    ) -> None:
        super().__init__(params, rng, rate_hz)
        self._fl = FlickerStream(self.p["B"] / 3600.0, self.rng)  # type: ignore[arg-type]

    def rate(self, ctx: BlockContext) -> np.ndarray:
        return self._fl.value_at(ctx.first_index, ctx.n, self.rate_hz)


@register
class RateRandomWalk(Effect):
    """Integrated white noise, K in °/h/√h: ``b_i = b_{i−1} + K_s √Δt · w_i`` (°/s),
    ``K_s = K / (3600 · 60)`` °/s/√s; Allan ``σ(τ) = K_s √(τ/3)`` (+½ line)."""

    name = "rate_random_walk"
    stochastic = True
    candidate = Candidate("noise", GAP_ALLAN, "K")
    PARAMS = {"K": Param(1.0, "deg/h/sqrt(h)", "rate random walk coefficient", "nonneg")}

    def __init__(
        self, params: dict[str, float], rng: np.random.Generator | None, rate_hz: float
    ) -> None:
        super().__init__(params, rng, rate_hz)
        self._b = 0.0

    def rate(self, ctx: BlockContext) -> np.ndarray:
        step = self.p["K"] / (3600.0 * 60.0) * math.sqrt(ctx.dt)
        b = self._b + np.cumsum(step * self.rng.standard_normal(ctx.n))  # type: ignore[union-attr]
        if ctx.n:
            self._b = float(b[-1])
        return b


@register
class Quantization(Effect):
    """Output quantized to a step q (°/s) with the angle carried over (IEEE 952 angle
    quantization): ``k_i = round(Σ_{j≤i} Ω_j / q)``, ``Ω_q,i = q (k_i − k_{i−1})``.

    Each output is a multiple of q; the error is a difference of a bounded angle error, so
    the Allan deviation falls as ``σ(τ) = √3 · Q / τ`` with ``Q = q Δt / √12`` (slope −1).
    """

    name = "quantization"
    target = "post"
    candidate = Candidate("sample", GAP_LATTICE, "q")
    PARAMS = {"q": Param(1.0e-3, "deg/s", "output step (LSB)", "pos")}

    def __init__(
        self, params: dict[str, float], rng: np.random.Generator | None, rate_hz: float
    ) -> None:
        super().__init__(params, rng, rate_hz)
        self._resid = 0.0  # carried angle, in units of q·Δt, relative to the last output

    def post(self, out: np.ndarray, ctx: BlockContext) -> np.ndarray:
        if not ctx.n:
            return out
        c = self._resid + np.cumsum(out / self.p["q"])
        k = np.rint(c)
        q = np.diff(k, prepend=0.0) * self.p["q"]
        self._resid = float(c[-1] - k[-1])
        return q


@register
class Outliers(Effect):
    """Sparse spikes: each sample is, with probability ``p = rate_per_h / 3600 / f_s``,
    offset by ±amplitude (°/s), sign equally likely."""

    name = "outliers"
    stochastic = True
    candidate = Candidate("sample", GAP_SPIKES, "amplitude")
    PARAMS = {
        "rate_per_h": Param(20.0, "1/h", "expected spikes per hour", "nonneg"),
        "amplitude": Param(0.05, "deg/s", "spike height"),
    }

    def rate(self, ctx: BlockContext) -> np.ndarray:
        u = self.rng.random(ctx.n)  # type: ignore[union-attr]
        p = self.p["rate_per_h"] / 3600.0 / self.rate_hz
        return np.where(u < p, np.where(u < 0.5 * p, -1.0, 1.0) * self.p["amplitude"], 0.0)


def overshoot_omega_zeta(overshoot: float, period_s: float) -> tuple[float, float]:
    """(ω_n rad/s, ζ) of a second-order step response with fractional ``overshoot``
    ``exp(−πζ/√(1−ζ²))`` and damped period ``period_s = 2π/(ω_n√(1−ζ²))``."""
    lo = math.log(overshoot)
    zeta = -lo / math.sqrt(math.pi**2 + lo * lo)
    wd = 2.0 * math.pi / period_s
    return wd / math.sqrt(1.0 - zeta * zeta), zeta


def overshoot_period_s(overshoot: float, mean_delay_s: float) -> float:
    """The damped period of a second-order chamber with ``overshoot`` whose step response
    has the mean delay ``2ζ/ω_n`` of a first-order one with τ = ``mean_delay_s``:
    ``π·τ / (ζ·√(1−ζ²))`` s (the chamber as fast as before, only ringing)."""
    lo = math.log(overshoot)
    zeta = -lo / math.sqrt(math.pi**2 + lo * lo)
    return math.pi * mean_delay_s / (zeta * math.sqrt(1.0 - zeta * zeta))


@register
class OvenOvershoot(Effect):
    """Chamber air answers a setpoint step as a second-order system (still rate limited).

    ``overshoot`` is the fractional overshoot of a small step, ``exp(−πζ/√(1−ζ²))``;
    ``period_s`` the damped period ``2π / (ω_n √(1−ζ²))``. Its detection limit is stated
    for a chamber as fast as the first-order fit (:func:`overshoot_period_s`).
    """

    name = "oven_overshoot"
    target = "air"
    candidate = Candidate("temperature", GAP_TEMPERATURE, "overshoot")
    PARAMS = {
        "overshoot": Param(0.15, "fraction", "overshoot of a small step", "frac"),
        "period_s": Param(1200.0, "s", "damped oscillation period", "pos"),
    }

    def omega_zeta(self) -> tuple[float, float]:
        """(ω_n in rad/s, ζ)."""
        return overshoot_omega_zeta(self.p["overshoot"], self.p["period_s"])


@register
class RtdSelfHeating(Effect):
    """The PT100 reads high by its own heat: the multimeter's test current I dissipates
    ``I²·R(T)`` in it, which a thermal resistance θ to the case turns into
    ``ΔT = θ·I²·R(T) = offset_c · R(T)/R0`` (°C; R by IEC 60751): the error grows with the
    sensor's resistance, 0.39 %/°C. ``offset_c`` is its value at 0 °C (``θ·I²·R0``); with
    the 1 mA of a 34401A, θ = 3 °C/mW gives the default 0.3 °C."""

    name = "rtd_self_heating"
    target = "pt100"
    candidate = Candidate("temperature", GAP_TEMPERATURE, "offset_c")
    PARAMS = {"offset_c": Param(0.3, "degC", "reading minus true case temperature at 0 °C")}
