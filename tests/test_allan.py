"""Allan deviation: Stable32 and allantools agreement, EDF, confidence coverage, noise terms."""

from __future__ import annotations

from pathlib import Path

import allantools
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gyrolab.errors import InputError
from gyrolab.numerics.allan import allan_deviation
from gyrolab.numerics.confidence import edf_greenhall
from gyrolab.numerics.noise_terms import noise_terms
from gyrolab.numerics.phase import tau_grid


def _ocxo(shared_dir: Path) -> np.ndarray:
    f = np.loadtxt(shared_dir / "ref" / "allan" / "ocxo_frequency.txt", comments="#")
    return f / 1e7 - 1.0


def _stable32(shared_dir: Path, name: str) -> np.ndarray:
    # columns: AF, Tau, #, Alpha, Min Sigma, Sigma, Max Sigma
    return np.loadtxt(shared_dir / "ref" / "allan" / name, comments="#")


def flicker_noise(n: int, fs: float, b: float, rng: np.random.Generator) -> np.ndarray:
    """Flicker rate noise whose IEEE 952 (two-sided) PSD is B^2 / (2 pi f): one-sided
    B^2 / (pi f), synthesised by shaping white Gaussian spectra."""
    f = np.fft.rfftfreq(n, 1.0 / fs)
    s = np.zeros_like(f)
    s[1:] = b**2 / (np.pi * f[1:])
    c = np.sqrt(s * fs * n / 4.0) * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size))
    return np.fft.irfft(c, n)


@pytest.mark.parametrize(
    ("name", "overlapping"),
    [("stable32_oadev_alltau.txt", True), ("stable32_adev_alltau.txt", False)],
)
def test_matches_stable32(shared_dir: Path, name: str, overlapping: bool) -> None:
    y = _ocxo(shared_dir)
    ref = _stable32(shared_dir, name)
    r = allan_deviation(y, 1.0, taus=ref[:, 1], overlapping=overlapping)
    np.testing.assert_array_equal(r.m, ref[:, 0].astype(int))
    np.testing.assert_array_equal(r.n, ref[:, 2].astype(int))
    # Stable32 prints 5 significant digits: 1e-4 relative is the resolution of the file
    np.testing.assert_allclose(r.dev, ref[:, 5], rtol=1e-4, atol=0)


def test_noise_id_agrees_with_stable32(shared_dir: Path) -> None:
    """Stable32 identifies alpha by lag-1 ACF where >= 30 averages exist (B1 ratio beyond)."""
    y = _ocxo(shared_dir)
    ref = _stable32(shared_dir, "stable32_oadev_alltau.txt")
    r = allan_deviation(y, 1.0, taus=ref[:, 1])
    enough = (y.size // ref[:, 0]) >= 30
    agree = np.mean(r.alpha[enough] == ref[enough, 3])
    assert enough.sum() > 100
    assert agree >= 0.95, agree


@pytest.mark.parametrize("taus", ["octave", "decade"])
@pytest.mark.parametrize("overlapping", [True, False])
def test_matches_allantools_random(taus: str, overlapping: bool) -> None:
    rng = np.random.default_rng(7)
    y = 0.02 * rng.standard_normal(50_000) + 1e-4 * np.cumsum(rng.standard_normal(50_000)) + 5.0
    r = allan_deviation(y, 200.0, taus=taus, overlapping=overlapping)
    fn = allantools.oadev if overlapping else allantools.adev
    t, d, _, n = fn(y, rate=200.0, data_type="freq", taus=taus)
    k = min(len(t), len(r.taus))
    assert k >= 5
    np.testing.assert_allclose(r.taus[:k], t[:k], rtol=1e-12)
    np.testing.assert_allclose(r.dev[:k], d[:k], rtol=1e-9)
    np.testing.assert_array_equal(r.n[:k], n[:k])


def test_angle_input_equals_rate_input() -> None:
    rng = np.random.default_rng(2)
    rate = 50.0
    y = rng.standard_normal(20_000) + 0.5
    angle = np.concatenate([[0.0], np.cumsum(y)]) / rate
    a = allan_deviation(y, rate, taus="all", confidence=None)
    b = allan_deviation(angle, rate, taus="all", data_type="angle", confidence=None)
    np.testing.assert_allclose(a.dev, b.dev, rtol=1e-8)
    t, d, _, _ = allantools.oadev(angle, rate=rate, data_type="phase", taus="octave")
    c = allan_deviation(angle, rate, data_type="angle")
    np.testing.assert_allclose(c.dev, d[: c.dev.size], rtol=1e-9)


def test_large_offset_keeps_float64_accuracy() -> None:
    """A 1e4 bias on unit noise over 2 M samples: the compensated phase keeps 1e-9."""
    rng = np.random.default_rng(4)
    y = rng.standard_normal(2_000_000)
    a = allan_deviation(y, 1.0, confidence=None)
    b = allan_deviation(y + 1e4, 1.0, confidence=None)
    np.testing.assert_allclose(b.dev, a.dev, rtol=1e-9)


def test_tau_grids() -> None:
    assert tau_grid(1001, 10.0, "octave").tolist() == [1, 2, 4, 8, 16, 32, 64, 128, 256]
    assert tau_grid(1001, 10.0, "decade").tolist() == [1, 2, 4, 10, 20, 40, 100, 200, 400]
    assert tau_grid(101, 1.0, "all").tolist() == list(range(1, 51))
    assert tau_grid(101, 10.0, [0.1, 0.1, 0.25, 99.0]).tolist() == [1, 2]  # rounded, deduped


@pytest.mark.parametrize("alpha", [-2, -1, 0, 1, 2])
@pytest.mark.parametrize("overlapping", [True, False])
def test_edf_matches_allantools(alpha: int, overlapping: bool) -> None:
    for n in (1000, 20_000, 1_000_000):
        for m in (1, 2, 5, 30, 200, 499):
            ours = edf_greenhall(alpha, m, n, overlapping=overlapping)
            try:
                ref = allantools.edf_greenhall(alpha, 2, m, n, overlapping=overlapping)
            except NotImplementedError:  # alpha = 2 with < 3 terms: ours sums eq. 13 exactly
                assert alpha == 2 and 0 < ours < 10
                continue
            assert ours == pytest.approx(ref, rel=1e-12), (n, m)


def test_confidence_interval_coverage_white_noise() -> None:
    """With correct EDF, the 68.3 % interval covers the true deviation ~68 % of the time."""
    rng = np.random.default_rng(11)
    true_tau = 16.0  # white rate noise, unit density: sigma(tau) = 1 / sqrt(tau)
    hits = 0
    trials = 300
    for _ in range(trials):
        y = rng.standard_normal(2048)
        r = allan_deviation(y, 1.0, taus=[true_tau], alpha=0)
        hits += int(r.dev_lo[0] <= 1 / np.sqrt(true_tau) <= r.dev_hi[0])
    assert 0.60 <= hits / trials <= 0.76, hits / trials


def test_bounds_bracket_and_alpha_identified() -> None:
    rng = np.random.default_rng(5)
    r = allan_deviation(rng.standard_normal(100_000), 10.0)
    ok = np.isfinite(r.edf)
    assert ok.all()
    assert np.all(r.dev_lo < r.dev) and np.all(r.dev < r.dev_hi)
    assert np.all(r.alpha[r.m <= 1000] == 0)  # white rate noise: alpha = 0
    lo, hi = allantools.confidence_interval(r.dev[3], r.edf[3])
    assert r.dev_lo[3] == pytest.approx(lo, rel=1e-10)
    assert r.dev_hi[3] == pytest.approx(hi, rel=1e-10)


def test_noise_terms_white_and_rate_random_walk() -> None:
    rng = np.random.default_rng(3)
    fs, n = 100.0, 1 << 20
    # K large enough that rate random walk dominates from ~20 s, five octaves below T/10
    # (with 1e-5 it would take over only in the last octave pair before T/10, where the
    # confidence intervals cannot tell +1/2 from a floor: not identifiable, by design)
    big_n, big_k = 1e-3, 1e-4  # deg/sqrt(s), deg/s/sqrt(s)
    white = big_n * np.sqrt(fs) * rng.standard_normal(n)
    r = allan_deviation(white, fs)
    t = noise_terms(r)
    assert t.N == pytest.approx(big_n, rel=0.03)
    assert t.deg_h()["arw_deg_per_sqrt_h"] == pytest.approx(60 * big_n, rel=0.03)
    rrw = np.cumsum(big_k / np.sqrt(fs) * rng.standard_normal(n))
    r = allan_deviation(white + rrw, fs)
    for method in ("slope", "fit"):
        t = noise_terms(r, method=method, terms=("N", "B", "K"))
        assert t.N == pytest.approx(big_n, rel=0.05), method
        assert t.K == pytest.approx(big_k, rel=0.25), method


def test_noise_terms_flicker_floor() -> None:
    rng = np.random.default_rng(8)
    fs, n, b = 100.0, 1 << 20, 2e-4
    y = flicker_noise(n, fs, b, rng) + 1e-4 * np.sqrt(fs) * rng.standard_normal(n)
    r = allan_deviation(y, fs)
    t = noise_terms(r)
    assert t.B == pytest.approx(b, rel=0.2)
    assert t.deg_h()["bias_instability_deg_per_h"] == pytest.approx(3600 * t.B)
    tf = noise_terms(r, method="fit", terms=("N", "B", "K"))
    assert tf.B == pytest.approx(b, rel=0.3)
    assert tf.N == pytest.approx(1e-4, rel=0.1)


def test_slope_rule_reports_nan_without_region() -> None:
    rng = np.random.default_rng(9)
    r = allan_deviation(rng.standard_normal(10_000), 1.0)  # pure white: no +1/2, +1 region
    t = noise_terms(r)
    assert np.isnan(t.K) and np.isnan(t.R)
    assert np.isfinite(t.N)


def test_bad_input() -> None:
    with pytest.raises(InputError, match="infinite"):
        allan_deviation(np.array([1.0, np.inf, 2.0, 3.0]), 1.0)
    with pytest.raises(InputError, match="too short"):
        allan_deviation(np.array([1.0, np.nan, np.nan, 2.0]), 1.0)
    with pytest.raises(InputError, match="too short"):
        allan_deviation(np.array([1.0, 2.0]), 1.0)
    with pytest.raises(InputError, match="too short"):
        allan_deviation(np.arange(100.0), 1.0, taus=[1000.0])
    with pytest.raises(InputError, match="constant"):
        allan_deviation(np.full(1000, 3.0), 1.0)
    with pytest.raises(InputError, match="rate"):
        allan_deviation(np.ones(100), 0.0)


def test_memory_is_one_phase_array() -> None:
    """Peak traced memory: the phase array plus small change, under half of allantools'."""
    import tracemalloc

    y = np.random.default_rng(6).standard_normal(2_000_000) + 1.0
    allan_deviation(y[:1000], 1.0)  # compile outside the measurement
    tracemalloc.start()
    allan_deviation(y, 100.0)
    ours = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    tracemalloc.start()
    allantools.oadev(y, rate=100.0, data_type="freq", taus="octave")
    peer = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert ours < 8 * y.size + 12e6  # one float64 phase array + noise-ID scratch
    assert ours <= 0.5 * peer, (ours, peer)


def test_to_dict_round_trips_through_json() -> None:
    import json

    rng = np.random.default_rng(10)
    r = allan_deviation(rng.standard_normal(5000), 2.0)
    d = json.loads(json.dumps(r.to_dict()))
    np.testing.assert_allclose(d["dev"], r.dev)
    assert d["duration_s"] == pytest.approx(2500.0)
    t = json.loads(json.dumps(noise_terms(r).to_dict()))
    assert t["arw_deg_per_sqrt_h"] == pytest.approx(60 * t["N"])


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    n=st.integers(8, 3000),
    scale=st.floats(1e-6, 1e6),
    offset=st.floats(-1e3, 1e3),
)
def test_invariances(seed: int, n: int, scale: float, offset: float) -> None:
    """sigma(c (y + b)) = |c| sigma(y); reversing the record leaves it unchanged."""
    y = np.random.default_rng(seed).standard_normal(n)
    a = allan_deviation(y, 1.0, taus="all", confidence=None)
    # offset relative to the scale: float64 itself keeps ~1e-16 of |c y + b|
    b = allan_deviation(scale * (y + offset), 1.0, taus="all", confidence=None)
    r = allan_deviation(y[::-1], 1.0, taus="all", confidence=None)
    np.testing.assert_allclose(b.dev, scale * a.dev, rtol=1e-7)
    np.testing.assert_allclose(r.dev, a.dev, rtol=1e-9)


@pytest.mark.parametrize("overlapping", [True, False])
def test_gaps_skip_exactly_the_terms_that_touch_them(overlapping: bool) -> None:
    """NaN samples: the kernel sums the runs of whole terms between the gaps; every kept
    term and count equals the definition (each term i, i + stride, ... whose 2m samples are
    all present), on records with several gaps, one at each end."""
    rng = np.random.default_rng(12)
    y = rng.standard_normal(600)
    for a, b in ((0, 2), (100, 103), (104, 110), (333, 334), (597, 600)):
        y[a:b] = np.nan
    r = allan_deviation(y, 2.0, taus="all", overlapping=overlapping, confidence=None)
    bad = np.isnan(y)
    x = np.concatenate([[0.0], np.cumsum(np.where(bad, 0.0, y - np.nanmean(y)))]) / 2.0
    for m, dev, n in zip(r.m, r.dev, r.n, strict=True):
        step = 1 if overlapping else m
        keep = [i for i in range(0, y.size + 1 - 2 * m, step) if not bad[i : i + 2 * m].any()]
        assert n == len(keep)
        if keep:
            d = np.array([x[i + 2 * m] - 2 * x[i + m] + x[i] for i in keep])
            assert dev == pytest.approx(np.sqrt(np.mean(d**2) / 2) / (m / 2.0), rel=1e-9)
    assert r.missing == int(bad.sum()) and r.kind == ("oadev" if overlapping else "adev")
