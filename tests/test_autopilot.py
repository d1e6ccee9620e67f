"""The firmwares' own rules (gyrolab.autopilot) and the ``firmware_*`` scores that run them:
PX4's TC cubic in float32, its 1 Hz module and 1 °C republish rule (also across gyros),
ArduPilot's INS_TCAL/offset/orientation order and its inverse, the rotation enum."""

from __future__ import annotations

import numpy as np
import pytest

from gyrolab.autopilot import ardupilot as ap
from gyrolab.autopilot import px4
from gyrolab.autopilot.rotation import rotate, rotation_matrix, rotation_name
from gyrolab.compensation.config import PipelineConfig
from gyrolab.compensation.evaluate import add_firmware_metrics
from gyrolab.compensation.firmware import (
    Poly3,
    ardupilot_parameter_set,
    firmware_offset_fn,
    px4_parameter_set,
)
from gyrolab.compensation.prepare import prepare_arrays


def _px4_params(slot: int = 0, device_id: int = 7) -> dict[str, float]:
    p = {"TC_G_ENABLE": 1, f"TC_G{slot}_ID": device_id, f"TC_G{slot}_TREF": 30.0,
         f"TC_G{slot}_TMIN": 10.0, f"TC_G{slot}_TMAX": 50.0}  # fmt: skip
    x = [[1e-3, -2e-3, 5e-4], [2e-5, 1e-5, -3e-5], [3e-7, -1e-7, 2e-7], [1e-8, 2e-9, -5e-9]]
    p.update({f"TC_G{slot}_X{k}_{a}": x[k][a] for k in range(4) for a in range(3)})
    return p


def test_rotation_enum() -> None:
    assert rotation_name(8) == "ROTATION_ROLL_180"
    np.testing.assert_array_equal(rotation_matrix(8), np.diag([1.0, -1.0, -1.0]))
    np.testing.assert_array_equal(rotate(np.array([1.0, 2.0, 3.0]), 2), [-2.0, 1.0, 3.0])  # yaw 90
    v = np.random.default_rng(0).normal(size=(5, 3))
    for rid in range(10):
        np.testing.assert_allclose(rotate(rotate(v, rid), rid, inverse=True), v, atol=1e-12)
    with pytest.raises(ValueError, match="not in the autopilot rotation enum"):
        rotation_matrix(100)  # ArduPilot's ROTATION_CUSTOM


def test_px4_thermal_offsets_float32_and_clipped() -> None:
    tc = px4.TcGyro.from_params(_px4_params(), 0)
    temps = np.array([-5.0, 10.0, 22.5, 30.0, 49.9, 50.0, 80.0])
    got = tc.offsets(temps)
    assert got.dtype == np.float32 and got.shape == (7, 3)
    d = np.clip(temps, 10.0, 50.0) - 30.0
    x = tc.x.astype(float)
    want = x[0] + x[1] * d[:, None] + x[2] * d[:, None] ** 2 + x[3] * d[:, None] ** 3
    np.testing.assert_allclose(got, want, rtol=2e-6, atol=1e-12)
    np.testing.assert_array_equal(got[0], got[1])  # below TMIN: TMIN
    np.testing.assert_array_equal(got[5], got[6])  # above TMAX: TMAX


def test_px4_module_republishes_only_after_1_degree_across_gyros() -> None:
    p = _px4_params(0, 7)
    p.update({k: v for k, v in _px4_params(1, 8).items() if k.startswith("TC_G1")})
    mod = px4.TemperatureCompensationModule(p, [7, 8, 9])  # gyro 2 has no calibration
    first = mod.poll([20.0, 30.0, 40.0])  # last_temperature starts at -100: publishes
    assert set(first) == {7, 8}
    assert mod.poll([20.9, 30.5, 40.0]) is None  # neither moved more than 1 °C
    pub = mod.poll([21.01, 30.6, 40.0])  # gyro 0 moved 1.01 °C: publish, gyro 1's fresh too
    tc = px4.TcGyro.from_params(p, 0)
    np.testing.assert_array_equal(pub[7], tc.offsets(21.01))
    np.testing.assert_array_equal(pub[8], px4.TcGyro.from_params(p, 1).offsets(30.6))
    assert mod.poll([21.5, 30.95, 40.0]) is None
    # gyro 1's last temperature is still 30.0: its 30.6 went out with gyro 0's publication
    assert mod.last_temperature[1] == pytest.approx(30.0)
    assert mod.poll([21.5, 31.05, 40.0]) is not None  # 1.05 °C from 30.0, 0.45 from 30.6
    mod.parameters_update(p)  # a parameter change: every last_temperature back to -100
    assert mod.poll([21.5, 31.61, 40.0]) is not None
    p["TC_G_ENABLE"] = 0
    mod.parameters_update(p)
    assert mod.poll([0.0, 0.0, 0.0]) is None


def test_px4_publications_equal_the_module_for_one_gyro() -> None:
    rng = np.random.default_rng(4)
    t = np.arange(0.0, 600.0, 0.1)
    temp = 20.0 + 0.05 * t + 0.3 * np.sin(t / 7.0) + 0.01 * rng.standard_normal(t.size)
    p = _px4_params(0, 7)
    tc = px4.TcGyro.from_params(p, 0)
    pub_t, pub = px4.publications(t, temp, tc, t[-1])
    mod = px4.TemperatureCompensationModule(p, [7])
    want_t, want = [], []
    for poll in np.arange(0.0, t[-1] + 1e-9, 1.0):
        latest = temp[np.searchsorted(t, poll, side="right") - 1]
        out = mod.poll([latest])
        if out is not None:
            want_t.append(poll)
            want.append(out[7])
    np.testing.assert_array_equal(pub_t, want_t)
    np.testing.assert_array_equal(pub, np.asarray(want))
    assert 25 <= pub_t.size <= 40  # ~30 °C of ramp: one publication per degree
    samples = np.array([0.05, pub_t[3], pub_t[3] + 0.5])
    h = px4.held(samples, pub_t, pub)
    np.testing.assert_array_equal(h[1], pub[3])
    np.testing.assert_array_equal(h[2], pub[3])


def test_ardupilot_correction_order_and_its_inverse() -> None:
    rng = np.random.default_rng(2)
    n = 200
    temp = np.linspace(-10.0, 70.0, n)
    raw = 0.02 * rng.standard_normal((n, 3))
    p = {"INS_TCAL2_ENABLE": 1, "INS_TCAL2_TMIN": 0.0, "INS_TCAL2_TMAX": 60.0,
         "INS_GYR2OFFS_X": 0.01, "INS_GYR2OFFS_Y": -0.02, "INS_GYR2OFFS_Z": 0.005,
         "INS_GYR2_CALTEMP": 25.0, "AHRS_ORIENTATION": 8}  # fmt: skip
    p.update({f"INS_TCAL2_GYR{k}_{a}": 10.0 ** (3 - k) * (1 + j) for k in (1, 2, 3)
              for j, a in enumerate("XYZ")})  # fmt: skip
    body = ap.correct(raw, temp, p, 1)
    # by hand: v - P(clip(T)-35) + P(clip(CALTEMP)-35) - offsets, then roll 180°
    c = np.array([[p[f"INS_TCAL2_GYR{k}_{a}"] for a in "XYZ"] for k in (1, 2, 3)]) * 1e-6
    poly = lambda x: (c[0] + (c[1] + c[2] * x) * x) * x  # noqa: E731
    x = np.clip(temp, 0.0, 60.0)[:, None] - 35.0
    v = raw - poly(x) + poly(np.array(25.0 - 35.0)) - [0.01, -0.02, 0.005]
    np.testing.assert_allclose(body, v * [1, -1, -1], atol=2e-7)
    np.testing.assert_allclose(ap.uncorrect(body, temp, p, 1), raw, atol=2e-7)
    p["INS_TCAL2_ENABLE"] = 2  # learning: no correction applied
    np.testing.assert_allclose(
        ap.correct(raw, temp, p, 1), (raw - [0.01, -0.02, 0.005]) * [1, -1, -1], atol=1e-7
    )


def _ramp_run(seed: int = 0):
    """A 4 h run, 10 Hz, temperature ramping -20 → 60 °C and back, bias a cubic in T."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 4 * 3600.0, 0.1)
    temp = 20.0 + 40.0 * np.sin(2 * np.pi * t / t[-1])
    bias = 0.01 + 4e-4 * (temp - 20) + 3e-6 * (temp - 20) ** 2 - 4e-8 * (temp - 20) ** 3
    rate = bias + 2e-3 * rng.standard_normal(t.size)
    pt_t = t[::10]
    return prepare_arrays("ramp", t, rate, 0.1, pt_t, np.interp(pt_t, t, temp), PipelineConfig())


def test_firmware_scores_run_each_update_rule() -> None:
    run = _ramp_run()
    p3 = Poly3((0.01, 4e-4, 3e-6, -4e-8), 20.0, -20.0, 60.0)
    metrics = {"compensated_streaming": {"rms_deg_per_s": 1.0, "drift_pp_deg_per_s": 1.0,
                                         "bias_stability_deg_per_h": 1.0}}  # fmt: skip
    add_firmware_metrics(p3, run, metrics, 3.6)
    form, fw_px4, fw_ap = (metrics[f"firmware_{k}"] for k in ("poly3", "px4", "ardupilot"))
    # ArduPilot corrects every sample: the cubic itself, up to float32
    assert fw_ap["drift_pp_deg_per_s"] == pytest.approx(form["drift_pp_deg_per_s"], rel=1e-3)
    # PX4 holds the offsets up to 1 °C stale: it leaves the slope times up to 1 °C more
    assert fw_px4["drift_pp_deg_per_s"] > 1.05 * form["drift_pp_deg_per_s"]
    assert "1 degC" in fw_px4["update_rule"] and "every sample" in fw_ap["update_rule"]
    # the held PX4 offset never lags the cubic by more than 1 °C of its slope (+ float32)
    t = run.raw_t
    gap = np.abs(firmware_offset_fn(p3, run, "px4")(t) - firmware_offset_fn(p3, run, "poly3")(t))
    slope = np.abs(4e-4 + 2 * 3e-6 * 60 + 3 * 4e-8 * 60**2)
    assert np.max(gap[t > 10.0]) <= 1.02 * slope


def test_parameter_sets_reproduce_the_cubic() -> None:
    """Both sets, evaluated by the firmware rules, give back b(T) (to float32)."""
    p3 = Poly3((0.02, 3e-4, -2e-6, 1e-8), 25.0, 5.0, 55.0)
    temps = np.linspace(0.0, 60.0, 121)
    want = p3.predict(temps) * np.pi / 180
    v = {k: x for k, (x, _ty) in px4_parameter_set([p3, p3, p3], 2, 99).items()}
    got = px4.TcGyro.from_params(v, 2).offsets(temps)
    np.testing.assert_allclose(got[:, 1], want, rtol=1e-5, atol=1e-9)
    v = {k: x for k, (x, _ty) in ardupilot_parameter_set([p3], 1).items()}
    got = ap.gyro_offsets(v, 1)[0] + ap.Tcal.from_params(v, 1).correction(
        temps, v["INS_GYR2_CALTEMP"]
    )[:, 0]
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-9)
    assert list(v)[0] == "INS_TCAL2_ENABLE"
