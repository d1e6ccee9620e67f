"""`gyrolab compensate` / `gyrolab apply`: contract outputs, compensated MCAP, bad input."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from contract import METRIC_KEYS
from test_pipeline import SMALL, write_run

from gyrolab.cli import main
from gyrolab.compensation.apply_command import TOPIC_RATE_OFFLINE, TOPIC_RATE_RAW
from gyrolab.compensation.model_dir import load_model
from gyrolab.numerics.averaging import PAPER_BLOCK_S, block_average
from gyrolab.record.format import TOPIC_PT100, TOPIC_RATE
from gyrolab.record.reader import iter_blocks, read_metadata, read_recording
from gyrolab.record.writer import RecordingWriter

torch.set_num_threads(1)


# the GPSO search runs (tiny swarm) so that the CLI path is the real one
CLI_CONFIG = replace(
    SMALL,
    vmd_K=None,
    vmd_alpha=None,
    gpso_population=4,
    gpso_generations=1,
    causal_families=("poly", "structured", "bp", "gabp"),
)


@pytest.fixture(autouse=True)
def small_config(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("gyrolab.compensation.commands.DEFAULT_CONFIG", CLI_CONFIG)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("cli")
    return {
        "cal": write_run(d / "cal.mcap", 11),
        "val": write_run(d / "val.mcap", 12, heating=True),
        "dir": d,
    }


@pytest.fixture(scope="module")
def model_dir(runs: dict[str, Path]) -> Path:
    out = runs["dir"] / "model"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr("gyrolab.compensation.commands.DEFAULT_CONFIG", CLI_CONFIG)
        rc = main(
            ["compensate", str(runs["cal"]), "--out", str(out), "--validate", str(runs["val"])]
        )
    assert rc == 0
    return out


def test_compensate_writes_contract_metrics(model_dir: Path, runs: dict[str, Path]) -> None:
    assert {p.name for p in model_dir.iterdir()} >= {
        "model.json",
        "arrays.npz",
        "drift_gabp.pt",
        "baseline_bp.pt",
        "metrics.json",
    }
    m = json.loads((model_dir / "metrics.json").read_text())
    assert m["held_out"] is True and m["run"] == str(runs["val"])
    assert m["calibration"]["held_out"] is False
    for block in (m["raw"], m["compensated"], *m["baselines"].values()):
        assert set(block) == METRIC_KEYS
        assert all(np.isfinite(v) for v in block.values())
    assert set(m["baselines"]) == {"poly", "bp"}
    K = m["vmd"]["K"]
    assert 3 <= K <= 11 and 50 <= m["vmd"]["alpha"] <= 5000
    classes = m["imf_classes"]
    assert sorted(classes["noise"] + classes["mixed"] + classes["drift"]) == list(range(K))
    assert isinstance(m["timing_s"], float) and m["timing_s"] > 0
    assert m["compensated"]["drift_pp_deg_per_s"] < 0.2 * m["raw"]["drift_pp_deg_per_s"]
    meta = json.loads((model_dir / "model.json").read_text())
    assert meta["vmd"]["K"] == K and "gpso_positions" in np.load(model_dir / "arrays.npz").files
    # the causal headline (issue 11): its metrics, the model that made it, 100 s p-p for all
    assert set(m["causal"]) == METRIC_KEYS
    assert m["headline"]["output"] == "causal"
    assert m["headline"]["family"] == m["causal_model"]["family"] == meta["causal_model"]["family"]
    assert set(m["causal_model"]["cv_rmse_deg_per_s"]) == {"poly", "structured", "bp", "gabp"}
    assert {"raw", "causal", "compensated"} <= set(m["drift_pp_100s_deg_per_s"])
    assert m["causal"]["drift_pp_deg_per_s"] < 0.5 * m["raw"]["drift_pp_deg_per_s"]


def test_apply_writes_compensated_recording(
    model_dir: Path, runs: dict[str, Path], tmp_path: Path
) -> None:
    out = tmp_path / "comp.mcap"
    assert main(["apply", str(model_dir), str(runs["val"]), "--out", str(out)]) == 0
    src = read_recording(runs["val"])
    dst = read_recording(out)
    assert dst.topic_counts == src.topic_counts  # same topics, same number of messages
    np.testing.assert_array_equal(dst.rate.t, src.rate.t)
    np.testing.assert_array_equal(dst.rate.index, src.rate.index)
    raw = np.concatenate([b[3] for b in iter_blocks(out, TOPIC_RATE_RAW)])
    np.testing.assert_array_equal(raw, src.rate.values.astype(np.float32))
    model = load_model(str(model_dir))
    # /gyro/rate is the causal headline: raw minus the causal model's held drift estimate
    expect = src.rate.values - model.causal.drift_at(src.rate.t, src.pt100_t, src.pt100_c)
    np.testing.assert_allclose(dst.rate.values, expect, atol=1e-6)
    # the drift is gone from the written rate: hour-scale mean is near zero everywhere
    assert np.abs(np.mean(dst.rate.values)) < 0.05 * np.ptp(
        block_average(src.rate.t, src.rate.values, PAPER_BLOCK_S, src.rate.period)[1]
    )
    off = list(iter_blocks(out, TOPIC_RATE_OFFLINE))
    assert off and off[0][1] == pytest.approx(3.6)
    meta = read_metadata(out)
    src_meta = read_metadata(runs["val"])
    assert {k: v for k, v in meta.items() if k != "compensation"} == src_meta
    assert meta["compensation"]["vmd"]["K"] == model.K
    assert TOPIC_RATE in meta["compensation"]["topics"]


def test_outputs_are_never_overwritten_without_force(
    model_dir: Path, runs: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    before = (model_dir / "metrics.json").read_bytes()
    assert main(["compensate", str(runs["cal"]), "--out", str(model_dir)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert (model_dir / "metrics.json").read_bytes() == before


def _write(path: Path, rate: np.ndarray, temp: np.ndarray | None, fs: float = 10.0) -> Path:
    with RecordingWriter(path, start_time_ns=0) as w:
        for s in range(0, rate.size, int(fs)):
            t = s / fs
            w.write_rate_block(t, 1 / fs, s, rate[s : s + int(fs)].astype(np.float32))
            if temp is not None:
                w.write_pt100(t, 100.0, float(temp[s]))
    return path


def _bad_inputs(d: Path, good: Path) -> dict[str, tuple[Path, str]]:
    n = 12000  # 20 min at 10 Hz
    rng = np.random.default_rng(0)
    temp = np.linspace(50, 0, n)
    rate = 1e-3 * temp + rng.normal(0, 1e-3, n)
    nan = rate.copy()
    nan[500] = np.nan
    trunc = d / "trunc.mcap"
    data = good.read_bytes()
    trunc.write_bytes(data[: len(data) // 2])
    return {
        "nan": (_write(d / "nan.mcap", nan, temp), "NaN"),
        "constant": (_write(d / "const.mcap", np.full(n, 0.01), temp), "constant"),
        "no_temperature": (_write(d / "notemp.mcap", rate, None), "/temperature/pt100"),
        "too_short": (_write(d / "short.mcap", rate[:3000], temp[:3000]), "at least"),
        "truncated": (trunc, "truncated"),
        "missing": (d / "nope.mcap", "not found"),
    }


@pytest.mark.parametrize(
    "case", ["nan", "constant", "no_temperature", "too_short", "truncated", "missing"]
)
def test_bad_input_is_one_line_exit_2_nothing_written(
    case: str, runs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path, words = _bad_inputs(tmp_path, runs["cal"])[case]
    out = tmp_path / "out_model"
    assert main(["compensate", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0] and path.name in err[0]
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out_model")]


def test_apply_refuses_a_model_from_another_version(
    model_dir: Path, runs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    foreign = tmp_path / "foreign"
    shutil.copytree(model_dir, foreign)
    meta = json.loads((foreign / "model.json").read_text())
    meta["format_version"] = 999
    (foreign / "model.json").write_text(json.dumps(meta))
    out = tmp_path / "c.mcap"
    assert main(["apply", str(foreign), str(runs["val"]), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "format version 999" in err[0]
    assert not out.exists()
    # and a run without temperature cannot be compensated either
    no_t = _bad_inputs(tmp_path, runs["cal"])["no_temperature"][0]
    assert main(["apply", str(model_dir), str(no_t), "--out", str(out)]) == 2
    assert not out.exists()
    assert read_recording(runs["val"], topics=[TOPIC_PT100]).pt100_t.size > 0
