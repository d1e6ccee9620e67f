"""Guards of `gyrolab compensate` / `apply` (issue 11 point 6), `--config`, and the
paper's gradient-descent BP option.

Small synthetic runs and the tiny CLI configuration of test_compensate_cli, so every guard
runs the real command path in a few seconds.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
import torch
from test_compensate_cli import CLI_CONFIG
from test_pipeline import case_temperature, true_bias, write_run

from gyrolab.cli import main
from gyrolab.compensation.config import PipelineConfig
from gyrolab.compensation.gabp import BPConfig, fit_mlp, gd_train
from gyrolab.compensation.model_dir import load_model
from gyrolab.compensation.prepare import prepare_file
from gyrolab.record.reader import read_metadata
from gyrolab.record.writer import RecordingWriter

torch.set_num_threads(1)
REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True)
def small_config(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("gyrolab.compensation.commands.DEFAULT_CONFIG", CLI_CONFIG)


def write_hot_run(path: Path, seed: int, offset_c: float = 25.0) -> Path:
    """Like test_pipeline.write_run (cooling, 1.2 h at 10 Hz) with the case temperature
    shifted by ``offset_c``: most of it lies above the calibrated range."""
    rng = np.random.default_rng(seed)
    fs, n = 10.0, int(1.2 * 3600 * 10)
    t = np.arange(n) / fs
    temp = case_temperature(t, heating=False) + offset_c
    rate = true_bias(temp) + rng.normal(0.0, 0.05 / 60 * np.sqrt(fs), n)
    with RecordingWriter(path, start_time_ns=1_700_000_000 * 10**9) as w:
        for s in range(0, n, 10):
            w.write_rate_block(t[s], 1 / fs, s, rate[s : s + 10].astype(np.float32))
            w.write_pt100(t[s], 100.0, float(temp[s]))
    return path


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("guards")
    cal = write_run(d / "cal.mcap", 21)
    copy = d / "renamed-copy.mcap"
    shutil.copyfile(cal, copy)
    return {
        "cal": cal,
        "copy": copy,
        "val": write_run(d / "val.mcap", 22),
        "hot": write_hot_run(d / "hot.mcap", 23),
        "dir": d,
    }


@pytest.fixture(scope="module")
def model_dir(runs: dict[str, Path]) -> Path:
    out = runs["dir"] / "model"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr("gyrolab.compensation.commands.DEFAULT_CONFIG", CLI_CONFIG)
        assert main(["compensate", str(runs["cal"]), "--out", str(out), "--seed", "7"]) == 0
    return out


def _one_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


@pytest.mark.parametrize("which", ["cal", "copy"])
def test_validate_on_the_calibration_data_is_refused(
    which: str, runs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "m"
    args = ["compensate", str(runs["cal"]), "--out", str(out), "--validate", str(runs[which])]
    assert main(args) == 2
    line = _one_line(capsys)
    assert runs[which].name in line and "same rate and temperature data" in line
    assert not out.exists() and not list(tmp_path.iterdir())


def test_model_json_records_seed_config_and_calibration_hash(
    model_dir: Path, runs: dict[str, Path]
) -> None:
    meta = json.loads((model_dir / "model.json").read_text())
    assert meta["seed"] == 7
    assert set(meta["config"]) == {f.name for f in fields(PipelineConfig)}
    h = meta["calibration"]["content_hash"]
    assert h.startswith("blake2b-160:")
    assert h == prepare_file(str(runs["copy"]), CLI_CONFIG).content_hash  # not the name
    assert h != prepare_file(str(runs["val"]), CLI_CONFIG).content_hash
    cal = meta["calibration"]
    assert cal["temp_rate_min_c_per_min"] < 0 and cal["temp_rate_window_s"] == 300.0
    # an older model directory (no seed, no hash, no dT/dt range) still loads and applies
    assert load_model(str(model_dir)).seed == 7


def test_older_model_dir_still_loads(
    model_dir: Path, runs: dict[str, Path], tmp_path: Path
) -> None:
    old = tmp_path / "old"
    shutil.copytree(model_dir, old)
    meta = json.loads((old / "model.json").read_text())
    del meta["seed"]
    for k in ("content_hash", "temp_rate_min_c_per_min", "temp_rate_max_c_per_min"):
        del meta["calibration"][k]
    for k in ("drift_model", "bp_optimizer", "bp_learning_rate", "bp_epochs", "vmd_fitness"):
        del meta["config"][k]
    (old / "model.json").write_text(json.dumps(meta))
    m = load_model(str(old))
    assert m.seed is None and m.config.drift_model == "gabp"
    assert main(["apply", str(old), str(runs["val"]), "--out", str(tmp_path / "c.mcap")]) == 0


def test_outside_the_calibrated_range_warns_and_flags(
    runs: dict[str, Path], model_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "m"
    args = ["compensate", str(runs["cal"]), "--out", str(out), "--validate", str(runs["hot"])]
    assert main(args) == 0
    err = capsys.readouterr().err
    warn = [line for line in err.splitlines() if line.startswith("warning:")]
    assert len(warn) == 1 and "hot.mcap" in warn[0]
    assert "outside the calibrated temperature range" in warn[0]
    m = json.loads((out / "metrics.json").read_text())
    t = m["temperature"]
    assert t["outside_calibration_range"] is True
    assert 0.05 < t["fraction_outside_calibration"] <= 1.0
    assert t["fraction_outside_calibration_beyond_margin"] <= t["fraction_outside_calibration"]
    # issue 23: the graded expected error, the band, the residual mean bias, and the
    # baselines said to extrapolate; the warning carries the grade
    band = m["causal_band"]
    assert (
        band["level"] == 0.9
        and band["max_half_width_deg_per_s"] > band["half_width_inside_deg_per_s"]
    )
    assert t["expected_error"] == band["expected_error"]
    assert t["expected_error"]["grade"] in ("mild", "severe")
    assert "expected error " + t["expected_error"]["grade"] in warn[0]
    assert set(m["residual_mean_bias_deg_per_h"]) >= {"raw", "causal", "baselines.poly"}
    assert m["headline"]["mean_bias_deg_per_h"] == m["residual_mean_bias_deg_per_h"]["causal"]
    ext = m["baselines_extrapolation"]["poly"]
    assert ext["extrapolating"] is True and ext["max_beyond_c"] > 5.0
    # apply warns too, still writes, and the compensated file carries the flag
    comp = tmp_path / "hot-comp.mcap"
    assert main(["apply", str(model_dir), str(runs["hot"]), "--out", str(comp)]) == 0
    assert "outside the calibrated temperature range" in capsys.readouterr().err
    rng = read_metadata(comp)["compensation"]["calibrated_range"]
    assert rng["outside_calibration_range"] is True
    # a run inside the range (same profile, another seed): no warning, flag false
    ok = tmp_path / "ok.mcap"
    assert main(["apply", str(model_dir), str(runs["val"]), "--out", str(ok)]) == 0
    assert "warning" not in capsys.readouterr().err
    assert (
        read_metadata(ok)["compensation"]["calibrated_range"]["outside_calibration_range"] is False
    )


def test_heating_run_is_outside_a_cooling_calibrations_rate_range(
    model_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    heat = write_run(tmp_path / "heat.mcap", 24, heating=True)
    assert main(["apply", str(model_dir), str(heat), "--out", str(tmp_path / "h.mcap")]) == 0
    err = capsys.readouterr().err
    assert "outside the calibrated dT/dt range" in err


@pytest.mark.parametrize("where", ["theta", "y_std", "flp"])
def test_non_finite_model_parameters_are_refused(
    where: str,
    model_dir: Path,
    runs: dict[str, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    bad = tmp_path / "bad"
    shutil.copytree(model_dir, bad)
    if where == "theta":
        with np.load(bad / "arrays.npz") as z:
            arrays = {k: z[k] for k in z.files}
        arrays["drift.theta"] = arrays["drift.theta"].copy()
        arrays["drift.theta"][3] = np.nan
        np.savez_compressed(bad / "arrays.npz", **arrays)
        name = "arrays.npz"
    else:
        meta = json.loads((bad / "model.json").read_text())
        if where == "y_std":
            meta["drift_model"]["y_std"] = None  # how JSON stores a NaN
        else:
            meta["flp"]["stream"]["coef"][0] = None
        (bad / "model.json").write_text(json.dumps(meta))
        name = "model.json"
    out = tmp_path / "c.mcap"
    assert main(["apply", str(bad), str(runs["val"]), "--out", str(out)]) == 2
    line = _one_line(capsys)
    assert name in line and ("not finite" in line or "non-finite" in line)
    assert not out.exists()


def test_config_file_selects_settings_and_rejects_unknown_keys(
    runs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = tmp_path / "model.toml"
    cfg.write_text(
        'seed = 5\ndrift_model = "gabp"\nbp_optimizer = "gd"\nbp_epochs = 200\n'
        'bp_learning_rate = 0.05\nvmd_fitness = "envelope_entropy"\nbaselines = ["poly"]\n'
    )
    out = tmp_path / "m"
    assert main(["compensate", str(runs["cal"]), "--out", str(out), "--config", str(cfg)]) == 0
    meta = json.loads((out / "model.json").read_text())
    assert meta["seed"] == 5
    c = meta["config"]
    assert (c["bp_optimizer"], c["bp_epochs"], c["vmd_fitness"]) == ("gd", 200, "envelope_entropy")
    assert c["ga_population"] == CLI_CONFIG.ga_population  # keys not in the file: defaults
    assert meta["drift_model"]["config"]["optimizer"] == "gradient-descent"
    assert set(meta["baselines"]) == {"poly"}
    # --seed overrides the file's seed
    out2 = tmp_path / "m2"
    args = ["compensate", str(runs["cal"]), "--out", str(out2), "--config", str(cfg)]
    assert main([*args, "--seed", "9"]) == 0
    assert json.loads((out2 / "model.json").read_text())["seed"] == 9
    capsys.readouterr()
    for text, words in [
        ("seeed = 3\n", "unknown key 'seeed'"),
        ('bp_optimizer = "adam"\n', "not one of lbfgs, gd"),
        ("hidden = 2.5\n", "hidden must be an integer"),
        ("vmd_K = 5\n", "give both or none"),
        ("[section\n", "not valid TOML"),
    ]:
        bad = tmp_path / "bad.toml"
        bad.write_text(text)
        out3 = tmp_path / "m3"
        assert main(["compensate", str(runs["cal"]), "--out", str(out3), "--config", str(bad)]) == 2
        line = _one_line(capsys)
        assert "bad.toml" in line and words in line, line
        assert not out3.exists()


def test_every_config_key_is_documented() -> None:
    doc = (REPO / "docs" / "compensation.md").read_text()
    section = doc[doc.index("## Configuration file") :]
    for f in fields(PipelineConfig):
        assert f"| `{f.name}` |" in section, f.name
    assert "| `seed` |" in section


def test_gradient_descent_bp_is_the_chain_rule_and_lowers_the_loss() -> None:
    rng = np.random.default_rng(0)
    X = rng.uniform(-40, 60, size=(400, 1))
    y = 1e-3 * np.tanh(X[:, 0] / 30) + 2e-5 * rng.standard_normal(400)
    # one step at learning rate 1 is minus the gradient: compare with torch autograd
    Xs = (X - X.mean()) / X.std()
    ys = (y - y.mean()) / y.std()
    th0 = rng.normal(size=3 * 5 + 1)
    th1, _ = gd_train(th0, Xs, ys, 5, BPConfig(optimizer="gd", learning_rate=1.0, epochs=1))
    t = torch.tensor(th0, requires_grad=True)
    Xt, yt = torch.tensor(Xs), torch.tensor(ys)
    z = torch.sigmoid(Xt @ t[:5].reshape(1, 5) + t[5:10]) @ t[10:15] + t[15]
    (0.5 * torch.mean((yt - z) ** 2)).backward()
    np.testing.assert_allclose(th0 - th1, t.grad.numpy(), rtol=1e-10, atol=1e-14)
    # training with the paper's plain gradient descent lowers the loss, GA start or not
    for init in ("ga", "random"):
        bp = BPConfig(hidden=5, optimizer="gd", epochs=300, learning_rate=0.5)
        m = fit_mlp(X, y, init=init, bp=bp, seed=1)
        h = m.bp_loss_history
        assert len(h) == 301 and h[-1] < h[0]
        if init == "random":  # from a random start it has most of the way to go
            assert h[-1] < 0.5 * h[0]
        assert m.config["optimizer"] == "gradient-descent"
    with pytest.raises(ValueError, match="diverged"):
        gd_train(th0, Xs, ys, 5, BPConfig(optimizer="gd", learning_rate=1e6, epochs=50))


def test_report_says_when_a_run_is_outside_the_calibrated_range(
    model_dir: Path, runs: dict[str, Path]
) -> None:
    from gyrolab.report.build import build_report

    doc, metrics = build_report(runs["hot"], model_dir)
    assert metrics["temperature"]["outside_calibration_range"] is True
    texts = [b.text for s in doc.sections for b in s.blocks if hasattr(b, "text")]
    assert any(t.startswith("Outside the calibrated range — hot.mcap:") for t in texts)
    head = next(
        b for s in doc.sections for b in s.blocks if getattr(b, "key", "") == "causal-headline"
    )
    assert "Prediction band (90 %" in head.note and "Baselines extrapolating" in head.note
    assert any(r[0] == "residual mean bias (°/h)" for r in head.rows)
    allan = next(b for s in doc.sections for b in s.blocks if getattr(b, "key", "") == "allan")
    assert "raw: ARW" in allan.caption and "τ =" in allan.caption


def write_unit_run(path: Path, seed: int, internal: bool) -> Path:
    """test_pipeline.write_run's cooling run as unit G-1 of a bench: its temperature from its
    internal (die) sensor, 1 °C above the case, or from its PT100."""
    rng = np.random.default_rng(seed)
    fs, n = 10.0, int(1.2 * 3600 * 10)
    t = np.arange(n) / fs
    temp = case_temperature(t, heating=False)
    rate = true_bias(temp) + rng.normal(0.0, 0.05 / 60 * np.sqrt(fs), n)
    extra = {"internal_temperature": ["G-1"]} if internal else {}
    with RecordingWriter(path, start_time_ns=1_700_000_000 * 10**9, units=["G-1"], **extra) as w:
        for s in range(0, n, 10):
            w.write_rate_block(t[s], 1 / fs, s, rate[s : s + 10].astype(np.float32), unit="G-1")
            if internal:
                w.write_internal_temperature(t[s] + 0.5, float(temp[s]) + 1.0, 10, unit="G-1")
            else:
                w.write_pt100(t[s], 100.0, float(temp[s]) + rng.normal(0, 0.01), unit="G-1")
    return path


def test_a_model_on_another_temperature_source_is_flagged_not_refused(
    runs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    die = write_unit_run(tmp_path / "die.mcap", 31, internal=True)
    case = write_unit_run(tmp_path / "case.mcap", 32, internal=False)
    out = tmp_path / "m"
    args = ["compensate", str(die), "--unit", "G-1", "--out", str(out), "--validate", str(case)]
    assert main(args) == 0
    warn = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("warning:")]
    # the die sensor's 1 °C offset already shows as points outside the calibrated range
    assert len(warn) == 2 and "outside the calibrated temperature range" in warn[0]
    assert warn[1:] == [
        f"warning: {case}: the model was fitted on the internal (die) sensor temperature, "
        "this run's is its PT100 (case): the offset and lag between die and case enter the "
        "drift model's input"
    ]
    assert (
        json.loads((out / "model.json").read_text())["calibration"]["temperature_source"]
        == "internal"
    )
    metrics = json.loads((out / "metrics.json").read_text())
    t = metrics["temperature"]
    assert (t["calibration_temperature_source"], t["temperature_source"]) == ("internal", "pt100")
    assert t["temperature_source_mismatch"] is True
    assert metrics["calibration"]["temperature"]["temperature_source_mismatch"] is False
    # apply (single-unit runs, PT100): written, the warning on stderr, the flag in the file
    comp = tmp_path / "c.mcap"
    assert main(["apply", str(out), str(runs["val"]), "--out", str(comp)]) == 0
    assert "fitted on the internal (die) sensor temperature" in capsys.readouterr().err
    rng = read_metadata(comp)["compensation"]["calibrated_range"]
    assert rng["temperature_source_mismatch"] is True and rng["temperature_source"] == "pt100"
