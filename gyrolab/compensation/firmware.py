"""The firmware polynomial: the 3rd-order bias(T) that PX4 and ArduPilot can load, its
parameter sets, and what each firmware leaves when it runs it.

PX4 (``TC_Gi_*``, ``src/modules/temperature_compensation``) and ArduPilot
(``INS_TCALn_*``, ``AP_InertialSensor_tempcal.cpp``) both correct a gyro by a cubic in the
temperature, clamped to the calibrated range::

    b(T) = c0 + c1·Δ + c2·Δ² + c3·Δ³,   Δ = clamp(T, T_min, T_max) − T_ref      (°/s here)

so neither can load gyrolab's network. :func:`fit_poly3` fits this cubic on the same
calibration run as the chosen model (the 1000 points/h averages of the raw rate against the
causal PT100 temperature, ordinary least squares in Δ with ``T_ref`` the middle of the
range, as PX4's ``Tools/process_sensor_caldata.py`` does); :func:`px4_parameter_set` and
:func:`ardupilot_parameter_set` write it as each firmware's parameters (float32, the
reference temperature and scale each uses), for ``gyrolab export`` and for flashing.
:func:`firmware_offset_fn` runs it on any run the way each firmware does — causal, full
rate, clamped, in its float32 arithmetic and with its own update rule
(:mod:`gyrolab.autopilot`: PX4 republishes the offsets only when the temperature moved more
than 1 °C, polled once a second; ArduPilot corrects every sample);
:func:`gyrolab.compensation.evaluate.add_firmware_metrics` scores that beside the chosen
model's causal output, so that metrics.json says what each firmware costs.
docs/export.md gives the parameter mappings.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from gyrolab.compensation.prepare import PreparedRun, causal_temperature, run_rate_batches
from gyrolab.numerics.averaging import BlockAverager

DEG2RAD = float(np.pi / 180.0)
MAV_PARAM_TYPE_INT8 = 2  # MAVLink MAV_PARAM_TYPE: ArduPilot's AP_Int8 (INS_TCALn_ENABLE)
MAV_PARAM_TYPE_INT32 = 6
MAV_PARAM_TYPE_REAL32 = 9
AXES = "XYZ"


@dataclass(frozen=True)
class Poly3:
    """``b(T) = Σ_k coef[k]·Δ^k`` (°/s), ``Δ = clamp(T, t_min, t_max) − t_ref`` (°C)."""

    coef: tuple[float, float, float, float]  # c0..c3, °/s per °C^k
    t_ref: float
    t_min: float
    t_max: float

    def predict(self, temp_c: np.ndarray) -> np.ndarray:
        """Bias in °/s at temperatures ``temp_c`` (clamped to the calibrated range): a 1-D
        array, or inputs ``(N, k)`` whose column 0 is the temperature."""
        T = np.asarray(temp_c, dtype=float)
        T = T[:, 0] if T.ndim == 2 else T
        d = np.clip(T, self.t_min, self.t_max) - self.t_ref
        c0, c1, c2, c3 = self.coef
        return c0 + d * (c1 + d * (c2 + d * c3))

    def recentred(self, t_ref: float) -> tuple[float, float, float, float]:
        """The same cubic's coefficients about another reference temperature (°/s)."""
        p = np.polynomial.Polynomial(self.coef)
        q = p(np.polynomial.Polynomial([t_ref - self.t_ref, 1.0]))
        c = np.zeros(4)
        c[: q.coef.size] = q.coef
        return tuple(float(v) for v in c)  # type: ignore[return-value]

    def spec(self, inputs: list[str], window_s: float | None) -> dict[str, Any]:
        """The exported form (``poly3``, :mod:`gyrolab.compensation.regressors`; its one
        input is T)."""
        return {
            "kind": "poly3",
            "coef": list(self.coef),
            "t_ref": self.t_ref,
            "t_min": self.t_min,
            "t_max": self.t_max,
        }

    def to_dict(self) -> dict[str, Any]:
        return {
            "form": "c0 + c1*d + c2*d^2 + c3*d^3, d = clamp(T, t_min_c, t_max_c) - t_ref_c",
            "unit": "deg/s",
            "coef_deg_per_s": list(self.coef),
            "t_ref_c": self.t_ref,
            "t_min_c": self.t_min,
            "t_max_c": self.t_max,
            "fitted_on": "1000 points/h averages of the raw rate vs the causal PT100 "
            "temperature of the calibration run (least squares)",
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Poly3:
        c = [float(v) for v in d["coef_deg_per_s"]]
        return cls(
            (c[0], c[1], c[2], c[3]), float(d["t_ref_c"]), float(d["t_min_c"]), float(d["t_max_c"])
        )


def fit_poly3(run: PreparedRun) -> Poly3:
    """Least-squares cubic of the averaged raw rate in ``Δ = T − T_ref`` on a calibration run
    (``T_ref`` = middle of the run's temperature range, as PX4's calibration script)."""
    temp = run.X[:, 0]
    lo, hi = float(temp.min()), float(temp.max())
    t_ref = 0.5 * (lo + hi)
    c = np.polynomial.polynomial.polyfit(temp - t_ref, run.rate, 3)
    return Poly3((float(c[0]), float(c[1]), float(c[2]), float(c[3])), t_ref, lo, hi)


FIRMWARES = ("px4", "ardupilot")


def firmware_offset_fn(p3: Poly3, run: PreparedRun, form: str) -> Callable[[np.ndarray], Any]:
    """``t → offset (°/s)`` that ``form`` subtracts from the gyro at sample times ``t`` of
    ``run`` (its temperature readings ``pt_t``/``pt_c``):

    * ``"poly3"`` — the cubic itself, continuous: ``b(T(t⁻))`` (float64);
    * ``"px4"`` — PX4's rule (:mod:`gyrolab.autopilot.px4`): the cubic as the
      ``TC_G*`` set (:func:`px4_parameter_set`, float32), evaluated by the
      temperature_compensation module once a second (polls at whole seconds of the run) and
      republished only when the temperature moved more than 1 °C; a sample uses the last
      publication (zero before the first);
    * ``"ardupilot"`` — ArduPilot's rule (:mod:`gyrolab.autopilot.ardupilot`): the
      ``INS_TCAL`` set with its offsets and ``CALTEMP`` (:func:`ardupilot_parameter_set`,
      float32), applied to every sample with the latest temperature."""
    from gyrolab.autopilot import ardupilot as ap
    from gyrolab.autopilot import px4

    if form == "poly3":
        return lambda t: p3.predict(causal_temperature(t, run.pt_t, run.pt_c))
    if form == "px4":
        values = {k: v for k, (v, _type) in px4_parameter_set([p3], 0, 1).items()}
        tc = px4.TcGyro.from_params(values, 0)
        # after the last reading the temperature no longer moves: no later publication
        t_end = float(run.pt_t[-1]) + px4.MODULE_PERIOD_S if run.pt_t.size else 0.0
        first = float(run.pt_t[0]) if run.pt_t.size else 0.0  # polls from the first reading
        pub_t, pub = px4.publications(run.pt_t, run.pt_c, tc, t_end, first_poll_s=first)
        return lambda t: px4.held(t, pub_t, pub)[:, 0].astype(float) / DEG2RAD
    if form == "ardupilot":
        values = {k: v for k, (v, _type) in ardupilot_parameter_set([p3], 0).items()}
        tcal = ap.Tcal.from_params(values, 0)
        cal = values[ap.caltemp_name(0)]
        off = float(ap.gyro_offsets(values, 0)[0])

        def corr(t: np.ndarray) -> np.ndarray:
            temp = causal_temperature(t, run.pt_t, run.pt_c)
            return (off + tcal.correction(temp, cal)[:, 0].astype(float)) / DEG2RAD

        return corr
    raise ValueError(f"unknown firmware form {form!r}")


def firmware_block_means(
    offset: Callable[[np.ndarray], Any], run: PreparedRun, block_s: float
) -> np.ndarray:
    """Causal full-rate ``raw(t) − offset(t)`` averaged to the run's 1000 points/h grid."""
    acc = BlockAverager(block_s)
    if run.raw_rate is not None and run.raw_t is not None:
        acc.add(run.raw_t, run.raw_rate - offset(run.raw_t), run.raw_period)
    else:
        for t, x, period in run_rate_batches(run):
            acc.add(t, x - offset(t), period)
    return acc.result()[1]


def poly3_block_means(p3: Poly3, run: PreparedRun, block_s: float) -> np.ndarray:
    """Causal full-rate ``raw(t) − b(T(t⁻))`` averaged to the run's 1000 points/h grid."""
    return firmware_block_means(firmware_offset_fn(p3, run, "poly3"), run, block_s)


def chosen_key(metrics: dict[str, Any]) -> str:
    """The metrics key of the chosen causal output: ``causal`` (the causal headline model)
    when the model has one, else ``compensated_streaming`` (GA-BP on T, causal)."""
    return "causal" if "causal" in metrics else "compensated_streaming"


UPDATE_RULES = {
    "px4": "TC_G* float32; recomputed once a second, republished when T moved > 1 degC "
    "(temperature_compensation update_offsets_gyro)",
    "ardupilot": "INS_TCAL* float32 with INS_GYROFFS at CALTEMP; every sample at the "
    "latest T (AP_InertialSensor_tempcal correct_sensor)",
}


def firmware_sentence(metrics: dict[str, Any]) -> str:
    """One sentence for the report: what the firmware form (PX4/ArduPilot cubic) costs."""
    fw = metrics["firmware_poly3"]
    r = fw["vs_chosen"]
    ch = metrics[r["chosen"]]
    name = "causal model" if r["chosen"] == "causal" else "causal GA-BP output"
    rules = "".join(
        f"; as {label} runs it ({metrics[k]['update_rule'].split(';')[1].strip()}): drift p-p "
        f"{metrics[k]['drift_pp_deg_per_s']:.4g} °/s "
        f"({metrics[k]['vs_chosen']['drift_pp_deg_per_s_ratio']:.3g}×)"
        for k, label in (("firmware_px4", "PX4"), ("firmware_ardupilot", "ArduPilot"))
        if k in metrics
    )
    return (
        "Firmware form (3rd-order polynomial in T, clamped to the calibrated range — what "
        "PX4 TC_G* and ArduPilot INS_TCAL* parameters hold; `gyrolab export --format "
        f"px4|ardupilot`): drift p-p {fw['drift_pp_deg_per_s']:.4g} °/s against "
        f"{ch['drift_pp_deg_per_s']:.4g} °/s for the {name} "
        f"({r['drift_pp_deg_per_s_ratio']:.3g}×), rms {fw['rms_deg_per_s']:.4g} against "
        f"{ch['rms_deg_per_s']:.4g} °/s ({r['rms_deg_per_s_ratio']:.3g}×), bias stability "
        f"{fw['bias_stability_deg_per_h']:.4g} against {ch['bias_stability_deg_per_h']:.4g} °/h "
        f"({r['bias_stability_deg_per_h_ratio']:.3g}×){rules}; a ratio above 1 is what the "
        "firmware form loses."
    )


# ----------------------------------------------- the cubic as each firmware's parameters


def _f32(v: float) -> float:
    """``v`` rounded to the float32 the firmware stores."""
    return float(np.float32(v))


def _axes3(polys: list[Poly3]) -> list[Poly3 | None]:
    return [polys[k] if k < len(polys) else None for k in range(3)]


def _range(polys: list[Poly3]) -> tuple[float, float]:
    # one temperature range per sensor in both firmwares: the axes share the calibration run
    return min(p.t_min for p in polys), max(p.t_max for p in polys)


def px4_parameter_set(
    polys: list[Poly3], instance: int, device_id: int
) -> dict[str, tuple[float, int]]:
    """``name → (value, MAV_PARAM_TYPE)`` of PX4's TC set for gyro ``instance`` (module
    docstring), ``TC_G_ENABLE`` first; values as float32 holds them."""
    from gyrolab.autopilot import px4

    if not 0 <= instance < px4.TC_SLOTS:
        raise ValueError(f"PX4 has thermal compensation for gyro instances 0..{px4.TC_SLOTS - 1}")
    lo, hi = _range(polys)
    tref = 0.5 * (lo + hi)
    g = f"TC_G{instance}_"
    vals: dict[str, tuple[float, int]] = {
        "TC_G_ENABLE": (1.0, MAV_PARAM_TYPE_INT32),
        f"{g}ID": (float(int(device_id)), MAV_PARAM_TYPE_INT32),
        f"{g}TMIN": (_f32(lo), MAV_PARAM_TYPE_REAL32),
        f"{g}TMAX": (_f32(hi), MAV_PARAM_TYPE_REAL32),
        f"{g}TREF": (_f32(tref), MAV_PARAM_TYPE_REAL32),
    }
    for a, p in enumerate(_axes3(polys)):
        c = (0.0, 0.0, 0.0, 0.0) if p is None else p.recentred(tref)
        for k in range(4):
            vals[f"{g}X{k}_{a}"] = (_f32(c[k] * DEG2RAD), MAV_PARAM_TYPE_REAL32)
    return vals


def ardupilot_parameter_set(polys: list[Poly3], instance: int) -> dict[str, tuple[float, int]]:
    """``name → (value, MAV_PARAM_TYPE)`` of ArduPilot's INS_TCAL set, gyro offsets and
    CALTEMP for IMU ``instance`` (0-based; module docstring), ``INS_TCALn_ENABLE`` first."""
    from gyrolab.autopilot import ardupilot as ap

    if not 0 <= instance < ap.IMUS:
        raise ValueError(
            f"ArduPilot has temperature calibration for IMU instances 0..{ap.IMUS - 1}"
        )
    n = instance + 1
    lo, hi = _range(polys)
    cal_temp = min(max(ap.TEMP_REFERENCE_C, lo), hi)
    vals: dict[str, tuple[float, int]] = {
        f"INS_TCAL{n}_ENABLE": (1.0, MAV_PARAM_TYPE_INT8),
        f"INS_TCAL{n}_TMIN": (_f32(lo), MAV_PARAM_TYPE_REAL32),
        f"INS_TCAL{n}_TMAX": (_f32(hi), MAV_PARAM_TYPE_REAL32),
    }
    ofs: dict[str, tuple[float, int]] = {}
    offs = ap.gyro_offset_names(instance)
    for a, p in enumerate(_axes3(polys)):
        c = (0.0,) * 4 if p is None else p.recentred(ap.TEMP_REFERENCE_C)
        for k in (1, 2, 3):
            v = c[k] * DEG2RAD * ap.SCALE_FACTOR
            vals[f"INS_TCAL{n}_GYR{k}_{AXES[a]}"] = (_f32(v), MAV_PARAM_TYPE_REAL32)
        x = float(np.float32(cal_temp)) - ap.TEMP_REFERENCE_C
        # offset = bias at CALTEMP, so that GYROFFS + P(x(T)) − P(x(CALTEMP)) = b(T)
        b = (c[0] + x * (c[1] + x * (c[2] + x * c[3]))) * DEG2RAD
        ofs[offs[a]] = (_f32(b), MAV_PARAM_TYPE_REAL32)
    vals.update(ofs)
    vals[ap.caltemp_name(instance)] = (_f32(cal_temp), MAV_PARAM_TYPE_REAL32)
    return vals
