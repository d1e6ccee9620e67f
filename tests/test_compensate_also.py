"""``gyrolab compensate RUN --also RUN2``: the causal model fitted on several power-ons."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from test_pipeline import SMALL, load, write_run

from gyrolab.batch import BatchOptions, Item, item_inputs
from gyrolab.cli import main
from gyrolab.compensation.causal import fit_causal
from gyrolab.compensation.drift_model import (
    POWER_CYCLE_GAP_S,
    CausalCalibration,
    join_calibrations,
)
from gyrolab.compensation.fit import causal_calibration
from gyrolab.compensation.model_dir import load_model

torch.set_num_threads(1)


@pytest.fixture(autouse=True)
def small_config(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("gyrolab.compensation.commands.DEFAULT_CONFIG", SMALL)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("also")
    return {
        "cal": write_run(d / "cal.mcap", 31, serial="G-7"),
        "cold": write_run(d / "cold.mcap", 32, heating=True, serial="G-7"),
        "val": write_run(d / "val.mcap", 33, heating=True, serial="G-7"),
        "dir": d,
    }


def test_join_shifts_each_part_after_the_last_and_marks_its_power_on() -> None:
    a = CausalCalibration(
        t=np.array([1.8, 5.4]), rate=np.ones(2), pt_t=np.array([0.0, 6.0]), pt_c=np.zeros(2)
    )
    b = CausalCalibration(
        t=np.array([1.8]),
        rate=np.zeros(1),
        pt_t=np.array([0.0, 1.0]),
        pt_c=np.ones(2),
        power_ons=(0.5,),
    )
    j = join_calibrations([a, b, a])
    on1 = 6.0 + POWER_CYCLE_GAP_S  # after a's last reading, its latest time
    on2 = on1 + 1.8 + POWER_CYCLE_GAP_S  # after b's last block centre
    assert j.power_ons == (on1, on1 + 0.5, on2)
    np.testing.assert_array_equal(j.t, [1.8, 5.4, on1 + 1.8, on2 + 1.8, on2 + 5.4])
    np.testing.assert_array_equal(j.rate, [1, 1, 0, 1, 1])
    np.testing.assert_array_equal(j.pt_t, [0, 6, on1, on1 + 1, on2, on2 + 6])
    assert join_calibrations([a]).power_ons == ()
    with pytest.raises(ValueError, match="no calibration"):
        join_calibrations([])


def test_the_causal_model_is_fitted_on_both_power_ons(
    runs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "model"
    cal, cold, val = (str(runs[k]) for k in ("cal", "cold", "val"))
    assert main(["compensate", cal, "--also", cold, "--validate", val, "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert f"each from its own power-on, {cold}" in printed
    m = load_model(out)
    (entry,) = m.calibration["also"]
    r_cal, r_cold, r_val = (load(Path(p)) for p in (cal, cold, val))
    assert entry["path"] == cold and entry["content_hash"] == r_cold.content_hash
    assert entry["n_points"] == r_cold.t.size
    # the ranges every output shares stay the main run's
    assert m.calibration["temp_min_c"] == pytest.approx(float(r_cal.temp.min()))
    # exactly the library's fit on the joined calibration (what break_suite scores)
    joined = causal_calibration(r_cal, [r_cold])
    assert joined.power_ons and joined.t.size == r_cal.t.size + r_cold.t.size
    ref = fit_causal(joined, config=SMALL, seed=0)
    args = (r_val.t, r_val.pt_t, r_val.pt_c)
    np.testing.assert_allclose(m.causal.drift_at(*args), ref.drift_at(*args), rtol=1e-9)
    # ... which is not the fit on the main run alone
    alone = fit_causal(causal_calibration(r_cal), config=SMALL, seed=0)
    assert not np.allclose(alone.drift_at(*args), ref.drift_at(*args), rtol=1e-6)


def _refusals(runs: dict[str, Path], d: Path) -> dict[str, tuple[list[str], str, str]]:
    cal, cold, val = (str(runs[k]) for k in ("cal", "cold", "val"))
    twin = d / "twin.mcap"
    shutil.copyfile(cal, twin)
    other = write_run(d / "other.mcap", 34, heating=True, serial="G-8")
    return {
        "the main run again": ([cal, "--also", str(twin)], "twin.mcap", "same rate"),
        "the held-out run": ([cal, "--also", cold, "--validate", cold], "cold.mcap", "same"),
        "another unit": ([cal, "--also", str(other)], "other.mcap", "unit G-8"),
        "with a prior": ([cal, "--also", cold, "--prior", str(d)], "cold.mcap", "--prior"),
        "missing": ([cal, "--also", str(d / "nope.mcap")], "nope.mcap", "not found"),
        "as the output": ([val, "--also", cold], "cold.mcap", ""),
    }


@pytest.mark.parametrize(
    "case",
    [
        "the main run again",
        "the held-out run",
        "another unit",
        "with a prior",
        "missing",
        "as the output",
    ],
)
def test_a_bad_also_is_one_line_exit_2_nothing_written(
    case: str, runs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv, name, words = _refusals(runs, tmp_path)[case]
    out = runs["cold"] if case == "as the output" else tmp_path / "out_model"
    before = runs["cold"].read_bytes()
    assert main(["compensate", *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and name in err[0] and words in err[0], err
    assert runs["cold"].read_bytes() == before
    if out != runs["cold"]:
        assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out_model")]


def test_a_batch_never_writes_over_an_also_run(tmp_path: Path) -> None:
    item = Item(tmp_path / "multi.mcap", tmp_path / "out" / "U1", "U1")
    opt = BatchOptions(validate=str(tmp_path / "v.mcap"), also=(str(tmp_path / "c.mcap"),))
    got = item_inputs("compensate", item, opt)
    assert got == [str(item.run), opt.validate, str(tmp_path / "c.mcap")]
    assert item_inputs("report", item, opt) == [str(item.run)]


def test_the_report_counts_an_also_run_as_fitted_on_and_names_it(
    runs: dict[str, Path], tmp_path: Path
) -> None:
    """A report of the cold run with that model is in sample, and says why it applied
    the model itself; the identity table names the run the causal model also saw."""
    from gyrolab.record.reader import read_recording
    from gyrolab.report.analysis import model_run
    from gyrolab.report.record_sections import identity_section

    out = tmp_path / "model"
    cal, cold = str(runs["cal"]), str(runs["cold"])
    assert main(["compensate", cal, "--also", cold, "--out", str(out)]) == 0
    m = load_model(out)
    rec = read_recording(cold)
    mr = model_run(out, m, rec)
    assert mr.held_out is False and "compensate --also" in (mr.computed or "")
    other = model_run(out, m, read_recording(str(runs["val"])))
    assert other.held_out is True
    rows = identity_section(rec, m.calibration["path"], [cold]).blocks[-1].rows
    assert ["causal model also fitted on (own power-on)", cold] in rows


def test_the_catalogue_traces_the_model_to_both_power_ons(
    runs: dict[str, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Registered as compensate ran, and again by ``runs rebuild`` from the files alone:
    the model hangs under the calibration run and under the ``--also`` run."""
    import json

    d = tmp_path / "lab"
    d.mkdir()
    for k in ("cal", "cold"):
        shutil.copyfile(runs[k], d / runs[k].name)
    out = d / "model"
    cat = f"sqlite:///{tmp_path / 'cat.sqlite'}"
    monkeypatch.setenv("GYROLAB_CATALOGUE", cat)
    argv = ["compensate", str(d / "cal.mcap"), "--also", str(d / "cold.mcap")]
    assert main([*argv, "--out", str(out)]) == 0
    rebuilt = f"sqlite:///{tmp_path / 'rebuilt.sqlite'}"
    assert main(["runs", "rebuild", str(d), "--catalogue", rebuilt]) == 0
    capsys.readouterr()
    for url in (cat, rebuilt):
        assert main(["runs", "trace", "G-7", "--json", "--catalogue", url]) == 0
        t = json.loads(capsys.readouterr().out)
        roles = {
            Path(r["segments"][0]["path"]).name: [m["role"] for m in r["models"]]
            for r in t["runs"]
        }
        assert roles == {"cal.mcap": ["calibration"], "cold.mcap": ["also"]}, url
        (also,) = t["runs"][0]["models"][0]["also"]
        assert also["path"] == str(d / "cold.mcap") and also["file_hash"].startswith("sha256:")
    assert main(["runs", "trace", "G-7", "--catalogue", cat]) == 0
    text = capsys.readouterr().out
    assert "model" in text and "(also " in text


def test_the_band_takes_dt_dt_within_each_power_on() -> None:
    """The band's calibrated dT/dt range of a joined calibration is its runs' own: the
    backward difference never compares the last reading of one run with the next's
    (a junction from +10 °C to −20 °C would read −6 °C/min), and no window spans two."""
    from gyrolab.compensation.band import fit_band
    from gyrolab.compensation.causal import blocked_folds

    rng = np.random.default_rng(5)
    tb = np.arange(1.8, 3000.0, 3.6)
    pt = np.arange(0.0, 3000.0, 1.0)
    a = CausalCalibration(t=tb, rate=np.zeros(tb.size), pt_t=pt, pt_c=pt * 0.01)  # 0.6 °C/min
    b = CausalCalibration(t=tb, rate=np.zeros(tb.size), pt_t=pt, pt_c=np.full(pt.size, -20.0))
    j = join_calibrations([a, b])
    y = rng.normal(0.0, 1e-3, j.t.size)
    folds = blocked_folds(j.t.size, 5, 10)
    band = fit_band(j.t, y, np.zeros(j.t.size), folds, j.pt_t, j.pt_c, power_ons=j.power_ons)
    assert band.rate_min_c_per_min == pytest.approx(0.0, abs=1e-9)
    assert band.rate_max_c_per_min == pytest.approx(0.6, abs=1e-6)
    blind = fit_band(j.t, y, np.zeros(j.t.size), folds, j.pt_t, j.pt_c)
    assert blind.rate_min_c_per_min < -5.0  # what it read before
