"""MDEV, TDEV, HDEV, TOTDEV (and gap-aware OADEV) against allantools, NIST SP 1065 and
Stable32; gaps as gaps; several axes; EDF of the modified variances; noise per plateau."""

from __future__ import annotations

import warnings
from pathlib import Path

import allantools
import numpy as np
import pytest

from gyrolab.errors import InputError
from gyrolab.numerics.confidence import edf_greenhall
from gyrolab.numerics.deviations import KINDS, deviation
from gyrolab.numerics.phase import gap_filled

PEER = {
    "oadev": allantools.oadev,
    "mdev": allantools.mdev,
    "tdev": allantools.tdev,
    "hdev": allantools.ohdev,
    "totdev": allantools.totdev,
}


def _data(n: int = 4000, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    # white + random-walk rate, an offset and a ramp: every estimator must be blind to the
    # offset, and the curves have more than one slope
    return rng.normal(size=n) + 0.01 * np.cumsum(rng.normal(size=n)) + 3.0 + 1e-4 * np.arange(n)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("taus", ["octave", "decade"])
def test_matches_allantools(kind: str, taus: str) -> None:
    y = _data()
    r = deviation(y, 10.0, kind, taus=taus)
    t, d, _e, n = PEER[kind](y, rate=10.0, data_type="freq", taus=r.taus)
    # allantools drops a last tau that rests on a single term; every other one is compared
    keep = np.isin(r.taus, t)
    assert keep.sum() >= r.taus.size - 1
    np.testing.assert_allclose(r.dev[keep], d, rtol=1e-10, atol=0)
    np.testing.assert_array_equal(r.n[keep], n)
    # angle (phase) input: the same curve
    x = np.concatenate(([0.0], np.cumsum(y) / 10.0))
    ra = deviation(x, 10.0, kind, taus=r.taus, data_type="angle", confidence=None)
    np.testing.assert_allclose(ra.dev, r.dev, rtol=1e-10)
    assert np.all(r.dev_lo < r.dev) and np.all(r.dev < r.dev_hi)


# NIST SP 1065 (Riley 2008), table 30: the 9-point "NBS" fractional-frequency set, tau0 = 1,
# tau = 1, 2; table 31: 1000 points of the Park-Miller generator, tau = 1, 10, 100. The
# handbook's values (Stable32's author) print 7 significant digits.
NBS9 = [892, 809, 823, 798, 671, 644, 883, 903, 677]
SP1065_T30 = {
    "oadev": [91.22945, 85.95287],
    "mdev": [91.22945, 74.78849],
    "tdev": [52.67135, 86.35831],
    "hdev": [70.80607, 85.61487],
    "totdev": [91.22945, 93.90379],
}
SP1065_T31 = {
    "oadev": [2.922319e-01, 9.159953e-02, 3.241343e-02],
    "mdev": [2.922319e-01, 6.172376e-02, 2.170921e-02],
    "tdev": [1.687202e-01, 3.563623e-01, 1.253382e00],
    "hdev": [2.943883e-01, 9.581083e-02, 3.237638e-02],
    "totdev": [2.922319e-01, 9.134743e-02, 3.406530e-02],
}


def _park_miller(n: int = 1000) -> np.ndarray:
    seed, out = 1234567890, []
    for _ in range(n):
        out.append(seed / 2147483647)
        seed = (16807 * seed) % 2147483647
    return np.array(out)


@pytest.mark.parametrize("kind", KINDS)
def test_matches_sp1065_tables(kind: str) -> None:
    r = deviation(np.array(NBS9, float), 1.0, kind, taus=[1, 2], confidence=None)
    np.testing.assert_allclose(r.dev, SP1065_T30[kind], rtol=1e-6)
    r = deviation(_park_miller(), 1.0, kind, taus=[1, 10, 100], confidence=None)
    np.testing.assert_allclose(r.dev, SP1065_T31[kind], rtol=1e-6)


def test_oadev_matches_stable32_ocxo(shared_dir: Path) -> None:
    f = np.loadtxt(shared_dir / "ref" / "allan" / "ocxo_frequency.txt", comments="#") / 1e7 - 1
    ref = np.loadtxt(shared_dir / "ref" / "allan" / "stable32_oadev_alltau.txt", comments="#")
    r = deviation(f, 1.0, "oadev", taus=ref[:, 1], confidence=None)
    np.testing.assert_array_equal(r.n, ref[:, 2].astype(int))
    np.testing.assert_allclose(r.dev, ref[:, 5], rtol=1e-4)  # the file prints 5 digits


@pytest.mark.parametrize("kind", KINDS)
def test_gap_pools_the_segments(kind: str) -> None:
    """A gap splits the record: the result pools the terms of the two gap-free parts, which
    allantools computes on each part alone (nothing interpolated into the gap)."""
    y = _data(3000, seed=4)
    y[1200:1260] = np.nan
    a, b = y[:1200], y[1260:]
    r = deviation(y, 1.0, kind, taus=[1, 2, 4, 8, 16, 64], confidence=None)
    assert r.missing == 60
    pooled, count = [], []
    for tau in r.taus:
        s = c = 0.0
        for seg in (a, b):
            _t, d, _e, n = PEER[kind](seg, rate=1.0, data_type="freq", taus=[tau])
            v = (d[0] * np.sqrt(3) / tau) ** 2 if kind == "tdev" else d[0] ** 2
            s += v * n[0]
            c += n[0]
        pooled.append(np.sqrt(s / c) * (tau / np.sqrt(3) if kind == "tdev" else 1.0))
        count.append(c)
    np.testing.assert_allclose(r.dev, pooled, rtol=1e-10)
    np.testing.assert_array_equal(r.n, count)


def test_gap_filled_places_samples_by_index() -> None:
    out = gap_filled(np.array([10, 11, 14]), np.array([1.0, 2.0, 3.0]))
    np.testing.assert_array_equal(np.isnan(out), [False, False, True, True, False])
    assert out[4] == 3.0


def test_two_dimensional_input_is_one_result_per_axis() -> None:
    rng = np.random.default_rng(2)
    y = rng.normal(size=(2000, 3)) * np.array([1.0, 2.0, 0.5])
    y[500:510, 1] = np.nan  # a gap in one axis only
    res = deviation(y, 100.0, "mdev")
    assert isinstance(res, list) and len(res) == 3
    for j, r in enumerate(res):
        one = deviation(y[:, j], 100.0, "mdev")
        np.testing.assert_array_equal(r.dev, one.dev)
    assert res[1].missing == 10 and res[0].missing == 0
    np.testing.assert_allclose(res[1].dev[0] / res[0].dev[0], 2.0, rtol=0.1)


@pytest.mark.parametrize("d", [2, 3])
def test_modified_edf_matches_allantools(d: int) -> None:
    worst = 0.0
    for alpha in (2, 1, 0, -1, -2):
        for n in (1000, 100_000):
            for m in (1, 2, 5, 30, 200):
                ours = edf_greenhall(alpha, m, n, overlapping=True, d=d, modified=True)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    ref = allantools.edf_greenhall(alpha, d, m, n, overlapping=True, modified=True)
                worst = max(worst, abs(ours / ref - 1.0))
    assert worst < 1e-12


def test_totdev_edf_is_sp1065_table7() -> None:
    rng = np.random.default_rng(3)
    r = deviation(rng.normal(size=4096), 1.0, "totdev", taus=[8, 16], alpha=0)
    np.testing.assert_allclose(r.edf, 1.5 * 4096 / r.m)  # white rate: b = 1.50, c = 0


def test_bad_input() -> None:
    with pytest.raises(InputError, match="unknown deviation"):
        deviation(np.ones(100), 1.0, "xdev")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="infinite"):
        deviation(np.r_[np.ones(100), np.inf], 1.0, "mdev")
    with pytest.raises(InputError, match="too short"):
        deviation(np.array([1.0, np.nan, np.nan, 2.0]), 1.0, "hdev")


def test_plateau_noise_on_a_simulated_run(tmp_path: Path) -> None:
    from gyrolab.cli import main
    from gyrolab.compensation.plateau_noise import plateau_noise
    from gyrolab.record.reader import read_recording

    f = tmp_path / "short.mcap"
    assert (
        main(["simulate", "--out", str(f), "--profile", "short", "--rate", "10", "--seed", "3"])
        == 0
    )
    rec = read_recording(f)
    rows = plateau_noise(rec)
    assert len(rows) == 12  # every step of the short profile ends soaked
    arw = np.array([p.arw_deg_per_sqrt_h for p in rows])
    # the simulator's ARW term (its default, docs/sim-model.md: 0.0523 deg/sqrt(h)) within 20 %
    np.testing.assert_allclose(arw, 0.0523, rtol=0.2)
    for p in rows:
        assert p.bi_lo_deg_per_h < p.bias_instability_deg_per_h < p.bi_hi_deg_per_h
        assert p.t_end - p.t_start >= 60.0 and p.missing == 0
