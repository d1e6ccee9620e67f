"""gyrolab demo and the report with a model: simulate -> compensate -> report, end to end.

The demo runs once per session on the short profile at 10 Hz (the paper profile at 100 Hz
is the command's default and is timed in docs/report.md); the browser test reuses it.
"""

from __future__ import annotations

import json
import re
from html.parser import HTMLParser
from pathlib import Path

import pypdf
import pytest
from contract import METRIC_KEYS

from gyrolab.app.demo import run_demo
from gyrolab.cli import main

MODEL_FIGURES = ("causal-headline", "gpso", "vmd-modes", "mpe", "drift-fit", "compensated")


def make_demo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One small demo (short profile, 10 Hz) per session, shared by the tests (the browser
    test too) that need a model: made on first use, found in the session's temp dir after.

    It registers in a catalogue of its own (:func:`demo_catalogue_file`), which only it
    writes: the session's catalogue is every test's, and one that registers a copy of the
    demo's model there (test_doc_examples exports one) moves the model's row to the copy,
    as the catalogue does for a moved file — what the demo registered then depended on
    which tests ran first."""
    out = tmp_path_factory.getbasetemp() / "demo"
    if not (out / "report" / "index.html").is_file():
        cat = str(demo_catalogue_file(out))
        run_demo(out, profile="short", seed=1, rate_hz=10.0, catalogue=cat)
    return out


def demo_catalogue_file(demo: Path) -> Path:
    """The catalogue the session's demo registered itself in (beside it, not in it)."""
    return demo.parent / "demo-catalogue.sqlite"


@pytest.fixture(scope="session")
def demo_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_demo(tmp_path_factory)


def test_demo_writes_every_stage(demo_run: Path) -> None:
    for name in (
        "calibration.mcap",
        "heldout.mcap",
        "model/model.json",
        "model/metrics.json",
        "report/index.html",
        "report/metrics.json",
        "report/report.pdf",
        "calibration-report/index.html",
        "demo.json",
    ):
        assert (demo_run / name).is_file(), name
    info = json.loads((demo_run / "demo.json").read_text())
    assert info["timing_s"]["total"] > 0 and set(info["timing_s"]) >= {"compensate", "report"}
    # the held-out run went through the wire-level simulated bench (drivers, runner)
    assert info["heldout_source"] == "acquire --bench sim"
    html = (demo_run / "report" / "index.html").read_text(encoding="utf-8")
    assert "34401A" in html and "Watlow" in html  # instrument identities from the bench


def test_demo_outputs_name_runs_relative_to_dir(demo_run: Path) -> None:
    """The stages ran in a temporary sibling (``.demo.*.part``) renamed into place: no text
    output may name it (nor any other path under DIR's parent); the runs are named relative
    to DIR, as a lab would look them up after the rename."""
    texts = [
        p
        for p in demo_run.rglob("*")
        if p.is_file() and p.suffix in {".json", ".toml", ".html", ".csv", ".md"}
    ]
    assert len(texts) >= 8  # model.json, metrics.json (x3), results.json, index.html (x2), …
    build_dir = re.compile(r"\.demo\.[^/\"'<>\s]*\.part")
    for p in texts:
        text = p.read_text(encoding="utf-8")
        assert not build_dir.search(text), f"{p.relative_to(demo_run)} names the build dir"
        assert str(demo_run.parent) not in text, f"{p.relative_to(demo_run)}: absolute path"
    model = json.loads((demo_run / "model" / "model.json").read_text())
    assert model["calibration"]["path"] == "calibration.mcap"
    fit = json.loads((demo_run / "model" / "metrics.json").read_text())
    assert (fit["run"], fit["calibration"]["run"]) == ("heldout.mcap", "calibration.mcap")
    results = json.loads((demo_run / "model" / "results.json").read_text())["runs"]
    assert {r: v["path"] for r, v in results.items()} == {
        "calibration": "calibration.mcap",
        "validation": "heldout.mcap",
    }
    held = json.loads((demo_run / "report" / "metrics.json").read_text())
    assert (held["run"], held["calibration_run"]) == ("heldout.mcap", "calibration.mcap")
    raw = json.loads((demo_run / "calibration-report" / "metrics.json").read_text())
    assert raw["run"] == "calibration.mcap"
    assert (demo_run / held["calibration_run"]).is_file()  # resolves against DIR


def test_model_report_contract(demo_run: Path) -> None:
    m = json.loads((demo_run / "report" / "metrics.json").read_text())
    # docs/cli.md metrics.json keys, with held-out metrics (the model was fitted on the other seed)
    assert m["held_out"] is True
    for key in ("raw", "compensated"):
        assert set(m[key]) >= METRIC_KEYS
    assert m["baselines"] and all(set(b) >= METRIC_KEYS for b in m["baselines"].values())
    assert isinstance(m["vmd"]["K"], int) and m["vmd"]["alpha"] > 0
    assert set(m["imf_classes"]) == {"noise", "mixed", "drift"} and m["imf_classes"]["drift"]
    assert m["timing_s"] > 0
    # the compensation removes most of the temperature drift of the held-out run
    assert m["compensated"]["drift_pp_deg_per_s"] < 0.6 * m["raw"]["drift_pp_deg_per_s"]
    # the report's numbers are the compensate command's numbers for the same run
    mm = json.loads((demo_run / "model" / "metrics.json").read_text())
    assert mm["held_out"] is True
    for key in METRIC_KEYS:
        assert m["compensated"][key] == pytest.approx(mm["compensated"][key], rel=1e-9)
    html = (demo_run / "report" / "index.html").read_text(encoding="utf-8")
    for key in ("temperature", "raw-output", "allan", *MODEL_FIGURES):
        assert f'id="fig-{key}"' in html, key
    assert 'id="tab-baselines"' in html and "held out" in html
    # the causal headline (issue 11) leads, the baselines and the paper's method beside it
    assert set(m["causal"]) >= METRIC_KEYS and m["headline"]["output"] == "causal"
    assert 'id="tab-causal-headline"' in html and 'id="fig-causal-headline"' in html
    assert html.index('id="tab-causal-headline"') < html.index('id="tab-baselines"')
    # the causal model's up/down hysteresis width (issue 30)
    assert 'id="tab-causal-hysteresis"' in html and "causal_hysteresis_width" in m
    assert "oracle" not in m  # an acquired run: its true drift is not known


def test_report_on_the_calibration_run_is_in_sample(demo_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "cal"
    assert (
        main(
            [
                "report",
                str(demo_run / "calibration.mcap"),
                "--model",
                str(demo_run / "model"),
                "--out",
                str(out),
            ]
        )
        == 0
    )
    m = json.loads((out / "metrics.json").read_text())
    assert m["held_out"] is False
    raw_only = json.loads((demo_run / "calibration-report" / "metrics.json").read_text())
    for key in METRIC_KEYS:  # same run, same raw metrics with or without the model
        assert m["raw"][key] == pytest.approx(raw_only["raw"][key], rel=1e-9)
    # a gyrolab simulate run: the oracle (true drift removed) sits beside the headline
    assert set(m["oracle"]) >= METRIC_KEYS
    assert m["oracle"]["bias_stability_deg_per_h"] < m["raw"]["bias_stability_deg_per_h"]


def test_demo_bad_input_exits_2(
    demo_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["demo", "--out", str(demo_run)]) == 2  # exists, no --force
    assert "already exists" in capsys.readouterr().err
    assert main(["demo", "--out", str(tmp_path / "d"), "--profile", "nope.toml"]) == 2
    assert "nope.toml" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()


def test_report_of_an_applied_recording_says_it_is_compensated(
    demo_run: Path, tmp_path: Path
) -> None:
    comp = tmp_path / "comp.mcap"
    assert (
        main(["apply", str(demo_run / "model"), str(demo_run / "heldout.mcap"), "--out", str(comp)])
        == 0
    )
    assert main(["report", str(comp), "--out", str(tmp_path / "r")]) == 0
    html = (tmp_path / "r" / "index.html").read_text(encoding="utf-8")
    assert "written by gyrolab apply" in html
    m = json.loads((tmp_path / "r" / "metrics.json").read_text())
    held = json.loads((demo_run / "report" / "metrics.json").read_text())
    # the applied output (causal, full rate: drift model only, no noise removal) has clearly
    # less drift than the raw held-out run (≈ 0.67x on this 48 min run, 0.14x on the paper's)
    assert m["raw"]["drift_pp_deg_per_s"] < 0.8 * held["raw"]["drift_pp_deg_per_s"]


def test_demo_report_has_noise_per_temperature_plateau(demo_run: Path) -> None:
    """The held-out (acquired) run's report tabulates ARW and bias instability per soaked
    step, with the figure against temperature."""
    from gyrolab.compensation.plateau_noise import plateau_noise
    from gyrolab.record.reader import read_recording
    from gyrolab.report.text import fmt

    html = (demo_run / "report" / "index.html").read_text(encoding="utf-8")
    assert 'id="tab-plateau-noise"' in html and 'id="fig-plateau-noise"' in html
    rows = plateau_noise(read_recording(demo_run / "heldout.mcap"))
    assert len(rows) >= 10  # the short profile has 12 steps
    for p in rows:
        assert f'<td class="num">{fmt(p.arw_deg_per_sqrt_h)}</td>' in html
        assert 0.02 < p.arw_deg_per_sqrt_h < 0.1  # the simulated unit: 0.0523 deg/sqrt(h)


def test_a_failed_acquisition_fails_the_demo_and_leaves_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """No silent fallback: the held-out acquisition refuses a setpoint above the bench's
    limits (after the calibration run was simulated), and the demo ends with that one line,
    exit 2, and no DIR nor temporary sibling left behind."""
    prof = tmp_path / "hot.toml"
    prof.write_text('name = "hot"\n[[step]]\nsetpoint_c = 150\nduration_s = 60\n')
    out = tmp_path / "d"
    assert main(["demo", "--out", str(out), "--profile", str(prof)]) == 2
    captured = capsys.readouterr()
    assert "wrote " in captured.out  # the calibration run was simulated first
    errors = [x for x in captured.err.splitlines() if x.startswith("gyrolab: error")]
    assert len(errors) == 1 and "150" in errors[0], captured.err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["hot.toml"]


class _Cells(HTMLParser):
    """Every table cell (th, td) of an HTML page, as text."""

    def __init__(self) -> None:
        super().__init__()
        self.cells: list[str] = []
        self._cell: list[str] | None = None

    def handle_starttag(self, tag: str, attrs: object) -> None:
        if tag in ("td", "th"):
            self._cell = []

    def handle_endtag(self, tag: str) -> None:
        if tag in ("td", "th") and self._cell is not None:
            self.cells.append("".join(self._cell))
            self._cell = None

    def handle_data(self, data: str) -> None:
        if self._cell is not None:
            self._cell.append(data)


def test_demo_report_pdf_keeps_every_cell_and_names_the_causal_output(demo_run: Path) -> None:
    """Issue 27: the signed page never truncates (every table cell of the report, the
    verdict's included, is whole in the PDF's text layer, with every metric's unit), and
    the headline, the Allan figure and the verdict all name the causal output."""
    from test_report_pdf import pdf_misses

    rep = demo_run / "report"
    parser = _Cells()
    parser.feed((rep / "index.html").read_text(encoding="utf-8"))
    assert len(parser.cells) > 200
    assert pdf_misses(rep / "report.pdf", [([], [parser.cells])]) == []
    text = " ".join(p.extract_text() for p in pypdf.PdfReader(rep / "report.pdf").pages)
    for unit in ("°/√h", "°/h", "°/s"):
        assert unit in text
    m = json.loads((rep / "metrics.json").read_text())
    # the demo is judged against examples/spec.toml, on the causal output
    assert m["verdict"]["series"] == "causal"
    assert m["verdict"]["spec"] == "example MEMS gyro acceptance"
    assert "metrics on the causal output" in text  # the verdict in the header
    assert "Metric limits apply to the causal output" in " ".join(text.split())
    assert "Headline: causal compensation" in text
    assert "Allan deviation: raw, causal output, offline reconstruction" in text
    html = (rep / "index.html").read_text(encoding="utf-8")
    assert "oracle" not in html.split('id="fig-causal-headline"')[1].split("</figure>")[0]


def test_headline_figure_title_names_what_it_draws() -> None:
    """The headline figure's title lists the outputs drawn: the oracle only when there is
    one (the demo's acquired run has none)."""
    import numpy as np

    from gyrolab.report import figures as F

    t = np.arange(0.0, 2000.0, 3.6)
    x = np.zeros_like(t)
    base = [("raw", x, "k"), ("causal output (poly)", x, "g"), ("offline reconstruction", x, "C1")]
    title = F.causal_headline(t, base, 3.6, 100.0).axes[0].get_title().replace("\n", " ")
    assert "oracle" not in title and "causal output (poly)" in title
    assert "offline reconstruction" in title
    with_oracle = [*base, ("oracle (true drift removed)", x, "b")]
    title = F.causal_headline(t, with_oracle, 3.6, 100.0).axes[0].get_title()
    assert "oracle (true drift removed)" in title.replace("\n", " ")
