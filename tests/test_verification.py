"""What gyrolab predicts a flight controller reports (gyrolab.compensation.verification):
the MAVLink message's truncation toward zero in expectation (checked against draws), its
inverse and its gain; PX4's module over every gyro of a controller (a publication another
gyro triggers carries this gyro's offsets) keeping each within 1 °C of its cubic."""

from __future__ import annotations

import numpy as np
import pytest

from gyrolab.autopilot import px4
from gyrolab.compensation.verification import (
    expected_truncated,
    firmware_offsets,
    truncation_gain,
    untruncated,
)


def test_expected_truncation_its_inverse_and_gain() -> None:
    rng = np.random.default_rng(0)
    mu = np.array([-3.2, -0.7, -0.2, 0.0, 0.3, 0.5, 1.4, 6.0])
    for sigma in (0.4, 1.0, 2.5):
        draws = np.trunc(mu[:, None] + sigma * rng.standard_normal((mu.size, 200_000)))
        se = sigma / np.sqrt(200_000)
        np.testing.assert_allclose(expected_truncated(mu, sigma), draws.mean(axis=1), atol=5 * se)
        np.testing.assert_allclose(untruncated(expected_truncated(mu, sigma), sigma), mu, atol=1e-3)
        h = 1e-4
        num = (expected_truncated(mu + h, sigma) - expected_truncated(mu - h, sigma)) / (2 * h)
        np.testing.assert_allclose(truncation_gain(mu, sigma), num, atol=1e-5)
    # far from zero a constant half-step shift toward zero; at zero a compression
    assert expected_truncated(np.array([6.0]), 1.0)[0] == pytest.approx(5.5, abs=1e-6)
    from scipy.stats import norm

    at_zero = 2 * sum(norm.pdf(k) for k in range(1, 12))  # Σ φ(k) + φ(−k)
    assert truncation_gain(np.array([0.0]), 1.0)[0] == pytest.approx(at_zero, rel=1e-9)
    assert at_zero < 0.65


def test_px4_module_over_three_gyros_keeps_each_within_a_degree() -> None:
    ids = [11, 22, 33]
    p: dict[str, float] = {"TC_G_ENABLE": 1}
    for s, dev in enumerate(ids):
        p.update({f"TC_G{s}_ID": dev, f"TC_G{s}_TREF": 30.0, f"TC_G{s}_TMIN": 0.0,
                  f"TC_G{s}_TMAX": 60.0})  # fmt: skip
        for k in range(4):
            for a in range(3):
                p[f"TC_G{s}_X{k}_{a}"] = (0.01, 1e-3, 1e-5, 1e-7)[k] * (s + 1)
    t = np.arange(0.0, 3600.0, 0.5)
    gyros = [(dev, t, 10.0 + 0.01 * t + 0.37 * j) for j, dev in enumerate(ids)]
    pub_t, pubs = px4.module_publications(p, gyros, t[-1] + 1.0)
    alone_t, _alone = px4.publications(t, gyros[1][2], px4.TcGyro.from_params(p, 1), t[-1] + 1)
    assert pub_t.size > 1.5 * alone_t.size  # the other gyros' moves publish too
    for s, (dev, tt, temp) in enumerate(gyros):
        tc = px4.TcGyro.from_params(p, s)
        held = px4.held(tt, pub_t, pubs[dev])
        lag = np.abs(held - tc.offsets(temp))
        slope = np.abs(tc.offsets(temp + 1.0) - tc.offsets(temp)).max()
        assert lag.max() <= 1.01 * slope
        got = firmware_offsets("px4", p, s, tt, tt, temp, dev, controller=gyros)
        np.testing.assert_allclose(got, held, atol=1e-7)  # + CAL offsets: none set here
