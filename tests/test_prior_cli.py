"""``gyrolab profile design`` and ``gyrolab compensate --prior`` end to end (issue 30): a
designed profile is a TOML that ``simulate`` runs; a unit fitted with a prior learned from
earlier units' model directories records it, and a unit of another part number is refused
(one line asking for the full profile, nothing written)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import test_pipeline
from test_pipeline import SMALL, write_run

from gyrolab.cli import main
from gyrolab.compensation.profile_design import design_profile
from gyrolab.profiles.profile import load_profile
from gyrolab.record.reader import read_recording


def test_profile_design_writes_a_profile_simulate_runs(tmp_path: Path, capsys) -> None:
    out = tmp_path / "short.toml"
    assert main(["profile", "design", "--hours", "1.5", "--out", str(out)]) == 0
    p = load_profile(out)
    assert p.duration_s == pytest.approx(1.5 * 3600)
    sps = [s.setpoint_c for s in p.steps]
    assert sps[0] == 25.0 and max(sps) == 60.0 and min(sps) == -40.0 and sps[-1] == 25.0
    assert "expected drift sd" in capsys.readouterr().out
    # the output exists: not replaced without --force
    assert main(["profile", "design", "--hours", "1.5", "--out", str(out)]) == 2
    run = tmp_path / "run.mcap"
    rc = main(["simulate", "--profile", str(out), "--rate", "2", "--out", str(run)])
    assert rc == 0
    rec = read_recording(run)
    # the simulator's case follows the trace the design predicted (its chamber model)
    lo, hi = design_profile(1.5)[1]["case_range_c"]
    assert rec.pt100_c.min() == pytest.approx(lo, abs=0.3)
    assert rec.pt100_c.max() == pytest.approx(hi, abs=0.3)


def test_acquire_runs_a_designed_profile(tmp_path: Path) -> None:
    """profile design -> TOML -> ``acquire --bench sim``: the simulated bench runs the
    designed steps in order, and its case follows the trace the design predicted."""
    prof = tmp_path / "designed.toml"
    assert main(["profile", "design", "--hours", "1", "--out", str(prof)]) == 0
    run = tmp_path / "acq.mcap"
    argv = ["acquire", "--bench", "sim", "--profile", str(prof), "--speed", "200"]
    assert main([*argv, "--out", str(run)]) == 0
    rec = read_recording(run)
    want = [s.setpoint_c for s in load_profile(prof).steps]
    got = [e["setpoint_c"] for e in rec.events if e["event"] == "step_started"]
    assert got == want and rec.run["profile"]["name"] == "design-1h"
    assert rec.events[-1]["event"] == "safe_state"
    # a suspension (an engine late under load) holds a step a little longer: 1 °C slack
    lo, hi = design_profile(1.0)[1]["case_range_c"]
    assert rec.pt100_c.min() == pytest.approx(lo, abs=1.0)
    assert rec.pt100_c.max() == pytest.approx(hi, abs=1.0)


def test_profile_design_refuses_bad_hours(tmp_path: Path, capsys) -> None:
    assert main(["profile", "design", "--hours", "0.2", "--out", str(tmp_path / "x.toml")]) == 2
    assert "--hours" in capsys.readouterr().err
    assert not (tmp_path / "x.toml").exists()


#: the fleet's part number in the session's catalogue (tests/conftest.py: every command
#: registers there), unique to this module
PN = "PN-ISSUE30-FLEET"


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("fleet")
    (d / "models").mkdir()
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr("gyrolab.compensation.commands.DEFAULT_CONFIG", SMALL)
        for i in range(3):
            run = write_run(d / f"cal{i}.mcap", 100 + i, serial=f"U30-{i}", part_number=PN)
            assert main(["compensate", str(run), "--out", str(d / "models" / f"u{i}")]) == 0
    return d


def test_compensate_with_prior(fleet: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("gyrolab.compensation.commands.DEFAULT_CONFIG", SMALL)
    run = write_run(fleet / "new.mcap", 200, hours=0.6)
    out = fleet / "new-model"
    assert main(["compensate", str(run), "--prior", str(fleet / "models"), "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    prior = m["causal_model"]["selection"]["prior"]
    assert prior["prior_units"] == 3 and prior["membership"]["belongs"] is True
    assert m["causal_model"]["family"] == "structured"


def test_prior_from_the_catalogue(fleet: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    """``--prior part-number:PN``: the catalogue's latest model of every unit of PN (the
    fleet fixture's compensate runs registered them); an unknown part number is one line."""
    monkeypatch.setattr("gyrolab.compensation.commands.DEFAULT_CONFIG", SMALL)
    run = write_run(fleet / "new-pn.mcap", 201, hours=0.6)
    out = fleet / "new-pn-model"
    assert main(["compensate", str(run), "--prior", f"part-number:{PN}", "--out", str(out)]) == 0
    prior = json.loads((out / "metrics.json").read_text())["causal_model"]["selection"]["prior"]
    assert prior["prior_units"] == 3 and prior["membership"]["belongs"] is True
    capsys.readouterr()
    bad = fleet / "no-pn-model"
    rc = main(["compensate", str(run), "--prior", "part-number:NO-SUCH-PN", "--out", str(bad)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and not bad.exists()
    assert len(err) == 1 and "no unit with a registered model (part number NO-SUCH-PN)" in err[0]


def test_other_part_number_is_refused(fleet: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    monkeypatch.setattr("gyrolab.compensation.commands.DEFAULT_CONFIG", SMALL)
    # another part number: the temperature slope reversed
    monkeypatch.setattr(test_pipeline, "true_bias", lambda T: 2e-3 - 3.8e-4 * (T - 25.0))
    run = write_run(fleet / "other.mcap", 300, hours=0.6)
    out = fleet / "other-model"
    rc = main(["compensate", str(run), "--prior", str(fleet / "models"), "--out", str(out)])
    assert rc == 2 and not out.exists()
    err = capsys.readouterr().err
    assert "does not belong to the fleet prior" in err and "full profile" in err


def test_prior_needs_model_directories(tmp_path: Path, capsys) -> None:
    run = write_run(tmp_path / "r.mcap", 1, hours=0.2)
    rc = main(["compensate", str(run), "--prior", str(tmp_path / "none"), "--out", "m"])
    assert rc == 2 and "model directory not found" in capsys.readouterr().err


def test_profile_design_with_a_prior(fleet: Path, capsys) -> None:
    out = fleet / "designed.toml"
    argv = ["profile", "design", "--hours", "1", "--prior", str(fleet / "models")]
    assert main([*argv, "--out", str(out)]) == 0
    p = load_profile(out)
    assert p.duration_s == pytest.approx(3600.0) and len(p.steps) == 4
    assert "expected drift sd" in capsys.readouterr().out
