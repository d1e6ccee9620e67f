"""Profiles and bench files are strict and checked before a run; the project's contracts
live in docs/ (issue 12, point 7)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gyrolab.cli import main
from gyrolab.profiles.profile import BUILTIN
from gyrolab.record.reader import read_recording

REPO = Path(__file__).resolve().parents[1]
STEP = "[[step]]\nsetpoint_c = 25\nduration_s = 60\n"


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


@pytest.mark.parametrize(
    "text, says",
    [
        ('ambiant_c = 20\n' + STEP, "unknown key(s) ['ambiant_c']"),
        ('safe_setpiont_c = 20\n' + STEP, "unknown key(s) ['safe_setpiont_c']"),
        ("[[step]]\nsetpoint = 25\nduration_s = 60\n", "step 1: unknown key(s) ['setpoint']"),
        ("[[step]]\nsetpoint_c = 25\nduration_s = 60\nstable_slope = 0.1\n", "['stable_slope']"),
        ('safe_setpoint_c = 150\n' + STEP, "safe_setpoint_c is not a profile key"),
        ('ambient_c = "warm"\n' + STEP, "ambient_c = 'warm': expected a number"),
        ('[[step]]\nsetpoint_c = "hot"\nduration_s = 60\n', "expected a number"),
        ("[[step]]\nsetpoint_c = 20\n", "step 1: duration_s required"),
    ],
)
def test_profile_keys_are_strict(text: str, says: str, tmp_path: Path, capsys) -> None:
    prof = tmp_path / "typo.toml"
    prof.write_text(text)
    out = tmp_path / "run.mcap"
    assert main(["simulate", "--profile", str(prof), "--rate", "1", "--out", str(out)]) == 2
    line = _one_line_error(capsys)
    assert "typo.toml" in line and says in line, line
    assert not out.exists()


def test_safe_setpoint_belongs_to_the_bench(tmp_path: Path, capsys) -> None:
    """The profile has no safe setpoint (it used to be parsed and ignored); the refusal
    says where the safe state is set."""
    prof = tmp_path / "p.toml"
    prof.write_text("safe_setpoint_c = 25\n" + STEP)
    out = tmp_path / "run.mcap"
    assert main(["acquire", "--bench", "sim", "--profile", str(prof), "--out", str(out)]) == 2
    assert "[safe_state] setpoint_c in BENCH.toml" in _one_line_error(capsys)
    assert not out.exists()
    assert "safe_setpoint_c" not in BUILTIN["paper"].to_dict()


def test_short_profile_says_what_it_reaches_in_the_simulator(tmp_path: Path) -> None:
    """`short` cannot reach its -40..60 °C setpoints; its description (recorded in every
    run) and docs/profiles.md give what it does reach, measured here."""
    out = tmp_path / "short.mcap"
    assert main(["simulate", "--profile", "short", "--rate", "10", "--out", str(out)]) == 0
    rec = read_recording(out)
    desc = BUILTIN["short"].description
    m = re.search(r"chamber (-?\d+)-(\d+) °C, gyro case (\d+)-(\d+) °C", desc)
    assert m, desc
    lo_air, hi_air, lo_case, hi_case = map(float, m.groups())
    assert rec.oven_pv_c.min() == pytest.approx(lo_air, abs=0.6)
    assert rec.oven_pv_c.max() == pytest.approx(hi_air, abs=0.6)
    assert rec.pt100_c.min() == pytest.approx(lo_case, abs=0.6)
    assert rec.pt100_c.max() == pytest.approx(hi_case, abs=0.6)
    assert rec.run["profile"]["description"] == desc  # recorded with the run
    doc = (REPO / "docs" / "profiles.md").read_text()
    assert f"{rec.pt100_c.min():.1f} … {rec.pt100_c.max():.1f} °C" in doc


def _bench(tmp_path: Path, **limits: float) -> Path:
    text = (REPO / "examples" / "lab.toml").read_text()
    for k, v in limits.items():
        text, n = re.subn(rf"^{k} = [-\d.]+", f"{k} = {v}", text, flags=re.M)
        assert n == 1, k
    f = tmp_path / "bench.toml"
    f.write_text(text)
    return f


@pytest.mark.parametrize(
    "limits, says",
    [
        ({"setpoint_max_c": 700.0}, "setpoint_max_c = 700 °C is outside the physical bounds"),
        ({"setpoint_min_c": -273.0}, "setpoint_min_c = -273 °C is outside the physical bounds"),
        ({"pt100_max_c": 900.0}, "pt100_max_c = 900 °C is outside the physical bounds"),
        # The watchdog window below the profile's range (paper: -40..60 °C): the run would
        # be aborted at the 60 °C step; refused before anything is opened.
        ({"pt100_max_c": 50.0}, "would stop profile paper at step 2 (setpoint 60 °C)"),
        ({"pt100_min_c": -39.0}, "would stop profile paper at step 12 (setpoint -40 °C)"),
        ({"pt100_max_c": 61.0}, "with 2 °C to spare"),
    ],
)
def test_bench_limits_are_sane_and_fit_the_profile(
    limits: dict[str, float], says: str, tmp_path: Path, capsys
) -> None:
    bench = _bench(tmp_path, **limits)
    out = tmp_path / "run.mcap"
    assert main(["acquire", "--bench", str(bench), "--out", str(out)]) == 2
    line = _one_line_error(capsys)
    assert "bench.toml" in line and says in line, line
    assert not out.exists()


def test_no_citation_of_the_design_notes_outside_docs(tmp_path: Path) -> None:
    """Code, docs, tests and --help cite docs/ pages, not the design notes that live
    outside the repository."""
    name = "DESIGN" + ".md"
    hits = []
    files = [REPO / "README.md", *REPO.glob("docs/*.md"), *REPO.glob("gyrolab/**/*.py")]
    files += list(REPO.glob("tests/**/*.py"))
    for f in files:
        if name in f.read_text(encoding="utf-8"):
            hits.append(str(f.relative_to(REPO)))
    assert hits == []
    helps = [[]] + [[c] for c in ("simulate", "acquire", "compensate", "apply", "report")]
    helps += [["discrepancy"], ["recover"], ["demo"]]
    for sub in helps:
        r = subprocess.run(
            [sys.executable, "-m", "gyrolab", *sub, "--help"], capture_output=True, text=True
        )
        assert r.returncode == 0 and name not in r.stdout, sub
    assert (REPO / "docs" / "cli.md").is_file() and (REPO / "docs" / "profiles.md").is_file()


def test_paper_ramps_is_the_staircase_then_one_cycle_and_listed() -> None:
    """``paper_ramps`` (docs/profiles.md) is ``paper`` unchanged plus one heating and one
    cooling step at the extremes, and every built-in profile is named in the CLI's help."""
    import gyrolab.cli as cli

    paper, ramps = BUILTIN["paper"].steps, BUILTIN["paper_ramps"].steps
    assert ramps[: len(paper)] == paper
    assert [(s.setpoint_c, s.duration_s) for s in ramps[len(paper) :]] == [
        (60.0, 7200.0),
        (-40.0, 7200.0),
    ]
    assert set(BUILTIN) <= {n.strip() for n in cli._PROFILES.split("|")}


def test_cold_start_powers_on_soaked_at_its_first_setpoint() -> None:
    """``cold_start`` (docs/profiles.md; ``compensate --also``): the unit starts at
    −20 °C, where the chamber holds it for the first hour, 3.5 h in all; the simulator
    starts the unit there (its first PT100 reading)."""
    from gyrolab.sim.model import nominal_model
    from gyrolab.sim.physics import Physics

    p = BUILTIN["cold_start"]
    assert p.ambient_c == p.steps[0].setpoint_c == -20.0 and p.steps[0].duration_s == 3600.0
    assert p.duration_s == 3.5 * 3600 and max(s.setpoint_c for s in p.steps) == 40.0
    phys = Physics(nominal_model(), rate_hz=1.0, seed=0, ambient_c=p.ambient_c)
    phys.set_setpoint(p.steps[0].setpoint_c)
    b = phys.advance(10)
    assert np.all(np.abs(b.case_trace + 20.0) < 0.05)
