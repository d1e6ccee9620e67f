"""The model directory's one owner (gyrolab.compensation.model_dir.ModelDir) refuses what
is not a model (issue 25): every number of every file checked on load, one line naming
file and field; no output may be inside, or replace, a model directory's files; a model
of one axis count on a run of another is one line; another unit's run is flagged. And
`apply` writes, on one axis as on three, the model the C export runs (issue 24)."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from test_export import CC, run_c
from test_pipeline import SMALL, write_run

from gyrolab.cli import main
from gyrolab.compensation.model_dir import ModelDir
from gyrolab.profiles.profile import load_profile
from gyrolab.record.reader import read_recording
from gyrolab.sim.model import nominal_model
from gyrolab.sim.simulate import simulate_run

torch.set_num_threads(1)
FAST = replace(SMALL, ga_generations=3, bp_max_iter=60)


@pytest.fixture(scope="module")
def unit(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("modeldir")
    runs = {
        "cal": write_run(d / "cal.mcap", 41, serial="G-0007"),
        "val": write_run(d / "val.mcap", 42, heating=True, serial="G-0007"),
        "other": write_run(d / "other.mcap", 43, heating=True, serial="G-0019"),
        "dir": d,
    }
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr("gyrolab.compensation.commands.DEFAULT_CONFIG", FAST)
        assert main(["compensate", str(runs["cal"]), "--out", str(d / "model")]) == 0
    runs["model"] = d / "model"
    return runs


def _one_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def _copy(unit: dict[str, Path], tmp_path: Path) -> Path:
    bad = tmp_path / "bad"
    shutil.copytree(unit["model"], bad)
    return bad


def _edit_json(path: Path, edit) -> None:  # noqa: ANN001 - a function of the parsed JSON
    meta = json.loads(path.read_text())
    edit(meta)
    path.write_text(json.dumps(meta))  # json writes NaN as the literal NaN


def _every_reader_refuses(
    model: Path, unit: dict[str, Path], tmp_path: Path, capsys, *want: str
) -> None:
    """apply, export json and report: exit 2, one line naming ``want``, nothing written."""
    runs = [
        ["apply", str(model), str(unit["val"]), "--out", str(tmp_path / "a.mcap")],
        ["export", str(model), "--format", "json", "--out", str(tmp_path / "e.json")],
        ["report", str(unit["val"]), "--model", str(model), "--out", str(tmp_path / "r")],
    ]
    for argv in runs:
        before = sorted(p.name for p in tmp_path.iterdir())
        assert main(argv) == 2, argv
        line = _one_line(capsys)
        assert all(w in line for w in want), (argv, line)
        assert sorted(p.name for p in tmp_path.iterdir()) == before


@pytest.mark.parametrize(
    "field, value, why",
    [
        ("temp_min_c", float("nan"), "calibration.temp_min_c is NaN: not a finite number"),
        ("temp_max_c", float("inf"), "calibration.temp_max_c is Infinity"),
        ("temp_min_c", 5000.0, "calibration.temp_min_c = 5000.0 °C is outside"),
        ("raw_rate_hz", -10.0, "calibration.raw_rate_hz = -10.0 is not a positive number"),
    ],
)
def test_a_bad_number_in_model_json_is_one_line(
    unit, tmp_path: Path, capsys: pytest.CaptureFixture[str], field, value, why
) -> None:
    bad = _copy(unit, tmp_path)
    _edit_json(bad / "model.json", lambda m: m["calibration"].__setitem__(field, value))
    _every_reader_refuses(bad, unit, tmp_path, capsys, "model.json", why)


def test_a_nan_in_arrays_npz_is_one_line(
    unit, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = _copy(unit, tmp_path)
    with np.load(bad / "arrays.npz") as z:
        arrays = {k: z[k] for k in z.files}
    arrays["calib_t"] = arrays["calib_t"].copy()
    arrays["calib_t"][10] = np.nan
    np.savez_compressed(bad / "arrays.npz", **arrays)
    _every_reader_refuses(bad, unit, tmp_path, capsys, "arrays.npz", "calib_t has 1 non-finite")


def test_bad_config_and_vmd_values_are_one_line(
    unit, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = _copy(unit, tmp_path)
    _edit_json(bad / "model.json", lambda m: m["config"].__setitem__("block_s", -3.6))
    _every_reader_refuses(bad, unit, tmp_path, capsys, "model.json", "config.block_s")
    shutil.rmtree(bad)
    bad = _copy(unit, tmp_path)
    _edit_json(bad / "model.json", lambda m: m["vmd"].__setitem__("K", 0))
    _every_reader_refuses(bad, unit, tmp_path, capsys, "model.json", "vmd.K = 0")


def test_a_nan_in_metrics_or_firmware_json_is_one_line(
    unit, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = _copy(unit, tmp_path)
    _edit_json(bad / "metrics.json", lambda m: m["raw"].__setitem__("rms_deg_per_s", float("nan")))
    out = tmp_path / "fleet"
    assert main(["fleet", str(bad), "--out", str(out)]) == 2
    line = _one_line(capsys)
    assert "metrics.json" in line and "raw.rms_deg_per_s is NaN" in line and not out.exists()
    fw = json.loads((bad / "firmware.json").read_text())
    c0 = json.dumps(fw["poly3"]["coef_deg_per_s"][0])
    text = (bad / "firmware.json").read_text()
    (bad / "firmware.json").write_text(text.replace(c0, "1e999", 1))  # overflows to inf
    argv = ["export", str(bad), "--format", "px4", "--device-id", "1", "--out", str(out)]
    assert main(argv) == 2
    line = _one_line(capsys)
    assert "firmware.json" in line and "poly3.coef_deg_per_s[0] is inf" in line


@pytest.mark.parametrize(
    "argv",
    [
        ["export", "{m}", "--format", "json", "--out", "{m}/model.json", "--force"],
        ["export", "{m}", "--format", "c", "--out", "{m}/arrays.c", "--force"],
        ["apply", "{m}", "{val}", "--out", "{m}/results.npz", "--force"],
        ["apply", "{m}", "{val}", "--out", "{m}/new.mcap"],
        ["report", "{val}", "--model", "{m}", "--out", "{m}/report"],
    ],
)
def test_no_output_inside_or_over_a_model_directory(
    unit, tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str]
) -> None:
    m = _copy(unit, tmp_path)
    before = {p.relative_to(m): p.read_bytes() for p in m.rglob("*") if p.is_file()}
    args = [a.format(m=m, val=unit["val"]) for a in argv]
    assert main(args) == 2
    line = _one_line(capsys)
    assert "is inside one of this command's inputs" in line and str(m) in line
    after = {p.relative_to(m): p.read_bytes() for p in m.rglob("*") if p.is_file()}
    assert after == before  # nothing replaced, nothing added (no temporary left either)
    ModelDir(m).load()


def test_a_one_axis_model_on_a_three_axis_run_is_one_line(
    unit, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    m = nominal_model()
    run3 = tmp_path / "three.mcap"
    simulate_run(
        run3, load_profile("short"), m, rate_hz=2.0, seed=1, axis_models=[m, m],
        show_progress=False,
    )  # fmt: skip
    out = tmp_path / "a.mcap"
    assert main(["apply", str(unit["model"]), str(run3), "--out", str(out)]) == 2
    line = _one_line(capsys)
    assert "three.mcap: has 3 axes" in line and "1" in line and not out.exists()


def test_another_units_run_is_flagged_not_refused(
    unit, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert ModelDir(unit["model"]).load().calibration["unit_serial"] == "G-0007"
    for run, mismatch in (("other", True), ("val", False)):
        out = tmp_path / f"{run}.mcap"
        assert main(["apply", str(unit["model"]), str(unit[run]), "--out", str(out)]) == 0
        err = capsys.readouterr().err
        said = "the model was fitted on unit G-0007, this run is unit G-0019" in err
        assert said == mismatch
        rng = read_recording(out).metadata["compensation"]["calibrated_range"]
        assert rng["unit_mismatch"] is mismatch and rng["calibration_unit_serial"] == "G-0007"
    rep = tmp_path / "rep"
    argv = ["report", str(unit["other"]), "--model", str(unit["model"]), "--out", str(rep)]
    assert main(argv) == 0
    m = json.loads((rep / "metrics.json").read_text())
    assert m["temperature"]["unit_mismatch"] is True and m["temperature"]["unit_serial"] == "G-0019"
    assert "Another unit" in (rep / "index.html").read_text(encoding="utf-8")


@pytest.mark.skipif(CC is None, reason="no C compiler on this machine")
def test_apply_on_one_axis_runs_the_model_the_c_export_runs(unit, tmp_path: Path) -> None:
    """Issue 24: /gyro/rate of `apply` is raw − the causal model's drift, which the C
    export (default kind: the chosen model) computes in float32 (3 axes: test_export)."""
    cm = ModelDir(unit["model"]).load()
    assert cm.causal is not None
    out = tmp_path / "a.mcap"
    assert main(["apply", str(unit["model"]), str(unit["val"]), "--out", str(out)]) == 0
    c = tmp_path / "g.c"
    assert main(["export", str(unit["model"]), "--format", "c", "--out", str(c)]) == 0
    rec = read_recording(unit["val"])
    (tmp_path / "b").mkdir()
    ok, drift_c = run_c(tmp_path / "b", c, rec, 1)
    assert ok.all()
    got = read_recording(out).rate.values.astype(float)
    raw = rec.rate.values.astype(float)
    d_apply = raw - got
    scale = np.abs(d_apply).max()
    # float32 output and float32 C: within the rounding of a float32 rate
    assert np.abs(d_apply - drift_c[:, 0]).max() <= 1e-5 * scale + 2 * np.spacing(
        np.float32(np.abs(raw).max())
    )
    # and not the paper's GA-BP on T, which the 3-axis path used to write
    gabp = cm.drift.drift_at(rec.rate.t, rec.pt100_t, rec.pt100_c)
    assert np.abs(gabp - drift_c[:, 0]).max() > 10 * np.abs(d_apply - drift_c[:, 0]).max()
