"""signal_metrics on synthetic signals with known ARW, bias instability and staircase drift."""

from __future__ import annotations

import numpy as np
import pytest

from gyrolab.compensation.metrics import METRIC_KEYS, signal_metrics
from gyrolab.errors import InputError
from gyrolab.numerics.allan import allan_deviation
from gyrolab.numerics.averaging import block_means


def _flicker(n: int, fs: float, b: float, rng: np.random.Generator) -> np.ndarray:
    """IEEE 952 flicker: two-sided PSD B^2 / (2 pi f), i.e. one-sided B^2 / (pi f). Made 8x
    longer and cut, so that the record holds frequencies below 1/T like real flicker does."""
    n_out, n = n, 8 * n
    f = np.fft.rfftfreq(n, 1.0 / fs)
    s = np.zeros_like(f)
    s[1:] = b**2 / (np.pi * f[1:])
    c = np.sqrt(s * fs * n / 4.0) * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size))
    return np.fft.irfft(c, n)[:n_out]


def test_known_arw_and_bias_instability() -> None:
    rng = np.random.default_rng(21)
    fs, n = 10.0, 1 << 18
    arw = 0.05  # deg/sqrt(h)
    b = 2.0  # deg/h
    white = (arw / 60.0) * np.sqrt(fs) * rng.standard_normal(n)  # N in deg/sqrt(s)
    y = white + _flicker(n, fs, b / 3600.0, rng)
    m = signal_metrics(y, fs)
    assert tuple(m) == METRIC_KEYS
    assert m["arw_deg_per_sqrt_h"] == pytest.approx(arw, rel=0.1)
    # flicker variance at long tau has few degrees of freedom: 25 % is the honest tolerance
    assert m["bias_instability_deg_per_h"] == pytest.approx(b, rel=0.25)
    assert m["rms_deg_per_s"] == pytest.approx(np.sqrt(np.mean(y**2)))
    # a precomputed Allan curve gives the same numbers
    assert signal_metrics(y, fs, allan=allan_deviation(y, fs)) == m


def test_staircase_bias_stability_and_drift() -> None:
    """The paper's case: 11 hourly steps spanning 0.0287 deg/s at 1000 points/h."""
    fs = 1000.0 / 3600.0
    levels = np.linspace(0.0, 0.0287, 11)
    y = np.repeat(levels, 1000) + 1e-6 * np.random.default_rng(0).standard_normal(11_000)
    m = signal_metrics(y, fs)  # 3.6 s window = one sample here
    assert m["drift_pp_deg_per_s"] == pytest.approx(0.0287, rel=1e-3)
    expected = np.sqrt(np.sum((levels - levels.mean()) ** 2) * 1000 / (11_000 - 1)) * 3600
    assert m["bias_stability_deg_per_h"] == pytest.approx(expected, rel=1e-3)
    assert 31.0 < m["bias_stability_deg_per_h"] < 33.5  # docs/allan.md: ~31-33 deg/h
    # the IEEE floor of the same signal is a different, much smaller number
    assert m["bias_instability_deg_per_h"] < 1.0


def test_windows() -> None:
    x = np.arange(10.0)
    np.testing.assert_allclose(block_means(x, 2.0, 1.5), [1.0, 4.0, 7.0])  # 3-sample windows
    rng = np.random.default_rng(1)
    y = rng.standard_normal(100_000)
    short = signal_metrics(y, 100.0, stability_window_s=0.01)
    long = signal_metrics(y, 100.0, stability_window_s=10.0)
    # white noise: std of the means falls as 1/sqrt(window)
    ratio = short["bias_stability_deg_per_h"] / long["bias_stability_deg_per_h"]
    assert ratio == pytest.approx(np.sqrt(1000), rel=0.1)
    d = signal_metrics(y, 100.0, drift_window_s=100.0)["drift_pp_deg_per_s"]
    assert d == pytest.approx(np.ptp(y[:100_000].reshape(10, -1).mean(axis=1)))


def test_bad_input() -> None:
    with pytest.raises(InputError, match="NaN"):
        signal_metrics(np.array([0.0, np.nan] * 100), 1.0)
    with pytest.raises(InputError, match="constant"):
        signal_metrics(np.zeros(1000), 1.0)
    with pytest.raises(InputError, match="too short"):
        signal_metrics(np.random.default_rng(0).standard_normal(100), 1.0, drift_window_s=80.0)
