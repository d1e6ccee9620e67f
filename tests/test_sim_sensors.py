"""PT100 (IEC 60751 Callendar–Van Dusen) and ADC conversions."""

from __future__ import annotations

import numpy as np
import pytest

from gyrolab.sim.sensors import AdcModel, cvd_resistance, cvd_temperature


@pytest.mark.parametrize(
    ("t_c", "r_ohm"), [(-40.0, 84.27), (0.0, 100.00), (60.0, 123.24), (100.0, 138.51)]
)
def test_cvd_matches_iec_60751_table(t_c: float, r_ohm: float) -> None:
    assert cvd_resistance(t_c) == pytest.approx(r_ohm, abs=0.005)


def test_cvd_inverse_round_trips_over_full_range() -> None:
    t = np.linspace(-200.0, 850.0, 100_001)
    back = cvd_temperature(cvd_resistance(t))
    assert np.max(np.abs(back - t)) < 1e-6
    # scalars in, scalars out
    assert isinstance(cvd_temperature(100.0), float)
    assert cvd_temperature(cvd_resistance(-123.4)) == pytest.approx(-123.4, abs=1e-6)


def test_cvd_inverse_is_monotonic_near_zero() -> None:
    r = np.linspace(99.0, 101.0, 2001)
    assert np.all(np.diff(cvd_temperature(r)) > 0)


def test_adc_round_trip_within_one_lsb_and_saturates() -> None:
    adc = AdcModel(bits=24, vref_v=2.5, gain_v_per_dps=0.01, offset_v=0.001)
    x = np.linspace(-200.0, 200.0, 10_001)
    c = adc.dps_to_counts(x)
    assert c.dtype == np.int32
    assert np.max(np.abs(adc.counts_to_dps(c) - x)) <= 0.5 * adc.lsb_dps * (1 + 1e-9)
    big = adc.dps_to_counts(np.array([1e6, -1e6]))
    assert big.tolist() == [2**23 - 1, -(2**23)]


def test_adc_rejects_bad_parameters() -> None:
    with pytest.raises(ValueError):
        AdcModel(bits=40)
    with pytest.raises(ValueError):
        AdcModel(gain_v_per_dps=0.0)


def test_scalar_and_array_paths_agree() -> None:
    for t in (-150.0, -40.0, -0.5, 0.0, 60.0, 500.0):
        r = cvd_resistance(t)
        assert r == cvd_resistance(np.array([t]))[0]
        assert cvd_temperature(r) == pytest.approx(cvd_temperature(np.array([r]))[0], abs=1e-12)
