"""kalibr ``imu.yaml`` gyro noise parameters from the Allan analysis of a run.

kalibr's IMU noise model (https://github.com/ethz-asl/kalibr/wiki/IMU-Noise-Model) takes
continuous-time densities:

* ``gyroscope_noise_density`` σ_g [rad/s/√Hz] — the white-noise strength, i.e. the IEEE 952
  angle random walk N read on the Allan slope −1/2 at τ = 1 s (rate unit × √s, the same
  number: 1/√Hz = √s);
* ``gyroscope_random_walk`` σ_bg [rad/s²/√Hz] — the bias random walk, i.e. the rate random
  walk K read on the Allan slope +1/2 at τ = 3 s (rate unit / √s);
* ``update_rate`` [Hz] — the rate of the IMU messages (kalibr makes the discrete-time
  σ_d = σ·√rate itself).

gyrolab's terms are in °/s (:func:`gyrolab.numerics.noise_terms.noise_terms`), so both are
multiplied by π/180 and nothing else. The Allan curve is that of the run's causal,
full-rate compensated output (the temperature model applied, so the thermal drift is not
mistaken for random walk); kalibr has one value for all axes, the largest axis is written
(each axis's value is in a comment). When the curve has no +1/2 region (a run too short for
the random walk to show) K comes from the weighted least-squares fit of all IEEE 952 terms
(``noise_terms(method="fit")``); where that does not identify it either, the file carries
the upper bound min σ(τ)·√(3/τ) over τ ≤ T/10 (a +1/2 line cannot lie above the curve) and
says so in the axis comment. kalibr also needs the accelerometer
fields; gyrolab measures no accelerometer, so the file names them in a comment for the user
to fill in rather than inventing numbers.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

DEG2RAD = math.pi / 180.0


def axis_noise(y_dps: np.ndarray, rate_hz: float) -> dict[str, Any]:
    """Allan deviation of ``y_dps`` and the N, K terms in kalibr's units (with provenance)."""
    from gyrolab.numerics.allan import allan_deviation
    from gyrolab.numerics.noise_terms import noise_terms

    res = allan_deviation(np.asarray(y_dps, dtype=float), rate_hz, taus="octave", confidence=None)
    slope = noise_terms(res, method="slope")
    N, K, how_k = slope.N, slope.K, "slope +1/2 at tau = 3 s"
    if not (np.isfinite(K) and K > 0):
        fit = noise_terms(res, method="fit", terms=("N", "B", "K"))
        K, how_k = fit.K, "least-squares fit of N, B, K (no +1/2 region on the curve)"
    if not (np.isfinite(K) and K > 0):
        # Not identifiable (docs/allan.md): never a guessed number, but kalibr needs one.
        # A +1/2 term cannot exceed the curve anywhere, sigma(tau) >= K sqrt(tau/3), so
        # min over tau <= T/10 of sigma(tau) sqrt(3/tau) bounds K from above.
        usable = res.taus <= 0.1 * res.duration_s
        bound = res.dev[usable] * np.sqrt(3.0 / res.taus[usable])
        K = float(np.min(bound)) if bound.size else float("nan")
        reason = slope.reasons.get("K", "no +1/2 region")
        how_k = f"upper bound min sigma(tau)*sqrt(3/tau), K not identifiable: {reason}"
    if not (np.isfinite(N) and N > 0):
        fit = noise_terms(res, method="fit", terms=("N", "B", "K"))
        N = fit.N
    return {
        "gyroscope_noise_density": float(N) * DEG2RAD,
        "gyroscope_random_walk": float(K) * DEG2RAD if np.isfinite(K) else float("nan"),
        "random_walk_from": how_k,
        "allan_taus_s": res.taus.tolist(),
        "allan_adev_dps": res.dev.tolist(),
    }


def imu_yaml(axes: dict[str, dict[str, Any]], rate_hz: float, rostopic: str, source: str) -> str:
    """The ``imu.yaml`` text (the largest axis's values; every axis in comments)."""
    nd = max(a["gyroscope_noise_density"] for a in axes.values())
    rws = [
        a["gyroscope_random_walk"] for a in axes.values() if np.isfinite(a["gyroscope_random_walk"])
    ]
    if not rws:
        from gyrolab.errors import InputError

        raise InputError(source, "Allan curve gives no bias random walk on any axis")
    rw = max(rws)
    lines = [
        f"# kalibr IMU noise parameters from gyrolab's Allan analysis of {source}",
        "# (causal compensated output; continuous-time units, kalibr wiki 'IMU Noise Model').",
    ]
    for name, a in axes.items():
        lines.append(
            f"# axis {name}: noise density {a['gyroscope_noise_density']:.6g} rad/s/sqrt(Hz), "
            f"random walk {a['gyroscope_random_walk']:.6g} rad/s^2/sqrt(Hz) "
            f"({a['random_walk_from']})"
        )
    lines += [
        "# gyrolab measures no accelerometer: add accelerometer_noise_density (m/s^2/sqrt(Hz))",
        "# and accelerometer_random_walk (m/s^3/sqrt(Hz)) of your IMU before running kalibr.",
        f"gyroscope_noise_density: {nd:.9g}  # rad/s/sqrt(Hz)",
        f"gyroscope_random_walk: {rw:.9g}  # rad/s^2/sqrt(Hz)",
        f"update_rate: {rate_hz:.9g}  # Hz",
        f"rostopic: {rostopic}",
    ]
    return "\n".join(lines) + "\n"
