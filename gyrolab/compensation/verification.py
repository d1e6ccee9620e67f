"""What a flight controller should report after flashing, and what it did: the on-device check.

A verification run records a controller's IMU with its firmware's compensation ON (the
flashed parameters), over a held-out temperature profile. gyrolab predicts that output for
the same run from three things it knows, none of them the device output itself:

1. **the unit's drift** — gyrolab's fitted model of that IMU axis (the chosen causal model,
   :mod:`gyrolab.compensation.causal`, else GA-BP), evaluated on the run's own temperature
   record (the IMU's sensor, as recorded): ``f̂(t)``, the rate the sensor should put out;
2. **the firmware** — the parameters on the vehicle (as read from it) run through the
   firmware's own rules (:mod:`gyrolab.autopilot`): PX4's ``TC_G*`` offsets published by
   its 1 Hz module with the 1 °C rule plus ``CAL_GYRO*`` offsets, rotated by
   ``SENS_BOARD_ROT``; ArduPilot's ``INS_TCAL``/offset correction at ``CALTEMP``, rotated by
   ``AHRS_ORIENTATION``: ``y(t) = R·(f̂(t) − offsets(t))`` in the body frame the device
   reports;
3. **the link's encoding** — the MAVLink IMU messages carry int16 mrad/s, truncated toward
   zero (:mod:`gyrolab.autopilot.mavlink`). With sensor noise of σ LSB, the expected value
   of a truncated sample is ``E[trunc(y + n)] = Σ_k≥1 P(y + n ≥ k) − Σ_k≥1 P(y + n ≤ −k)``
   (:func:`expected_truncated`), which compresses a residual near zero by up to
   0.4/σ — not a property of the firmware's compensation, but what the device shows, and
   the same for the noise riding on it (:func:`truncation_gain`). σ is read from the
   calibration run of the same IMU and axis (the sample-to-sample scatter of its raw
   output, far from zero: ``σ² = var(Δy)/2 − 1/12`` LSB²), where the model was fitted on
   truncated samples too: its values are taken back through the inverse of the same
   expectation (:func:`untruncated`).

Both are compared as the drift peak-to-peak of 100 s averages: the device's from its
output, the prediction's from the 100 s means of the expected output plus the scatter a
100 s mean of this IMU shows (the Allan deviation at τ = 100 s of the calibration run's
compensated output, :func:`mean_noise_dps`, through the truncation's gain; the median p-p
of 200 seeded draws): a p-p of noisy averages is larger than that of their expectation,
and the prediction says by how much.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy.special import ndtr

from gyrolab.numerics.averaging import BlockAverager

WINDOW_S = 100.0
MC_DRAWS = 200
LSB_RAD_S = 1e-3  # one count of the MAVLink message: 1 mrad/s
DEG2RAD = float(np.pi / 180.0)


def expected_truncated(mu: np.ndarray, sigma: float) -> np.ndarray:
    """``E[trunc(X)]`` for ``X ~ N(mu, sigma²)`` (LSB units): C's float → integer
    conversion of a noisy value (module doc). ``sigma`` > 0."""
    mu = np.asarray(mu, dtype=float)
    if not sigma > 0:
        return np.trunc(mu)
    kmax = int(np.ceil(np.max(np.abs(mu)) + 8.0 * sigma)) + 1
    k = np.arange(1, kmax + 1)[:, None]
    up = ndtr((mu[None, :] - k) / sigma).sum(axis=0)  # P(X >= k)
    down = ndtr((-k - mu[None, :]) / sigma).sum(axis=0)  # P(X <= -k)
    return up - down


def truncation_gain(mu: np.ndarray, sigma: float) -> np.ndarray:
    """``d E[trunc(X)] / d mu`` (:func:`expected_truncated`): how much of a small change —
    of the drift, or a noise average — passes the truncation at ``mu`` (1 far from zero,
    down to ``1 − 0.8·φ(0)/σ`` at zero)."""
    from scipy.stats import norm

    mu = np.asarray(mu, dtype=float)
    if not sigma > 0:
        return np.ones_like(mu)
    kmax = int(np.ceil(np.max(np.abs(mu)) + 8.0 * sigma)) + 1
    k = np.arange(1, kmax + 1)[:, None]
    return (norm.pdf((mu[None, :] - k) / sigma) + norm.pdf((-k - mu[None, :]) / sigma)).sum(
        axis=0
    ) / sigma


def untruncated(m: np.ndarray, sigma: float) -> np.ndarray:
    """The mean ``mu`` whose :func:`expected_truncated` is ``m`` (LSB): a model fitted on
    truncated samples describes ``E[trunc]``, not the sensor's rate; this undoes it
    (``E[trunc]`` increases monotonically in ``mu`` for ``sigma`` > 0)."""
    m = np.asarray(m, dtype=float)
    grid = np.arange(np.min(m) - 4.0, np.max(m) + 4.0, 0.01)
    return np.interp(m, expected_truncated(grid, sigma), grid)


def noise_lsb(counts: np.ndarray) -> float:
    """Per-sample white noise (LSB) of a quantised raw output far from zero: from the
    first differences, less the uniform quantisation's 1/12 LSB²."""
    d = np.diff(np.asarray(counts, dtype=float))
    v = float(np.var(d)) / 2.0 - 1.0 / 12.0
    return float(np.sqrt(max(v, 1e-6)))


def firmware_offsets(
    firmware: str,
    params: Mapping[str, float],
    imu: int,
    t: np.ndarray,
    temp_t: np.ndarray,
    temp_c: np.ndarray,
    device_id: int = 0,
    controller: list[tuple[int, np.ndarray, np.ndarray]] | None = None,
) -> np.ndarray:
    """``(n, 3)`` rad/s the firmware subtracts (sensor frame) at sample times ``t`` of IMU
    ``imu``, its temperature readings ``(temp_t, temp_c)`` (module doc, item 2). PX4:
    ``controller`` gives every gyro's ``(device_id, t, °C)`` on the same clock, for the
    module's publications (another gyro's 1 °C move republishes this one's offsets too);
    without it this gyro's own readings alone."""
    from gyrolab.autopilot import ardupilot as ap
    from gyrolab.autopilot import px4
    from gyrolab.compensation.prepare import causal_temperature

    t = np.asarray(t, dtype=float)
    if firmware == "px4":
        out = np.zeros((t.size, 3))
        if px4.tc_slot_for(params, device_id) is not None:
            gyros = controller or [(device_id, temp_t, temp_c)]
            t_end = max(float(g[1][-1]) for g in gyros) + px4.MODULE_PERIOD_S
            # the module ran before the run: poll from when every gyro has a reading
            first = max(float(g[1][0]) for g in gyros)
            pub_t, pubs = px4.module_publications(params, gyros, t_end, first_poll_s=first)
            out += px4.held(t, pub_t, pubs[device_id]).astype(float)
        ids = [int(params.get(px4.cal_id_name(s), 0)) for s in range(px4.TC_SLOTS)]
        if device_id in ids:
            cal = ids.index(device_id)
            out += np.array([params.get(n, 0.0) for n in px4.cal_offset_names(cal)])
        return out
    temp = causal_temperature(t, temp_t, temp_c)
    tcal = ap.Tcal.from_params(params, imu)
    cal_temp = float(params.get(ap.caltemp_name(imu), -300.0))
    return ap.gyro_offsets(params, imu).astype(float) + tcal.correction(temp, cal_temp).astype(
        float
    )


def board_rotation(firmware: str, params: Mapping[str, float]) -> int:
    from gyrolab.autopilot import ardupilot as ap
    from gyrolab.autopilot import px4

    name = px4.BOARD_ROTATION if firmware == "px4" else ap.BOARD_ORIENTATION
    return int(params.get(name, 0))


def drift_pp(t: np.ndarray, x: np.ndarray, period: float) -> float:
    """Peak-to-peak of the ``WINDOW_S`` averages of ``x`` at times ``t``."""
    acc = BlockAverager(WINDOW_S)
    acc.add(np.asarray(t, dtype=float), x, period)
    _tb, xb, _filled = acc.result()
    xb = xb[np.isfinite(xb)]
    return float(xb.max() - xb.min()) if xb.size >= 2 else float("nan")


def mean_noise_dps(models: list[Any], calibration: Any) -> np.ndarray:
    """Per sensor axis, the scatter of ``WINDOW_S`` means the unit shows once its drift is
    removed: the Allan deviation at τ = ``WINDOW_S`` of the calibration run's causal
    compensated output (white noise, flicker and all; °/s)."""
    from gyrolab.compensation.apply import streaming_compensate
    from gyrolab.numerics.allan import allan_deviation

    out = []
    pt_t, pt_c = calibration.require_temperature()
    for a, m in enumerate(models):
        s = calibration.axis(a).require_rate()
        y = streaming_compensate(m, s.t, s.values, pt_t, pt_c, which="chosen")
        res = allan_deviation(y, s.rate_hz, taus=np.array([WINDOW_S]), confidence=None)
        out.append(float(res.dev[0]) if res.dev.size else float("nan"))
    return np.asarray(out)


def verify_imu(
    models: list[Any],
    firmware: str,
    params: Mapping[str, float],
    imu: int,
    run: Any,
    sigma_lsb: np.ndarray,
    device_id: int = 0,
    seed: int = 0,
    mean_noise: np.ndarray | None = None,
    controller: list[tuple[int, np.ndarray, np.ndarray]] | None = None,
) -> dict[str, dict[str, float]]:
    """Per body axis (x, y, z): the predicted and the device's drift p-p of 100 s averages
    (°/s) for IMU ``imu`` of the verification ``run`` (a :class:`Recording` of that IMU's
    unit: rate in °/s as the device reported it, its temperature), from the unit's fitted
    ``models`` (x, y, z sensor axes), the vehicle's ``params`` and the per-axis noise
    ``sigma_lsb`` (module doc); ``controller``: every IMU's temperature record, for PX4's
    module (:func:`firmware_offsets`)."""
    from gyrolab.autopilot.rotation import rotation_matrix
    from gyrolab.compensation.apply import streaming_compensate

    rate = run.require_rate()
    pt_t, pt_c = run.require_temperature()
    t = rate.t
    # 1. the unit's drift, sensor frame (rad/s): the model's correction on zeros, negated;
    # fitted on truncated samples, so its truncation expectation undone (module doc)
    sig = np.asarray(sigma_lsb, dtype=float)
    drift = np.column_stack(
        [
            untruncated(
                -streaming_compensate(m, t, np.zeros(t.size), pt_t, pt_c, which="chosen")
                * DEG2RAD / LSB_RAD_S,
                float(sig[a]),
            ) * LSB_RAD_S
            for a, m in enumerate(models)
        ]
    )  # fmt: skip
    # 2. the firmware, into the body frame
    y = drift - firmware_offsets(firmware, params, imu, t, pt_t, pt_c, device_id, controller)
    r = rotation_matrix(board_rotation(firmware, params))
    y_body = y @ r.T
    # σ of each body axis: the sensor axes' noise, rotated (rotations permute/negate axes)
    sig_body = np.sqrt((sig**2) @ (r.T**2))
    # the scatter of a 100 s mean: measured on the calibration run where given, else white
    n_per = WINDOW_S / rate.period
    white = sig * LSB_RAD_S / DEG2RAD / np.sqrt(n_per)
    noise = white if mean_noise is None else np.asarray(mean_noise, dtype=float)
    noise_body = np.sqrt((noise**2) @ (r.T**2))
    rng = np.random.default_rng(seed)
    out: dict[str, dict[str, float]] = {}
    for j, name in enumerate("xyz"):
        # 3. the link's encoding (LSB = 1 mrad/s), then °/s
        lsb = y_body[:, j] / LSB_RAD_S
        mu_dps = expected_truncated(lsb, float(sig_body[j])) * LSB_RAD_S / DEG2RAD
        gain = truncation_gain(lsb, float(sig_body[j]))  # noise passes it scaled likewise
        acc, accg = BlockAverager(WINDOW_S), BlockAverager(WINDOW_S)
        acc.add(t, mu_dps, rate.period)
        accg.add(t, gain, rate.period)
        _tb, means, _f = acc.result()
        _tb, gains, _f = accg.result()
        ok = np.isfinite(means) & np.isfinite(gains)
        means, gains = means[ok], gains[ok]
        sd = float(noise_body[j])
        draws = means[None, :] + sd * gains[None, :] * rng.standard_normal((MC_DRAWS, means.size))
        predicted = float(np.median(draws.max(axis=1) - draws.min(axis=1)))
        device = drift_pp(t, rate.values[:, j], rate.period)
        out[name] = {
            "predicted_drift_pp_100s_deg_per_s": predicted,
            "device_drift_pp_100s_deg_per_s": device,
            "ratio": device / predicted if predicted > 0 else float("nan"),
            "predicted_expectation_pp_100s_deg_per_s": float(means.max() - means.min()),
            "noise_lsb": float(sig_body[j]),
            "mean_noise_100s_deg_per_s": sd,
        }
    return out

