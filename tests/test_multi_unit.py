"""Multi-unit recordings: layout, unit selection, `simulate --units`, and compensate /
report / discrepancy with and without `--unit` (docs/fleet.md, docs/recording-format.md)."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from test_pipeline import SMALL

from gyrolab.cli import main
from gyrolab.errors import InputError
from gyrolab.outputs import MARKER
from gyrolab.record.format import TOPIC_PT100, TOPIC_RATE, unit_topic
from gyrolab.record.reader import list_units, read_recording, select_unit
from gyrolab.record.writer import RecordingWriter
from gyrolab.sim.family import unit_family
from gyrolab.sim.model import nominal_model

torch.set_num_threads(1)

CLI_CONFIG = replace(SMALL, vmd_K=None, vmd_alpha=None, gpso_population=4, gpso_generations=1)
SERIALS = ["SIM3-01", "SIM3-02", "SIM3-03"]


@pytest.fixture(autouse=True)
def small_config(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("gyrolab.compensation.commands.DEFAULT_CONFIG", CLI_CONFIG)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("units")
    common = ["--profile", "short", "--rate", "10", "--seed", "3"]
    assert main(["simulate", "--out", str(d / "multi.mcap"), "--units", "3", *common]) == 0
    assert main(["simulate", "--out", str(d / "single.mcap"), *common]) == 0
    return {"multi": d / "multi.mcap", "single": d / "single.mcap", "dir": d}


def _topics(path: Path) -> set[str]:
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
        assert summary is not None
        return {c.topic for c in summary.channels.values()}


def test_layout_per_unit_topics_and_shared_chamber(runs: dict[str, Path]) -> None:
    multi, single = runs["multi"], runs["single"]
    assert list_units(multi) == SERIALS and list_units(single) == []
    per_unit = {
        f"/unit/{s}{t}"
        for s in SERIALS
        for t in ("/gyro/adc", TOPIC_RATE, "/gyro/rate_summary", TOPIC_PT100)
    }
    shared = {"/oven/state", "/profile/event", "/log", "/log/foxglove"}
    assert _topics(multi) == per_unit | shared
    assert _topics(single) == {t for t in _topics(multi) if not t.startswith("/unit/")} | {
        "/gyro/adc",
        TOPIC_RATE,
        "/gyro/rate_summary",
        TOPIC_PT100,
    }
    assert not any(t.startswith("/unit/") for t in _topics(single))
    assert unit_topic("/oven/state", "X") == "/oven/state"
    recs = [read_recording(multi, unit=s) for s in SERIALS]
    for s, rec in zip(SERIALS, recs, strict=True):
        assert rec.unit == s and rec.run["unit_serial"] == s and rec.run["units"] == SERIALS
        assert rec.rate is not None and rec.rate.t.size == 0.8 * 3600 * 10
        assert rec.pt100_t.size > 0 and rec.oven_t.size > 0
    # one chamber: the same oven record for every unit; units differ (a dispersed family)
    np.testing.assert_array_equal(recs[0].oven_pv_c, recs[2].oven_pv_c)
    means = [float(np.mean(r.rate.values)) for r in recs]  # type: ignore[union-attr]
    assert min(abs(a - b) for i, a in enumerate(means) for b in means[i + 1 :]) > 1e-4


def test_unit_family_is_deterministic_and_shares_the_chamber() -> None:
    a, b = unit_family(nominal_model(), 4, 7), unit_family(nominal_model(), 4, 7)
    assert [u.serial for u in a] == ["SIM7-01", "SIM7-02", "SIM7-03", "SIM7-04"]
    assert [u.model.to_toml() for u in a] == [u.model.to_toml() for u in b]
    assert len({u.seed for u in a}) == 4
    assert len({u.model.get("bias_poly").params["c1"] for u in a}) == 4  # type: ignore[union-attr]
    assert {u.model.thermal.air_tau_s for u in a} == {nominal_model().thermal.air_tau_s}


def test_unit_selection_rules(runs: dict[str, Path]) -> None:
    multi, single = runs["multi"], runs["single"]
    assert select_unit(single, None) is None
    assert select_unit(multi, "SIM3-02") == "SIM3-02"
    with pytest.raises(
        InputError, match="choose one with --unit SERIAL: SIM3-01, SIM3-02, SIM3-03"
    ):
        select_unit(multi, None)
    with pytest.raises(InputError, match="has no unit 'NOPE'; its units: SIM3-01"):
        select_unit(multi, "NOPE")
    with pytest.raises(InputError, match="single-unit recording"):
        select_unit(single, "SIM3-01")
    with pytest.raises(ValueError, match="serial"):
        RecordingWriter(runs["dir"] / "x.mcap", start_time_ns=0, units=["a/b"])


def test_report_and_discrepancy_need_a_unit_of_a_multi_unit_run(
    runs: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    d = runs["dir"]
    for cmd in ("report", "discrepancy"):
        assert main([cmd, str(runs["multi"]), "--out", str(d / f"no-{cmd}")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "SIM3-01, SIM3-02, SIM3-03" in err[0]
        assert not (d / f"no-{cmd}").exists()
        assert main([cmd, str(runs["multi"]), "--unit", "X", "--out", str(d / f"x-{cmd}")]) == 2
        assert not (d / f"x-{cmd}").exists()
        assert "has no unit 'X'" in capsys.readouterr().err


@pytest.fixture(scope="module")
def fleet_models(runs: dict[str, Path]) -> Path:
    """`gyrolab compensate MULTI --out DIR`: every unit, on a 2-worker LocalCluster."""
    out = runs["dir"] / "models"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr("gyrolab.compensation.commands.DEFAULT_CONFIG", CLI_CONFIG)
        assert main(["compensate", str(runs["multi"]), "--out", str(out), "--workers", "2"]) == 0
    return out


def test_compensate_fits_every_unit(fleet_models: Path, runs: dict[str, Path]) -> None:
    assert sorted(p.name for p in fleet_models.iterdir()) == [MARKER, *SERIALS]
    for s in SERIALS:
        meta = json.loads((fleet_models / s / "model.json").read_text())
        assert meta["calibration"]["unit"] == s
        assert meta["calibration"]["path"] == str(runs["multi"])
        m = json.loads((fleet_models / s / "metrics.json").read_text())
        assert m["unit"] == s and m["held_out"] is False
        assert set(m["oracle"]) == set(m["raw"])  # the unit's own true drift, replayed
    # --unit gives that unit's model alone: the same bytes as its directory in the fleet
    one = runs["dir"] / "one"
    assert main(["compensate", str(runs["multi"]), "--unit", "SIM3-02", "--out", str(one)]) == 0
    assert (one / "model.json").read_bytes() == (
        fleet_models / "SIM3-02" / "model.json"
    ).read_bytes()


def test_prior_fits_one_named_unit_of_a_multi_unit_run(
    runs: dict[str, Path], fleet_models: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--prior`` tests each unit against the prior on its own: a multi-unit run without
    ``--unit`` is one line asking for it, nothing written; with it, that unit is fitted."""
    d = runs["dir"]
    out = d / "prior-all"
    argv = ["compensate", str(runs["multi"]), "--prior", str(fleet_models)]
    assert main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "name it with --unit" in err[0] and str(runs["multi"]) in err[0]
    assert not out.exists()
    one = d / "prior-one"
    assert main([*argv, "--unit", "SIM3-03", "--out", str(one)]) == 0
    m = json.loads((one / "metrics.json").read_text())
    assert m["unit"] == "SIM3-03"
    assert m["causal_model"]["selection"]["prior"]["prior_units"] == len(SERIALS)


def test_compensate_without_unit_and_report_with_unit(
    runs: dict[str, Path], fleet_models: Path
) -> None:
    d = runs["dir"]
    single = runs["single"]
    assert main(["compensate", str(single), "--out", str(d / "m_single")]) == 0
    meta = json.loads((d / "m_single" / "model.json").read_text())
    # the serial the recording names travels into the model and its metrics (issue 27)
    serial = read_recording(single).run["unit_serial"]
    assert serial and meta["calibration"]["unit"] == serial
    assert json.loads((d / "m_single" / "metrics.json").read_text())["unit"] == serial
    # a unit's report with its model, held out on another unit of the same run
    out = d / "rep2"
    model = fleet_models / "SIM3-01"
    assert main(["report", str(runs["multi"]), "--unit", "SIM3-02", "--model", str(model),
                 "--out", str(out)]) == 0  # fmt: skip
    m = json.loads((out / "metrics.json").read_text())
    assert m["unit"] == "SIM3-02" and m["held_out"] is True
    cal = json.loads((fleet_models / "SIM3-02" / "metrics.json").read_text())
    assert m["raw"] == pytest.approx(cal["raw"])  # the same unit's data as compensate read


def test_discrepancy_reads_the_selected_unit(runs: dict[str, Path]) -> None:
    from gyrolab.sim.discrepancy.data import load_recording

    a = load_recording(runs["multi"], unit="SIM3-01")
    b = load_recording(runs["multi"], unit="SIM3-03")
    rec = read_recording(runs["multi"], unit="SIM3-03")
    assert rec.rate is not None
    assert not np.allclose(a.pt100_c, b.pt100_c) and not np.allclose(a.y, b.y)
    np.testing.assert_allclose(b.pt100_c, rec.pt100_c)


# ------------------------------------------------------------------ the fleet record


def test_robust_z_and_wilson_against_hand_values() -> None:
    from gyrolab.report.fleet import robust_z, wilson

    x = np.array([1.0, 2.0, 3.0, 4.0, 100.0])  # median 3, MAD median(|[-2,-1,0,1,97]|) = 1
    np.testing.assert_allclose(robust_z(x), 0.6745 * (x - 3.0))
    y = np.array([5.0, 5.0, 5.0, 5.0, 9.0])  # MAD 0: mean absolute deviation 0.8 instead
    np.testing.assert_allclose(robust_z(y), (y - 5.0) / (1.253314 * 0.8))
    z = 1.959964
    assert wilson(0, 10) == pytest.approx((0.0, z * z / (10 + z * z)))
    assert wilson(10, 10)[1] == pytest.approx(1.0)


def test_fleet_record(fleet_models: Path, runs: dict[str, Path]) -> None:
    import csv

    import pyarrow.parquet as pq

    from gyrolab.report.fleet import robust_z

    # six units: the three fitted ones and three copies with other serials; one copy's
    # causal (compensated) drift made 50x worse (an outlier, and a spec failure)
    root = runs["dir"] / "fleet_in"
    root.mkdir()
    for k, s in enumerate([*SERIALS, *SERIALS]):
        name = s if k < 3 else f"{s}-B"
        shutil.copytree(fleet_models / s, root / name)
        meta = json.loads((root / name / "model.json").read_text())
        meta["calibration"]["unit"] = name
        (root / name / "model.json").write_text(json.dumps(meta))
        if name == "SIM3-02-B":
            m = json.loads((root / name / "metrics.json").read_text())
            m["causal"]["drift_pp_deg_per_s"] *= 50
            (root / name / "metrics.json").write_text(json.dumps(m))
    spec = runs["dir"] / "spec.toml"
    # in-sample models of a short run: counted only because this spec allows them
    spec.write_text(
        'name = "t"\nmax_drift_pp_deg_per_s = 0.01\nrequire_complete = true\n'
        "allow_in_sample = true\nmin_calibrated_span_c = 5\n"
    )
    out = runs["dir"] / "fleet"
    assert main(["fleet", str(root), "--spec", str(spec), "--out", str(out)]) == 0
    assert json.loads((out / MARKER).read_text())["command"] == "fleet"
    with open(out / "units.csv", newline="") as fh:
        units = list(csv.DictReader(fh))
    assert sorted(u["unit"] for u in units) == sorted([*SERIALS, *(s + "-B" for s in SERIALS)])
    table = pq.read_table(out / "units.parquet").to_pylist()  # the same table, read back
    assert [r["unit"] for r in table] == [u["unit"] for u in units]
    col = "causal.drift_pp_deg_per_s"
    x = np.array([float(u[col]) for u in units])
    np.testing.assert_allclose([r[col] for r in table], x)
    z = robust_z(x)
    flagged = {(o["unit"], o["quantity"]) for o in csv.DictReader(open(out / "outliers.csv"))}
    assert ("SIM3-02-B", col) in flagged
    assert {u for (u, q) in flagged if q == col} == {
        units[i]["unit"] for i in np.flatnonzero(np.abs(z) > 3.5)
    }
    doc = json.loads((out / "fleet.json").read_text())
    y = doc["yield"]
    expect = sum(v <= 0.01 for v in x)
    assert (y["passed"], y["total"]) == (expect, 6) and y["not_checked"] == ["require_complete"]
    verdicts = {u["unit"]: u["verdict"] for u in units}
    assert verdicts["SIM3-02-B"] == "FAIL"
    html = (out / "index.html").read_text()
    assert "SIM3-02-B" in html and "Yield against the spec" in html


def test_fleet_bad_input_is_exit_2(runs: dict[str, Path]) -> None:
    empty = runs["dir"] / "empty"
    empty.mkdir()
    assert main(["fleet", str(empty), "--out", str(runs["dir"] / "f2")]) == 2
    assert not (runs["dir"] / "f2").exists()


def test_fleet_counts_only_validated_units_named_by_serial(
    fleet_models: Path, runs: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 27: one validated model (--validate) and two in-sample ones: the yield is 1/1,
    the in-sample units are marked and not counted, every unit is named by its serial; a
    model calibrated over a short run's 7 °C is marked narrow range unless the spec allows
    it."""
    d = runs["dir"] / "fleet3"
    d.mkdir()
    argv = ["compensate", str(runs["multi"]), "--unit", "SIM3-01",
            "--validate", str(runs["single"]), "--out", str(d / "validated")]  # fmt: skip
    assert main(argv) == 0
    for s in ("SIM3-02", "SIM3-03"):
        shutil.copytree(fleet_models / s, d / f"folder-{s}")  # folders named otherwise
    spec = runs["dir"] / "spec3.toml"
    spec.write_text("max_drift_pp_deg_per_s = 1.0\nmin_calibrated_span_c = 5\n")
    out = runs["dir"] / "fleet3-out"
    assert main(["fleet", str(d), "--spec", str(spec), "--out", str(out)]) == 0
    assert "yield 1/1" in capsys.readouterr().err
    doc = json.loads((out / "fleet.json").read_text())
    assert (doc["yield"]["passed"], doc["yield"]["total"]) == (1, 1)
    status = {u["unit"]: (u["status"], u["counted_in_yield"]) for u in doc["units"]}
    assert set(status) == set(SERIALS)  # serials, not folder names
    assert status["SIM3-01"] == ("validated", True)
    for s in ("SIM3-02", "SIM3-03"):
        assert status[s][0].startswith("not validated") and status[s][1] is False
    html = (out / "index.html").read_text()
    assert "not validated (in-sample metrics" in html and "1/1" in html
    # the default span (30 °C): the short run's models are all narrow range, none counted
    spec.write_text("max_drift_pp_deg_per_s = 1.0\n")
    out2 = runs["dir"] / "fleet3-default"
    assert main(["fleet", str(d), "--spec", str(spec), "--out", str(out2)]) == 0
    doc = json.loads((out2 / "fleet.json").read_text())
    assert doc["yield"]["total"] == 0
    assert all("narrow range (calibrated 25" in u["status"] for u in doc["units"])
    # no cell left empty without its reason: f(T) at 25 °C, just below a unit's range
    html = (out2 / "index.html").read_text()
    for u in doc["units"]:
        if u["bias_at_25c_dps"] is None:  # NaN in the JSON
            assert u["temp_min_c"] > 25.0 and "25 °C outside 25" in html


def test_also_takes_each_units_own_run_of_a_multi_unit_recording(
    runs: dict[str, Path],
) -> None:
    """``compensate MULTI --also MULTI2``: every unit's causal model gets that unit's run
    of MULTI2 (by serial), in the fan-out over units."""
    from gyrolab.compensation.axis_runs import load_runs

    d = runs["dir"]
    cold, prof = d / "multi_cold.mcap", d / "cold.toml"
    # the same units (the family's seed), powered on cold: a short cold_start
    steps = "".join(
        f"[[step]]\nsetpoint_c = {c}\nduration_s = {s}\n" for c, s in ((-20, 600), (40, 900))
    )
    prof.write_text(f'name = "cold"\nambient_c = -20.0\n{steps}')
    common = ["--profile", str(prof), "--rate", "10", "--seed", "3", "--units", "3"]
    assert main(["simulate", "--out", str(cold), *common]) == 0
    out = d / "models_also"
    argv = ["compensate", str(runs["multi"]), "--also", str(cold), "--workers", "2"]
    assert main([*argv, "--out", str(out)]) == 0
    for s in SERIALS:
        (also,) = json.loads((out / s / "model.json").read_text())["calibration"]["also"]
        (want,) = load_runs(str(cold), CLI_CONFIG, unit=s)
        assert also["content_hash"] == want.content_hash and also["path"] == str(cold)


def _sha12(path: Path) -> str:
    import hashlib

    return hashlib.sha256(path.read_bytes()).hexdigest()[:12]


def test_apply_compensates_the_named_unit_and_copies_every_other_topic(
    fleet_models: Path, runs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`gyrolab apply DIR MULTI --unit S`: unit S's rate compensated by DIR/S (or by its
    model directory given itself: the same bytes), its raw and offline topics beside it
    under its prefix, every other unit's topics and the shared ones unchanged."""
    from gyrolab.compensation.apply_command import TOPIC_RATE_OFFLINE, TOPIC_RATE_RAW
    from gyrolab.compensation.model_dir import load_model
    from gyrolab.record.reader import iter_blocks, iter_messages, read_metadata

    multi, s = runs["multi"], "SIM3-02"
    out, out2 = tmp_path / "dir.mcap", tmp_path / "model.mcap"
    assert main(["apply", str(fleet_models), str(multi), "--unit", s, "--out", str(out)]) == 0
    assert f"unit {s} compensated" in capsys.readouterr().err
    assert main(["apply", str(fleet_models / s), str(multi), "--unit", s, "--out", str(out2)]) == 0
    assert out.read_bytes() == out2.read_bytes()
    added = {unit_topic(TOPIC_RATE_RAW, s), unit_topic(TOPIC_RATE_OFFLINE, s)}
    assert _topics(out) == _topics(multi) | added
    src, dst = read_recording(multi, unit=s), read_recording(out, unit=s)
    np.testing.assert_array_equal(dst.rate.t, src.rate.t)
    np.testing.assert_array_equal(dst.rate.index, src.rate.index)
    raw = np.concatenate([b[3] for b in iter_blocks(out, unit_topic(TOPIC_RATE_RAW, s))])
    np.testing.assert_array_equal(raw, src.rate.values.astype(np.float32))
    model = load_model(str(fleet_models / s))
    expect = src.rate.values - model.causal.drift_at(src.rate.t, src.pt100_t, src.pt100_c)
    np.testing.assert_allclose(dst.rate.values, expect, atol=1e-6)
    assert np.ptp(dst.rate.values) < np.ptp(src.rate.values)  # the unit's drift taken out
    off = list(iter_blocks(out, unit_topic(TOPIC_RATE_OFFLINE, s)))
    assert off and off[0][1] == pytest.approx(3.6)
    # the other units and the chamber: message for message what the input holds
    kept = sorted(_topics(multi) - {unit_topic(TOPIC_RATE, s)})
    assert list(iter_messages(out, kept)) == list(iter_messages(multi, kept))
    meta = read_metadata(out)
    assert {k: v for k, v in meta.items() if k != "compensation"} == read_metadata(multi)
    comp = meta["compensation"]
    assert comp["unit"] == s and comp["model_dir"] == str(fleet_models / s)
    assert set(comp["topics"]) == {unit_topic(TOPIC_RATE, s), *added}
    assert comp["calibrated_range"]["unit_mismatch"] is False
    # the catalogue: the unit's own model, applied (both copies are one file, the same
    # bytes: the latest path); the other units' models of the run are theirs, not listed
    assert main(["runs", "trace", s]) == 0
    text = capsys.readouterr().out
    assert str(fleet_models / s) in text and f"applied {_sha12(out)} {out2}" in text
    assert not any(str(fleet_models / o) in text for o in SERIALS if o != s)


def test_apply_to_a_multi_unit_run_refuses_what_it_cannot_take(
    fleet_models: Path, runs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """One model and no --unit, a DIR short of a unit's model, a unit the run lacks, another
    unit's model: one line each (exit 2, nothing written), or a warning for the last."""
    multi, out = runs["multi"], tmp_path / "c.mcap"
    partial = tmp_path / "partial"
    shutil.copytree(fleet_models / "SIM3-01", partial / "SIM3-01")
    cases = [
        ([str(partial / "SIM3-01"), str(multi)], "holds 3 units; choose one with --unit SERIAL"),
        ([str(partial), str(multi)], "has no model for unit SIM3-02, SIM3-03 of"),
        ([str(fleet_models), str(multi), "--unit", "SN9"], "has no unit 'SN9'"),
        ([str(partial), str(multi), "--unit", "SIM3-03"], "has no model for unit SIM3-03;"),
    ]
    for args, msg in cases:
        assert main(["apply", *args, "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert msg in err and len(err.strip().splitlines()) == 1, err
        assert not out.exists()
    # SIM3-01's model on SIM3-03: applied, with the warning that it is another unit's drift
    assert (
        main(
            ["apply", str(partial / "SIM3-01"), str(multi), "--unit", "SIM3-03", "--out", str(out)]
        )
        == 0
    )
    err = capsys.readouterr().err
    assert "fitted on unit SIM3-01, this run is unit SIM3-03" in err


def test_apply_without_unit_compensates_every_unit_by_its_own_model(
    fleet_models: Path, runs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`gyrolab apply DIR MULTI`: every unit by DIR/<serial>, in one copy; the catalogue
    links the copy to each unit's model, as registered and as rebuilt from the files."""
    from gyrolab.compensation.apply_command import TOPIC_RATE_OFFLINE, TOPIC_RATE_RAW
    from gyrolab.compensation.model_dir import load_model
    from gyrolab.record.reader import iter_messages, read_metadata

    multi, out = runs["multi"], tmp_path / "all.mcap"
    assert main(["apply", str(fleet_models), str(multi), "--out", str(out)]) == 0
    assert f"units {', '.join(SERIALS)} compensated" in capsys.readouterr().err
    added = {unit_topic(t, s) for s in SERIALS for t in (TOPIC_RATE_RAW, TOPIC_RATE_OFFLINE)}
    assert _topics(out) == _topics(multi) | added
    for s in SERIALS:
        src, dst = read_recording(multi, unit=s), read_recording(out, unit=s)
        model = load_model(str(fleet_models / s))
        d = model.causal.drift_at(src.rate.t, src.pt100_t, src.pt100_c)
        np.testing.assert_allclose(dst.rate.values, src.rate.values - d, atol=1e-6)
    shared = sorted(t for t in _topics(multi) if not t.startswith("/unit/"))
    assert list(iter_messages(out, shared)) == list(iter_messages(multi, shared))
    comp = read_metadata(out)["compensation"]
    assert list(comp["units"]) == SERIALS and "unit" not in comp
    for s in SERIALS:
        assert comp["units"][s]["model_dir"] == str(fleet_models / s)
        assert set(comp["units"][s]["topics"]) == {unit_topic(TOPIC_RATE, s)} | {
            unit_topic(t, s) for t in (TOPIC_RATE_RAW, TOPIC_RATE_OFFLINE)
        }
    # registered, and rebuilt from the files into a new catalogue: under every unit's model
    # (the run copied beside the copy: the module's directory holds other tests' files)
    shutil.copy(multi, tmp_path / "multi.mcap")
    rebuilt = tmp_path / "rebuilt.sqlite"
    argv = ["runs", "rebuild", str(fleet_models), str(tmp_path), "--catalogue", str(rebuilt)]
    assert main(argv) == 0
    capsys.readouterr()
    for cat in ([], ["--catalogue", str(rebuilt)]):
        for s in SERIALS:
            assert main(["runs", "trace", s, *cat]) == 0
            text = capsys.readouterr().out
            model_line = text.index(str(fleet_models / s))
            assert f"applied {_sha12(out)} {out}" in text[model_line:], (s, cat, text)
