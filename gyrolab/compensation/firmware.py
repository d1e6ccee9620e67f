"""The firmware polynomial: the 3rd-order bias(T) that PX4 and ArduPilot can load.

PX4 (``TC_Gi_*``, ``src/modules/temperature_compensation``) and ArduPilot
(``INS_TCALn_*``, ``AP_InertialSensor_tempcal.cpp``) both correct a gyro by a cubic in the
temperature, clamped to the calibrated range::

    b(T) = c0 + c1·Δ + c2·Δ² + c3·Δ³,   Δ = clamp(T, T_min, T_max) − T_ref      (°/s here)

so neither can load gyrolab's network. :func:`fit_poly3` fits this cubic on the same
calibration run as the chosen model (the 1000 points/h averages of the raw rate against the
causal PT100 temperature, ordinary least squares in Δ with ``T_ref`` the middle of the
range, as PX4's ``Tools/process_sensor_caldata.py`` does), and :func:`poly3_block_means`
applies it the way the firmware would run it — causal, full rate, clamped — on any run;
:func:`gyrolab.compensation.evaluate.poly3_metrics` scores that beside the chosen model's
causal output, so that metrics.json says what the firmware's form costs. docs/export.md
gives the parameter mappings.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from gyrolab.compensation.prepare import PreparedRun, causal_temperature, run_rate_batches
from gyrolab.numerics.averaging import BlockAverager

DEG2RAD = float(np.pi / 180.0)


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


def poly3_block_means(p3: Poly3, run: PreparedRun, block_s: float) -> np.ndarray:
    """Causal full-rate ``raw(t) − b(T(t⁻))`` averaged to the run's 1000 points/h grid."""
    acc = BlockAverager(block_s)

    def comp(t: np.ndarray, x: np.ndarray) -> np.ndarray:
        return x - p3.predict(causal_temperature(t, run.pt_t, run.pt_c))

    if run.raw_rate is not None and run.raw_t is not None:
        acc.add(run.raw_t, comp(run.raw_t, run.raw_rate), run.raw_period)
    else:
        for t, x, period in run_rate_batches(run):
            acc.add(t, comp(t, x), period)
    return acc.result()[1]


def chosen_key(metrics: dict[str, Any]) -> str:
    """The metrics key of the chosen causal output: ``causal`` (the causal headline model)
    when the model has one, else ``compensated_streaming`` (GA-BP on T, causal)."""
    return "causal" if "causal" in metrics else "compensated_streaming"


def firmware_sentence(metrics: dict[str, Any]) -> str:
    """One sentence for the report: what the firmware form (PX4/ArduPilot cubic) costs."""
    fw = metrics["firmware_poly3"]
    r = fw["vs_chosen"]
    ch = metrics[r["chosen"]]
    name = "causal model" if r["chosen"] == "causal" else "causal GA-BP output"
    return (
        "Firmware form (3rd-order polynomial in T, clamped to the calibrated range — what "
        "PX4 TC_G* and ArduPilot INS_TCAL* parameters hold; `gyrolab export --format "
        f"px4|ardupilot`): drift p-p {fw['drift_pp_deg_per_s']:.4g} °/s against "
        f"{ch['drift_pp_deg_per_s']:.4g} °/s for the {name} "
        f"({r['drift_pp_deg_per_s_ratio']:.3g}×), rms {fw['rms_deg_per_s']:.4g} against "
        f"{ch['rms_deg_per_s']:.4g} °/s ({r['rms_deg_per_s_ratio']:.3g}×), bias stability "
        f"{fw['bias_stability_deg_per_h']:.4g} against {ch['bias_stability_deg_per_h']:.4g} °/h "
        f"({r['bias_stability_deg_per_h_ratio']:.3g}×); a ratio above 1 is what the firmware "
        "form loses."
    )
