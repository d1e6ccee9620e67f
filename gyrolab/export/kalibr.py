"""kalibr ``imu.yaml`` noise parameters from the Allan analysis of a run.

kalibr's IMU noise model (https://github.com/ethz-asl/kalibr/wiki/IMU-Noise-Model) takes
continuous-time densities:

* ``gyroscope_noise_density`` σ_g [rad/s/√Hz] — the white-noise strength, i.e. the IEEE 952
  angle random walk N read on the Allan slope −1/2 at τ = 1 s (rate unit × √s, the same
  number: 1/√Hz = √s);
* ``gyroscope_random_walk`` σ_bg [rad/s²/√Hz] — the bias random walk, i.e. the rate random
  walk K read on the Allan slope +1/2 at τ = 3 s (rate unit / √s);
* ``accelerometer_noise_density`` [m/s²/√Hz] and ``accelerometer_random_walk``
  [m/s³/√Hz] — the same two terms of the accelerometer (velocity random walk, acceleration
  random walk), which kalibr's camera–IMU calibration needs too;
* ``update_rate`` [Hz] — the rate of the IMU messages (kalibr makes the discrete-time
  σ_d = σ·√rate itself).

gyrolab's terms are in the data's units (:func:`gyrolab.numerics.noise_terms.noise_terms`):
°/s for the gyro (×π/180 here, nothing else), m/s² for the accelerometer. The gyro's Allan
curve is that of the run's causal, full-rate compensated output (the temperature model
applied, so the thermal drift is not mistaken for random walk); the accelerometer's is its
raw output (gyrolab models no accelerometer drift: a thermal accelerometer drift shows as
random walk, which the comment says). kalibr has one value for all axes: the largest axis
is written, each axis's value and how it was read are in a comment.

**How a term is read, and when it is not.** A term is read off its slope only where the
curve identifies it (the IEEE 952 slope rules with their confidence test) *and* the τ at
which it is defined (1 s for the noise density, 3 s for the random walk) lies inside the
record: a slope is never labelled at a τ the record does not reach. Otherwise the weighted
least-squares fit of the IEEE 952 terms gives it, on the same condition. Where neither
does, the file carries an upper bound the curve itself guarantees — every term's share of
the Allan variance is non-negative, so σ(τ) ≥ N/√τ and σ(τ) ≥ K·√(τ/3) at every τ, hence
N ≤ min σ(τ)·√τ and K ≤ min σ(τ)·√(3/τ) over τ ≤ T/10 — and its comment names it an upper
bound with the reason. All of it on τ at or above the sensor's own output-filter corner
(:func:`gyrolab.numerics.noise_terms.filter_corner_tau`): below it the filter lowers σ, so
a density read there comes out low and σ·√τ is no bound. A record too short for any of
that (no τ with ten independent averages) is refused in one line: kalibr never gets
``nan``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gyrolab.errors import InputError

DEG2RAD = math.pi / 180.0
UNITS = {
    "gyroscope_noise_density": "rad/s/sqrt(Hz)",
    "gyroscope_random_walk": "rad/s^2/sqrt(Hz)",
    "accelerometer_noise_density": "m/s^2/sqrt(Hz)",
    "accelerometer_random_walk": "m/s^3/sqrt(Hz)",
}
#: (IEEE 952 term, the τ (s) its value is defined at, its kalibr key stem)
_TERMS = (("N", 1.0, "noise_density"), ("K", 3.0, "random_walk"))


def _bound(res: Any, name: str, tau_min: float) -> float:
    """The upper bound of term ``name`` over tau_min ≤ τ ≤ T/10 (module doc); NaN without
    such τ."""
    usable = (res.taus <= 0.1 * res.duration_s) & (res.dev > 0)
    usable &= res.taus >= tau_min * (1.0 - 1e-9)
    t, a = res.taus[usable], res.dev[usable]
    if t.size == 0:
        return float("nan")
    return float(np.min(a * np.sqrt(t) if name == "N" else a * np.sqrt(3.0 / t)))


def allan_densities(y: np.ndarray, rate_hz: float, scale: float = 1.0) -> dict[str, Any]:
    """The white-noise density and the random walk of ``y`` (kalibr's units: the data's
    units × ``scale``), each with how it was read (module doc), and the Allan curve."""
    from gyrolab.numerics.allan import allan_deviation
    from gyrolab.numerics.noise_terms import filter_corner_tau, noise_terms

    y = np.asarray(y, dtype=float)
    res = allan_deviation(y, rate_hz, taus="octave", confidence=None)
    record = res.duration_s
    out: dict[str, Any] = {}
    corner = filter_corner_tau(y, rate_hz)  # the sensor's own filter lowers sigma below it
    slope = noise_terms(res, method="slope", tau_min=corner)
    fit = noise_terms(res, method="fit", terms=("N", "B", "K"), tau_min=corner)
    for name, tau_def, key in _TERMS:
        value, how = float("nan"), ""
        inside = tau_def <= record
        for terms, label in ((slope, "slope"), (fit, "fit")):
            v = float(getattr(terms, name))
            if not (np.isfinite(v) and v > 0 and inside):
                continue
            lo, hi = terms.tau_ranges[name]
            s = "-1/2" if name == "N" else "+1/2"
            value = v
            how = (
                f"slope {s} over tau = {lo:.3g}-{hi:.3g} s, read at tau = {tau_def:g} s"
                if label == "slope"
                else f"least-squares fit of N, B, K (its {name} term dominates tau = "
                f"{lo:.3g}-{hi:.3g} s), read at tau = {tau_def:g} s"
            )
            break
        if not np.isfinite(value):
            value = _bound(res, name, corner)
            if not inside:
                why = f"tau = {tau_def:g} s lies beyond the {record:.3g} s record"
            else:
                why = slope.reasons.get(name) or fit.reasons.get(name) or "not identified"
            what = "sigma(tau)*sqrt(tau)" if name == "N" else "sigma(tau)*sqrt(3/tau)"
            how = f"upper bound min {what} over {corner:.3g} s <= tau <= T/10 ({why})"
        if not (np.isfinite(value) and value > 0):
            raise InputError(
                None,
                f"a {record:.3g} s record is too short to bound its noise terms for kalibr "
                "(needs taus with ten independent averages, T/10)",
            )
        out[key] = value * scale
        out[f"{key}_from"] = how
    out["allan_taus_s"] = res.taus.tolist()
    out["allan_adev"] = res.dev.tolist()
    return out


def axis_noise(y_dps: np.ndarray, rate_hz: float) -> dict[str, Any]:
    """One gyro axis (compensated, °/s) in kalibr's keys (rad/s units)."""
    d = allan_densities(y_dps, rate_hz, DEG2RAD)
    return {
        "gyroscope_noise_density": d["noise_density"],
        "gyroscope_random_walk": d["random_walk"],
        "noise_density_from": d["noise_density_from"],
        "random_walk_from": d["random_walk_from"],
        "allan_taus_s": d["allan_taus_s"],
        "allan_adev_dps": d["allan_adev"],
    }


def accel_axis_noise(a_m_s2: np.ndarray, rate_hz: float) -> dict[str, Any]:
    """One accelerometer axis (m/s², raw) in kalibr's keys."""
    d = allan_densities(a_m_s2, rate_hz)
    return {
        "accelerometer_noise_density": d["noise_density"],
        "accelerometer_random_walk": d["random_walk"],
        "noise_density_from": d["noise_density_from"],
        "random_walk_from": d["random_walk_from"],
    }


def imu_yaml(
    axes: dict[str, dict[str, Any]],
    rate_hz: float,
    rostopic: str,
    source: str,
    accel: dict[str, dict[str, Any]] | None = None,
    no_accel_reason: str = "the run has no accelerometer",
) -> str:
    """The ``imu.yaml`` text (the largest axis's values; every axis in comments); without
    ``accel`` the two accelerometer fields are named in a comment (``no_accel_reason``)."""
    lines = [
        f"# kalibr IMU noise parameters from gyrolab's Allan analysis of {source}",
        "# (gyro: causal compensated output; continuous-time units, kalibr wiki "
        "'IMU Noise Model').",
    ]
    values: dict[str, float] = {}
    for prefix, per_axis in (("gyroscope", axes), ("accelerometer", accel or {})):
        if not per_axis:
            continue
        nd, rw = f"{prefix}_noise_density", f"{prefix}_random_walk"
        for name, a in per_axis.items():
            lines.append(
                f"# {prefix} axis {name}: noise density {a[nd]:.6g} {UNITS[nd]} "
                f"({a['noise_density_from']}); random walk {a[rw]:.6g} {UNITS[rw]} "
                f"({a['random_walk_from']})"
            )
        values[nd] = max(a[nd] for a in per_axis.values())
        values[rw] = max(a[rw] for a in per_axis.values())
    if accel:
        lines.append(
            "# accelerometer: raw output (no thermal model); a thermal drift in the run "
            "raises its random walk."
        )
    else:
        lines += [
            f"# {no_accel_reason}: add accelerometer_noise_density (m/s^2/sqrt(Hz))",
            "# and accelerometer_random_walk (m/s^3/sqrt(Hz)) of your IMU before running kalibr.",
        ]
    for key, v in values.items():  # finite and > 0: allan_densities refuses otherwise
        lines.append(f"{key}: {v:.9g}  # {UNITS[key]}")
    lines += [f"update_rate: {rate_hz:.9g}  # Hz", f"rostopic: {rostopic}"]
    return "\n".join(lines) + "\n"
