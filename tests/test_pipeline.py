"""Compensation pipeline: decimation, causality, fit/apply, model directory format."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from gyrolab.compensation.apply import (
    compensate_offline,
    effective_bandwidth,
    streaming_block_means,
    streaming_compensate,
)
from gyrolab.compensation.config import PipelineConfig
from gyrolab.compensation.evaluate import evaluate
from gyrolab.compensation.firmware import fit_poly3, poly3_block_means
from gyrolab.compensation.fit import CompensationModel, Decomposition, fit
from gyrolab.compensation.model_dir import MODEL_FORMAT_VERSION, load_model, save_model
from gyrolab.compensation.prepare import (
    PreparedRun,
    causal_temperature,
    features,
    iter_rate_batches,
    prepare_file,
    prepare_run,
)
from gyrolab.errors import InputError
from gyrolab.numerics.averaging import BlockAverager, block_average
from gyrolab.record.reader import read_recording
from gyrolab.record.writer import RecordingWriter

torch.set_num_threads(1)

# small and fast, fixed (K, alpha): the GPSO search is exercised by the CLI test
SMALL = PipelineConfig(
    vmd_K=5,
    vmd_alpha=2000.0,
    ga_population=12,
    ga_generations=6,
    bp_max_iter=150,
    hidden=5,
    gpso_population=4,
    gpso_generations=1,
    # the networks' CV costs ten fits; the CLI test runs all four families
    causal_families=("poly", "structured"),
)


def true_bias(temp: np.ndarray) -> np.ndarray:
    """Bias (°/s) of the synthetic gyro: quadratic in case temperature."""
    d = temp - 25.0
    return 2e-3 + 3.8e-4 * d + 3.4e-6 * d * d


def case_temperature(t: np.ndarray, heating: bool) -> np.ndarray:
    """A first-order case response to a step: cooling 55 → -25 °C or heating the other way."""
    lo, hi, tau = -25.0, 55.0, 1500.0
    x = 1.0 - np.exp(-t / tau)
    return lo + (hi - lo) * x if heating else hi - (hi - lo) * x


def write_run(
    path: Path,
    seed: int,
    *,
    hours: float = 1.2,
    fs: float = 10.0,
    heating: bool = False,
    arw_deg_rt_h: float = 0.05,
    serial: str = "",
    part_number: str = "",
) -> Path:
    """A synthetic recording: bias(T) + white noise at ``fs``, PT100 at 1 Hz; ``serial``,
    ``part_number``: the unit's serial and model in the run record (none when empty)."""
    rng = np.random.default_rng(seed)
    n = int(hours * 3600 * fs)
    t = np.arange(n) / fs
    temp = case_temperature(t, heating)
    sigma = arw_deg_rt_h / 60.0 * np.sqrt(fs)  # °/s per sample from N (°/√h)
    rate = true_bias(temp) + rng.normal(0.0, sigma, n)
    run = {
        "op": "t",
        **({"unit_serial": serial} if serial else {}),
        **({"unit_model": part_number} if part_number else {}),
    }
    with RecordingWriter(path, start_time_ns=1_700_000_000 * 10**9, run=run) as w:
        blk = int(fs)
        for s in range(0, n, blk):
            w.write_rate_block(t[s], 1.0 / fs, s, rate[s : s + blk].astype(np.float32))
            w.write_pt100(t[s], 100.0, float(temp[s]) + rng.normal(0, 0.01))
    return path


def load(path: Path, cfg: PipelineConfig = SMALL) -> PreparedRun:
    return prepare_run(read_recording(path), cfg)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("runs")
    return {
        "cal": write_run(d / "cal.mcap", 1),
        "val": write_run(d / "val.mcap", 2),
        "heat": write_run(d / "heat.mcap", 3, heating=True),
    }


@pytest.fixture(scope="module")
def fitted(runs: dict[str, Path]) -> tuple[CompensationModel, Decomposition]:
    return fit(load(runs["cal"]), SMALL, seed=0)


# ------------------------------------------------------------------ building blocks


def test_block_average_means_gaps_and_partial_tail() -> None:
    fs, block = 10.0, 3.6
    t = np.arange(1000) / fs  # 100 s: 27 full blocks of 36 samples + 28 samples
    x = np.arange(1000, dtype=float)
    tb, xb, filled = block_average(t, x, block, 1 / fs)
    assert tb.size == 27 and filled == 0
    np.testing.assert_allclose(xb, x[: 27 * 36].reshape(27, 36).mean(axis=1))
    np.testing.assert_allclose(tb, (np.arange(27) + 0.5) * block)
    # drop the samples of block 5: it is filled by interpolation and counted
    keep = (t < 5 * block) | (t >= 6 * block)
    tb2, xb2, filled2 = block_average(t[keep], x[keep], block, 1 / fs)
    assert filled2 == 1 and tb2.size == 27
    assert xb2[5] == pytest.approx(0.5 * (xb2[4] + xb2[6]))


def test_features_are_causal() -> None:
    pt_t = np.arange(0.0, 600.0, 1.0)
    pt_c = 20.0 + 0.01 * pt_t
    cfg = replace(SMALL, use_dtdt=True, dtdt_window_s=60.0)
    t = np.linspace(0, 599, 2000)
    X = features(t, pt_t, pt_c, cfg)
    changed = pt_c.copy()
    changed[300:] += 50.0  # the future after t = 300 s changes
    X2 = features(t, pt_t, changed, cfg)
    before = t < 300.0
    np.testing.assert_array_equal(X[before], X2[before])
    assert not np.allclose(X[~before], X2[~before])
    # zero-order hold and backward difference
    assert X[np.searchsorted(t, 100.5), 0] == pytest.approx(21.0)
    assert X[-1, 1] == pytest.approx(0.01, rel=1e-6)


def test_effective_bandwidth_of_a_known_filter() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(size=20000)
    block = 3.6
    k = 20  # moving average: ENBW = fs / (2 k) one-sided
    y = np.convolve(x, np.ones(k) / k, mode="same")
    bw = effective_bandwidth(x, y, block)
    fs = 1 / block
    assert bw["enbw_hz"] == pytest.approx(fs / (2 * k), rel=0.1)
    # first -3 dB point of a k-point moving average is ≈ 0.443 fs / k
    assert bw["f3db_hz"] == pytest.approx(0.443 * fs / k, rel=0.15)
    assert bw["nyquist_hz"] == pytest.approx(fs / 2)


# ------------------------------------------------------------------ fit and apply


def test_fit_and_held_out_compensation(
    runs: dict[str, Path], fitted: tuple[CompensationModel, Decomposition]
) -> None:
    model, dec = fitted
    assert model.K == 5 and sorted(sum(dec.classes.values(), [])) == list(range(5))
    assert dec.classes["drift"], "the drift must be found"
    for key in ("cal", "val"):
        run = load(runs[key])
        app = compensate_offline(model, run)
        m = evaluate(model, app, run, held_out=key != "cal")
        raw, comp = m["raw"], m["compensated"]
        assert m["held_out"] is (key != "cal")
        # the drift is ~0.03 °/s peak to peak; compensation must remove nearly all of it
        assert comp["drift_pp_deg_per_s"] < 0.15 * raw["drift_pp_deg_per_s"]
        assert comp["bias_stability_deg_per_h"] < 0.1 * raw["bias_stability_deg_per_h"]
        # the drift model's residual against the truth is far below the drift itself
        truth = true_bias(run.temp)
        err = app.series["drift_prediction"] - truth
        assert np.sqrt(np.mean(err**2)) < 0.02 * np.ptp(truth)
        # without noise removal the white noise is untouched: ARW stays within 20 %
        assert m["compensated_drift_only"]["arw_deg_per_sqrt_h"] == pytest.approx(
            raw["arw_deg_per_sqrt_h"], rel=0.2
        )
        for name in ("poly", "bp"):
            b = m["baselines"][name]
            assert b["drift_pp_deg_per_s"] < 0.5 * raw["drift_pp_deg_per_s"]
        assert (
            0 < m["denoising"]["bandwidth"]["f3db_hz"] <= m["denoising"]["bandwidth"]["nyquist_hz"]
        )


def test_streaming_path_is_causal_and_matches_the_drift_model(
    runs: dict[str, Path], fitted: tuple[CompensationModel, Decomposition]
) -> None:
    model, _ = fitted
    run = load(runs["heat"])
    y = streaming_compensate(model, run.raw_t, run.raw_rate, run.pt_t, run.pt_c)
    T = causal_temperature(run.raw_t, run.pt_t, run.pt_c)
    np.testing.assert_allclose(y, run.raw_rate - model.drift.predict(T[:, None]), atol=1e-15)
    cut = run.raw_t.size // 2
    pt_future = run.pt_c.copy()
    pt_future[run.pt_t > run.raw_t[cut]] += 30.0
    rate_future = run.raw_rate.copy()
    rate_future[cut + 1 :] = 0.0
    y2 = streaming_compensate(model, run.raw_t, rate_future, run.pt_t, pt_future)
    np.testing.assert_array_equal(y[: cut + 1], y2[: cut + 1])


def test_heating_run_is_compensated_by_a_cooling_fit(
    runs: dict[str, Path], fitted: tuple[CompensationModel, Decomposition]
) -> None:
    model, _ = fitted
    run = load(runs["heat"])
    m = evaluate(model, compensate_offline(model, run), run, held_out=True)
    assert m["compensated"]["drift_pp_deg_per_s"] < 0.15 * m["raw"]["drift_pp_deg_per_s"]
    assert 0.0 <= m["temperature"]["fraction_outside_calibration"] < 0.05


def test_model_dir_round_trip(
    tmp_path: Path, runs: dict[str, Path], fitted: tuple[CompensationModel, Decomposition]
) -> None:
    model, _ = fitted
    d = tmp_path / "model"
    d.mkdir()
    save_model(model, str(d))
    meta = json.loads((d / "model.json").read_text())
    assert meta["format_version"] == MODEL_FORMAT_VERSION and meta["software_version"]
    with np.load(d / "arrays.npz", allow_pickle=False) as z:
        assert "calib_modes" in z.files and z["calib_modes"].shape[0] == model.K
    sd = torch.load(d / "drift_gabp.pt", weights_only=True)
    assert sd["0.weight"].shape == (model.drift.regressor.hidden, model.drift.regressor.n_in)
    back = load_model(str(d))
    assert back.config == model.config and (back.K, back.alpha) == (model.K, model.alpha)
    run = load(runs["val"])
    a1 = compensate_offline(model, run)
    a2 = compensate_offline(back, run)
    for k in ("compensated", "compensated_drift_only", "baselines.poly", "baselines.bp"):
        np.testing.assert_array_equal(a1.series[k], a2.series[k])


def test_model_from_another_format_version_is_refused(
    tmp_path: Path, fitted: tuple[CompensationModel, Decomposition]
) -> None:
    d = tmp_path / "model"
    d.mkdir()
    save_model(fitted[0], str(d))
    meta = json.loads((d / "model.json").read_text())
    meta["format_version"] = MODEL_FORMAT_VERSION + 1
    (d / "model.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match="format version"):
        load_model(str(d))
    (d / "model.json").write_text("{not json")
    with pytest.raises(InputError, match="damaged"):
        load_model(str(d))


def test_constant_temperature_cannot_be_fitted(tmp_path: Path) -> None:
    p = tmp_path / "flat.mcap"
    rng = np.random.default_rng(0)
    with RecordingWriter(p, start_time_ns=0) as w:
        for s in range(0, 1100):
            w.write_rate_block(float(s), 0.1, 10 * s, rng.normal(0, 1e-3, 10).astype(np.float32))
            w.write_pt100(float(s), 100.0, 25.0)
    with pytest.raises(InputError, match="temperature spans only"):
        fit(load(p), SMALL)


def test_dtdt_input_learns_a_thermal_rate_term(tmp_path: Path) -> None:
    """With ``use_dtdt`` the drift model sees dT/dt and removes a rate-sensitive bias that a
    temperature-only model cannot (the `thermal_rate` effect, docs/sim-model.md)."""
    fs, n = 10.0, int(1.2 * 3600 * 10)
    t = np.arange(n) / fs
    temp = 15 + 30 * np.sin(2 * np.pi * t / 2400.0)  # heats and cools: dT/dt of both signs
    dtdt = np.gradient(temp, t)
    rng = np.random.default_rng(5)
    rate = true_bias(temp) + 0.5 * dtdt + rng.normal(0, 1e-4, n)
    p = tmp_path / "rate.mcap"
    with RecordingWriter(p, start_time_ns=0) as w:
        for s in range(0, n, 10):
            w.write_rate_block(t[s], 0.1, s, rate[s : s + 10].astype(np.float32))
            w.write_pt100(t[s], 100.0, float(temp[s]))
    res = {}
    for use in (False, True):
        cfg = replace(SMALL, use_dtdt=use, dtdt_window_s=30.0)
        run = load(p, cfg)
        model, dec = fit(run, cfg)
        app = compensate_offline(model, run, dec)
        res[use] = np.std(app.series["compensated_drift_only"])
    assert res[True] < 0.3 * res[False]


def test_streamed_preparation_equals_in_memory(runs: dict[str, Path]) -> None:
    """prepare_file (block by block, bounded memory) == prepare_run (whole arrays)."""
    a = load(runs["cal"])
    b = prepare_file(str(runs["cal"]), SMALL)
    for k in ("t", "rate", "temp", "X"):
        np.testing.assert_allclose(getattr(b, k), getattr(a, k), rtol=1e-12, atol=1e-15)
    assert b.raw_rate is None and b.raw_period == pytest.approx(a.raw_period)
    # chunked accumulation, including chunks that split a block, equals one shot
    acc = BlockAverager(3.6)
    for s in range(0, a.raw_t.size, 977):
        acc.add(a.raw_t[s : s + 977], a.raw_rate[s : s + 977], a.raw_period)
    tb, xb, _ = acc.result()
    np.testing.assert_allclose(xb, a.rate, rtol=1e-12)
    np.testing.assert_array_equal(tb, a.t)


@pytest.fixture
def reader_passes(monkeypatch: pytest.MonkeyPatch) -> list[object]:
    """The topics of every pass through ``gyrolab.record.reader.iter_messages`` from here on
    (the one place a recording's chunks are decompressed)."""
    import gyrolab.record.reader as reader

    passes: list[object] = []
    real = reader.iter_messages

    def counted(*args: object, **kwargs: object) -> object:
        passes.append(args[1] if len(args) > 1 else kwargs.get("topics"))
        return real(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(reader, "iter_messages", counted)
    return passes


def test_streamed_preparation_reads_the_file_once(
    runs: dict[str, Path], reader_passes: list[object]
) -> None:
    """PT100 readings and the rate come from one pass through the reader (one
    decompression of the chunks), with the same data and content hash as a whole read."""
    b = prepare_file(str(runs["cal"]), SMALL)
    assert len(reader_passes) == 1, reader_passes
    a = load(runs["cal"])
    assert b.content_hash == a.content_hash
    np.testing.assert_array_equal(b.pt_c, a.pt_c)
    np.testing.assert_array_equal(b.t, a.t)


def test_the_kept_rate_batches_give_the_streamed_results_without_a_read(
    runs: dict[str, Path],
    fitted: tuple[CompensationModel, Decomposition],
    monkeypatch: pytest.MonkeyPatch,
    reader_passes: list[object],
) -> None:
    """prepare_file keeps the rate batches a later pass would read from the file (up to
    RATE_KEEP_MAX_SAMPLES): the same batches, the same block means bit for bit, no read;
    over the limit it keeps none and each pass streams the file as before."""
    import gyrolab.compensation.prepare as prepare

    model, _ = fitted
    path = str(runs["val"])
    kept = prepare_file(path, SMALL)
    assert kept.rate_batches is not None
    for a, b in zip(kept.rate_batches, iter_rate_batches(path), strict=True):
        np.testing.assert_array_equal(a[0], b[0])
        np.testing.assert_array_equal(a[1], b[1])
        assert a[2] == b[2]
    monkeypatch.setattr(prepare, "RATE_KEEP_MAX_SAMPLES", 10)
    streamed = prepare_file(path, SMALL)
    assert streamed.rate_batches is None
    passes = reader_passes
    p3 = fit_poly3(kept)
    results = {}
    for name, run in (("kept", kept), ("streamed", streamed)):
        before = len(passes)
        results[name] = (streaming_block_means(model, run), poly3_block_means(p3, run, 3.6))
        assert len(passes) - before == (0 if name == "kept" else 2)
    for x, y in zip(results["kept"], results["streamed"], strict=True):
        np.testing.assert_array_equal(x, y)


def test_streaming_block_means_from_file_and_memory_agree(
    runs: dict[str, Path], fitted: tuple[CompensationModel, Decomposition]
) -> None:
    model, _ = fitted
    a = load(runs["val"])
    b = prepare_file(str(runs["val"]), SMALL)
    np.testing.assert_allclose(
        streaming_block_means(model, b), streaming_block_means(model, a), rtol=1e-12
    )
