"""FLP filter: AR estimation, order selection, causality, streaming, noise reduction."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import signal

from gyrolab.compensation.flp import ForwardLinearPredictor, burg, yule_walker
from gyrolab.errors import InputError

AR2 = [1.0, -1.5, 0.75]  # poles at 0.866 exp(+-j 0.52): a resonant, stable AR(2)


def _ar(a: list[float], n: int, seed: int) -> np.ndarray:
    return signal.lfilter([1.0], a, np.random.default_rng(seed).standard_normal(n))


def _ar_plus_noise(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    s = 0.2 * signal.lfilter([1.0], [1.0, -0.98], rng.standard_normal(n))
    return s + rng.standard_normal(n), s


@pytest.mark.parametrize("fit", [burg, yule_walker])
def test_ar2_coefficients_recovered(fit) -> None:  # noqa: ANN001
    x = _ar(AR2, 20_000, 1)
    a_all, err = fit(x - x.mean(), 6)
    np.testing.assert_allclose(a_all[2, :3], AR2, atol=0.02)
    assert err[2] == pytest.approx(1.0, rel=0.05)  # innovation variance
    assert np.all(np.diff(err) <= 1e-12)  # error power never increases with order


def test_mdl_selects_true_order() -> None:
    x = _ar([1.0, -0.9, 0.5, -0.3], 20_000, 2)
    flp = ForwardLinearPredictor(criterion="mdl", max_order=15).fit(x)
    assert flp.order == 3
    np.testing.assert_allclose(flp.coef, [0.9, -0.5, 0.3], atol=0.03)
    aic = ForwardLinearPredictor(criterion="aic", max_order=15).fit(x)
    assert aic.order >= 3  # AIC is never more parsimonious than MDL here


def test_causal() -> None:
    x, _ = _ar_plus_noise(3000, 3)
    flp = ForwardLinearPredictor(max_order=20).fit(x)
    y = flp.filter(x)
    for n0 in (0, 1, 500, 2999):
        x2 = x.copy()
        x2[n0:] += np.random.default_rng(n0).standard_normal(x.size - n0) * 10
        flp.reset()
        y2 = flp.filter(x2)
        # the output at n0 is a prediction made before x[n0]: unchanged up to and at n0
        np.testing.assert_array_equal(y2[: n0 + 1], y[: n0 + 1])
        if n0 < x.size - 1:
            assert not np.allclose(y2[n0 + 1 :], y[n0 + 1 :])


def test_streaming_equals_batch() -> None:
    x, _ = _ar_plus_noise(5000, 4)
    flp = ForwardLinearPredictor(max_order=20).fit(x[:2000])
    batch = flp.filter(x)
    flp.reset()
    rng = np.random.default_rng(0)
    cuts = np.sort(rng.choice(np.arange(1, x.size), 40, replace=False))
    blocks = [flp.filter(b) for b in np.split(x, cuts)]
    np.testing.assert_allclose(np.concatenate(blocks), batch, rtol=0, atol=1e-12)
    flp.reset()
    samples = np.array([flp.step(v) for v in x[:300]])
    np.testing.assert_allclose(samples, batch[:300], rtol=0, atol=1e-12)


def test_reduces_noise_on_held_out_ar_plus_noise() -> None:
    """Fit on one realisation, apply to another: closer to the clean AR signal."""
    cal, _ = _ar_plus_noise(20_000, 5)
    x, s = _ar_plus_noise(20_000, 6)
    flp = ForwardLinearPredictor(max_order=40).fit(cal)
    y = flp.filter(x)
    assert np.var(y) < 0.5 * np.var(x)
    mse_in = np.mean((x - s) ** 2)
    mse_out = np.mean((y - s) ** 2)
    assert mse_out < 0.3 * mse_in, (mse_in, mse_out)
    # the output variance is the input variance less the prediction-error power
    assert np.var(y) == pytest.approx(np.var(x) - flp.error_variance, rel=0.1)


def test_bandwidth() -> None:
    cal, _ = _ar_plus_noise(20_000, 7)
    flp = ForwardLinearPredictor(max_order=40).fit(cal)
    fs = 1000.0 / 3600.0  # the paper's 1000 points per hour
    bw = flp.bandwidth_hz(fs)
    assert 0 < bw < 0.1 * fs  # a smoothing low-pass
    assert flp.bandwidth_hz(2 * fs) == pytest.approx(2 * bw)  # scales with the rate
    f, h = flp.frequency_response(fs)
    g = np.abs(h)
    assert np.all(g[f > bw * 1.01] < g.max() / np.sqrt(2))
    assert flp.passband_hz(fs) == (0.0, bw)


def test_save_load_round_trip() -> None:
    x, _ = _ar_plus_noise(4000, 8)
    flp = ForwardLinearPredictor(max_order=12, criterion="mdl").fit(x)
    again = ForwardLinearPredictor.from_dict(json.loads(json.dumps(flp.to_dict())))
    np.testing.assert_array_equal(again.filter(x), flp.filter(x))


def test_bad_input() -> None:
    with pytest.raises(InputError, match="NaN"):
        ForwardLinearPredictor().fit(np.array([1.0, np.nan] * 100))
    with pytest.raises(InputError, match="too short"):
        ForwardLinearPredictor(max_order=32).fit(np.arange(20.0))
    with pytest.raises(InputError, match="constant"):
        ForwardLinearPredictor(max_order=4).fit(np.ones(100))
    with pytest.raises(InputError, match="before fit"):
        ForwardLinearPredictor().filter(np.ones(10))
