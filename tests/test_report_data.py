"""The report reads what `gyrolab compensate` computed (results.json / results.npz in the
model directory) instead of applying the model again; a model directory without them (an
older gyrolab) still makes a report, computed by the report and said so.

Uses the session's demo (tests/test_demo.py: short profile, 10 Hz, compensate with
--validate on the held-out run).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from contract import METRIC_KEYS
from test_demo import make_demo

from gyrolab.cli import main
from gyrolab.compensation.model_dir import ModelDir

RESULTS_JSON, RESULTS_NPZ = ModelDir.RESULTS_JSON, ModelDir.RESULTS_NPZ


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_demo(tmp_path_factory)


def test_compensate_keeps_the_results_of_both_runs(demo_run: Path) -> None:
    res = ModelDir(demo_run / "model").results()
    assert set(res) == {"calibration", "validation"}
    val = res["validation"]
    assert val.held_out and not res["calibration"].held_out
    n = val.t.size
    assert val.modes.shape == (len(val.mpe), n) and val.temp.shape == (n,)
    for name in ("raw", "compensated", "drift_prediction", "causal", "baselines.poly"):
        assert val.series[name].shape == (n,), name
    assert val.oracle_checked and "oracle" not in val.series  # acquired: no truth known
    assert "oracle" in res["calibration"].series  # the simulated calibration run has one
    # the Allan curves kept are those of the metrics compensate wrote for the same series
    mm = json.loads((demo_run / "model" / "metrics.json").read_text())
    raw = val.allan["raw"]
    assert raw.adev.shape == raw.tau.shape == raw.lo.shape and np.all(raw.lo <= raw.adev)
    assert raw.arw == pytest.approx(mm["noise_terms"]["raw"]["arw_deg_per_sqrt_h"], rel=1e-9)


def test_the_report_reads_the_model_directory(demo_run: Path) -> None:
    m = json.loads((demo_run / "report" / "metrics.json").read_text())
    assert m["model_results"] == "model_dir"
    html = (demo_run / "report" / "index.html").read_text(encoding="utf-8")
    assert "read from the model directory" in html and "applied to this run by" not in html


def test_an_older_model_directory_still_reports_and_says_it_computed(
    demo_run: Path, tmp_path: Path
) -> None:
    """Without results files (gyrolab before they were kept) the report applies the model
    itself, says so, and finds the numbers compensate wrote."""
    old = tmp_path / "old-model"
    shutil.copytree(demo_run / "model", old)
    (old / RESULTS_JSON).unlink()
    (old / RESULTS_NPZ).unlink()
    out = tmp_path / "rep"
    argv = ["report", str(demo_run / "heldout.mcap"), "--model", str(old), "--out", str(out)]
    assert main(argv) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["model_results"] == "computed" and m["held_out"] is True
    html = (out / "index.html").read_text(encoding="utf-8")
    assert "The model was applied to this run by the report" in html
    assert "old-model holds no results of gyrolab compensate" in html
    read = json.loads((demo_run / "report" / "metrics.json").read_text())
    for series in ("raw", "compensated", "causal"):
        for key in METRIC_KEYS:
            assert m[series][key] == pytest.approx(read[series][key], rel=1e-6), (series, key)


def test_results_of_another_format_version_exit_2(
    demo_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "model"
    shutil.copytree(demo_run / "model", bad)
    meta = json.loads((bad / RESULTS_JSON).read_text())
    meta["format_version"] = 99
    (bad / RESULTS_JSON).write_text(json.dumps(meta))
    out = tmp_path / "rep"
    argv = ["report", str(demo_run / "heldout.mcap"), "--model", str(bad), "--out", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and RESULTS_JSON in err[0] and "format version 99" in err[0]
    assert not out.exists()
