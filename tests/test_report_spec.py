"""Spec limits (gyrolab/report/spec_limits.py), the verdict and the sign-off block of a report."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from gyrolab.cli import main
from gyrolab.errors import InputError
from gyrolab.report.spec_limits import evaluate, load_spec

METRICS = {
    "raw": {
        "arw_deg_per_sqrt_h": 0.05,
        "bias_instability_deg_per_h": 0.8,
        "bias_stability_deg_per_h": 31.0,
        "drift_pp_deg_per_s": 0.03,
        "rms_deg_per_s": 0.01,
    },
    "causal": {
        "arw_deg_per_sqrt_h": 0.05,
        "bias_instability_deg_per_h": 0.45,
        "bias_stability_deg_per_h": 0.7,
        "drift_pp_deg_per_s": 0.0015,
        "rms_deg_per_s": None,
    },
    # the paper's offline reconstruction (low-passed): judged only when a spec names it
    "compensated": {
        "arw_deg_per_sqrt_h": 0.03,
        "bias_instability_deg_per_h": 0.1,
        "bias_stability_deg_per_h": 0.5,
        "drift_pp_deg_per_s": 0.0009,
        "rms_deg_per_s": None,
    },
}


def _spec(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "spec.toml"
    p.write_text(text)
    return p


def test_each_limit_passes_or_fails_and_the_verdict_needs_all(tmp_path: Path) -> None:
    spec = load_spec(
        _spec(
            tmp_path,
            'name = "G-7 rev B"\nmax_bias_stability_deg_per_h = 1.0\n'
            "max_drift_pp_deg_per_s = 0.001\nmin_temperature_coverage = 0.9\n"
            "max_gap_s = 5\nrequire_complete = true\nrequire_safe_state = true\n",
        )
    )
    v = evaluate(spec, METRICS, has_model=True, coverage_fraction=0.95, gap_s=0.0,
                 complete=True, safe_state_ok=True)  # fmt: skip
    got = {line.quantity: (line.measured, line.passed) for line in v.lines}
    assert got == {  # the causal output by default, when there is a model
        "bias stability (causal output)": ("0.7", True),
        "drift peak-to-peak (causal output)": ("0.0015", False),
        "temperature coverage (gyro case)": ("95.0 %", True),
        "gyro data missing in gaps": ("0", True),
        "run complete": ("yes", True),
        "oven safe state verified": ("yes", True),
    }
    assert v.word == "FAIL" and "drift peak-to-peak (causal output)" in v.summary()
    assert "metrics on the causal output" in v.summary()
    # the failing line as the command prints it: value, unit and limit
    bad = next(line for line in v.lines if not line.passed)
    assert bad.text() == "drift peak-to-peak (causal output): 0.0015 °/s (limit ≤ 0.001 °/s) FAIL"
    # "compensated" is the causal output too; the offline reconstruction only by its name
    for series, expect in (("compensated", "0.0015"), ("causal", "0.0015"), ("offline", "0.0009")):
        text = f'series = "{series}"\nmax_drift_pp_deg_per_s = 0.001\n'
        line = evaluate(load_spec(_spec(tmp_path, text)), METRICS, has_model=True).lines[0]
        assert line.measured == expect
        name = "offline" if series == "offline" else "causal"
        assert line.quantity == f"drift peak-to-peak ({name} output)"
    # raw series chosen explicitly; an unmeasured value fails
    spec2 = load_spec(_spec(tmp_path, 'series = "raw"\nmax_arw_deg_per_sqrt_h = 0.06\n'))
    assert evaluate(spec2, METRICS, has_model=True).word == "PASS"
    spec3 = load_spec(_spec(tmp_path, "max_rms_deg_per_s = 1\nmin_temperature_coverage = 0.5"))
    v3 = evaluate(spec3, METRICS, has_model=True, coverage_fraction=math.nan)
    assert [line.passed for line in v3.lines] == [False, False] and v3.word == "FAIL"


@pytest.mark.parametrize(
    "text, message",
    [
        ("max_bias_stabilty_deg_per_h = 1\n", "unknown key(s) max_bias_stabilty_deg_per_h"),
        ('max_arw_deg_per_sqrt_h = "low"\n', "max_arw_deg_per_sqrt_h must be a number"),
        ("min_temperature_coverage = 90\n", "must be between 0 and 1"),
        ('series = "filtered"\n', "series must be one of raw, causal, compensated, offline"),
        ("require_complete = 1\n", "require_complete must be true or false"),
        ("max_rms_deg_per_s = \n", "not valid TOML"),
    ],
)
def test_bad_spec_files_are_refused(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)")):
        load_spec(_spec(tmp_path, text))


@pytest.fixture(scope="module")
def short_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("run") / "short.mcap"
    argv = ["simulate", "--out", str(out), "--profile", "short", "--rate", "10", "--seed", "3"]
    assert main(argv) == 0
    return out


def test_report_with_spec_gives_verdict_and_sign_off(
    short_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    spec = _spec(tmp_path, "max_arw_deg_per_sqrt_h = 0.2\nmin_temperature_coverage = 0.99\n")
    out = tmp_path / "rep"
    argv = ["report", str(short_run), "--out", str(out), "--spec", str(spec),
            "--operator", "A. Tester", "--unit-serial", "G-0042"]  # fmt: skip
    assert main(argv) == 0
    m = json.loads((out / "metrics.json").read_text())
    v = m["verdict"]
    assert v["series"] == "raw" and [x["passed"] for x in v["lines"]] == [True, False]
    # the short profile's gyro case stays far inside -40…60 °C: coverage fails, honestly
    assert m["coverage"]["case_fraction"] < 0.99 and v["verdict"] == "FAIL"
    # the terminal names each failing line with its value and limit (and only those)
    err = capsys.readouterr().err.splitlines()
    assert "verdict: FAIL (metric limits on the raw output)" in err
    cov = f"{100 * m['coverage']['case_fraction']:.1f} %"
    assert f"  temperature coverage (gyro case): {cov} (limit ≥ 99 %) FAIL" in err
    assert not any("angle random walk" in line for line in err)
    html = (out / "index.html").read_text(encoding="utf-8")
    assert 'id="tab-verdict"' in html and 'id="tab-signoff"' in html
    assert "A. Tester" in html and "Temperature test report — G-0042" in html
    assert 'class="st st-FAIL"' in html


def test_report_with_bad_spec_exits_2_and_writes_nothing(
    short_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    spec = _spec(tmp_path, "max_arw = 0.2\n")
    out = tmp_path / "rep"
    assert main(["report", str(short_run), "--out", str(out), "--spec", str(spec)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "spec.toml" in err[0] and "unknown key(s) max_arw" in err[0]
    assert not out.exists()
