"""gyrolab report: the raw record, the HTML/PDF writers, the run log, bad input."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from contract import METRIC_KEYS

from gyrolab.cli import main
from gyrolab.record.writer import RecordingWriter
from gyrolab.report import figures as F
from gyrolab.report.build import build_report
from gyrolab.report.document import Document, FigureBlock, Section, TableBlock, TextBlock
from gyrolab.report.html import render
from gyrolab.report.pdf import write_pdf
from gyrolab.report.text import fmt, hms


@pytest.fixture(scope="module")
def short_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A simulated run of the short profile (48 min) at 10 Hz: a few seconds to make."""
    out = tmp_path_factory.mktemp("run") / "short.mcap"
    assert (
        main(["simulate", "--out", str(out), "--profile", "short", "--rate", "10", "--seed", "3"])
        == 0
    )
    return out


def _synthetic(path: Path, with_rate: bool = True) -> Path:
    """A hand-made recording with a fault, a recovery and an unlogged gap in /gyro/rate."""
    rng = np.random.default_rng(0)
    with RecordingWriter(
        path,
        start_time_ns=0,
        run={"operator": "test", "unit_serial": "G-42"},
        bench={"multimeter": {"idn": "HEWLETT-PACKARD,34401A,0,11-5-2", "serial": "MY123"}},
    ) as w:
        if with_rate:
            # two blocks of 600 s at 10 Hz with 50 samples missing between them
            w.write_rate_block(0.0, 0.1, 0, rng.normal(0.01, 1e-3, 6000))
            w.write_rate_block(605.0, 0.1, 6050, rng.normal(0.01, 1e-3, 6000))
        for t in range(0, 1206, 2):
            w.write_pt100(float(t), 109.7, 25.0 + t / 100)
            w.write_oven(float(t), 30.0, 25.0 + t / 90, "run")
        w.write_event(0.0, "run_started")
        w.write_log(300.0, "fault", "oven", "Modbus timeout", kind="fault")
        w.write_log(302.0, "info", "oven", "reconnected after 2 s", kind="recovery")
        w.write_log(400.0, "info", "runner", "routine message")
    return path


def _external_refs(html: str) -> list[str]:
    refs = re.findall(r"""(?:src|href)\s*=\s*["']([^"']*)["']""", html)
    refs += re.findall(r"url\(([^)]*)\)", html)
    return [r for r in refs if not r.startswith(("data:", "#"))]


def test_formatting_helpers() -> None:
    assert fmt(float("nan")) == "—" and fmt(None) == "—"
    assert fmt(0.052345678) == "0.05235" and fmt(7) == "7"
    assert hms(3725.4) == "1:02:05"


def test_html_is_self_contained_and_pdf_has_every_page(tmp_path: Path) -> None:
    fig = F.compensated(np.arange(10.0), np.ones(10), np.zeros(10))
    doc = Document(
        "T <&> report",
        "sub",
        [("unit", "G-1")],
        [
            Section(
                "a",
                "Alpha",
                [FigureBlock("c", "Comp", fig, "a caption"), TextBlock("note text", "note")],
            ),
            Section(
                "b",
                "Beta",
                [TableBlock("t", "Tab", ["k", "v"], [[str(i), f"{i * 0.5}"] for i in range(90)])],
            ),
        ],
    )
    html = render(doc)
    assert "<script" not in html and _external_refs(html) == []
    assert "T &lt;&amp;&gt; report" in html  # escaped
    assert html.count('src="data:image/png;base64,') == 1
    assert 'id="fig-c"' in html and 'id="tab-t"' in html and "@media print" in html
    n = write_pdf(doc, tmp_path / "r.pdf")
    # everything flows on A4 pages: the title, section A's figure and note, then section
    # B's 90-row table continued over two more pages (layout: tests/test_report_pdf.py)
    assert n == 3
    data = (tmp_path / "r.pdf").read_bytes()
    assert data.startswith(b"%PDF")
    assert len(re.findall(rb"/Type\s*/Page(?!s)", data)) == n


def test_raw_report(short_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "rep"
    assert main(["report", str(short_run), "--out", str(out)]) == 0
    html = (out / "index.html").read_text(encoding="utf-8")
    for key in ("temperature", "raw-output", "allan"):
        assert f'id="fig-{key}"' in html
    for key in ("metrics", "runlog", "events", "bench", "run-meta", "software"):
        assert f'id="tab-{key}"' in html
    # without a model there is no model figure
    assert 'id="fig-vmd-modes"' not in html and 'id="fig-compensated"' not in html
    assert _external_refs(html) == []
    m = json.loads((out / "metrics.json").read_text())
    assert set(m["raw"]) == METRIC_KEYS
    # simulator defaults: ARW about the paper's 0.0523 deg/rt(h)
    assert 0.03 < m["raw"]["arw_deg_per_sqrt_h"] < 0.08
    assert m["raw"]["drift_pp_deg_per_s"] > 0
    assert (out / "report.pdf").read_bytes().startswith(b"%PDF")
    # never overwritten without --force
    assert main(["report", str(short_run), "--out", str(out)]) == 2


def test_run_log_lists_faults_recoveries_and_gaps(tmp_path: Path) -> None:
    rec = _synthetic(tmp_path / "syn.mcap")
    doc, metrics = build_report(rec)
    log = next(t for t in doc.tables() if t.key == "runlog")
    kinds = [r[3] for r in log.rows]
    assert kinds == ["fault", "recovery", "gap"]
    assert "50 samples missing" in log.rows[2][4] and log.rows[2][0] == "0:10:00"
    assert all("routine" not in r[4] for r in log.rows)  # info chatter is not a log entry
    everything = next(t for t in doc.tables() if t.key == "alllog")
    assert [r[4] for r in everything.rows][-1] == "routine message" and len(everything.rows) == 3
    bench = next(t for t in doc.tables() if t.key == "bench")
    assert ["multimeter.serial", "MY123"] in bench.rows
    assert dict(doc.summary)["unit under test"] == "G-42"
    assert set(metrics["raw"]) == METRIC_KEYS


def test_no_gyro_topic_exits_2_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rec = _synthetic(tmp_path / "nogyro.mcap", with_rate=False)
    out = tmp_path / "rep"
    assert main(["report", str(rec), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "/gyro/rate" in err[0] and "nogyro.mcap" in err[0]
    assert not out.exists()


def test_not_an_mcap_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "x.mcap"
    bad.write_text("hello")
    assert main(["report", str(bad), "--out", str(tmp_path / "r")]) == 2
    assert "not an MCAP" in capsys.readouterr().err


def test_model_of_another_version_exits_2(
    short_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from gyrolab.compensation.model_dir import MODEL_FORMAT, ModelDir

    model = tmp_path / "model"
    model.mkdir()
    (model / ModelDir.MODEL_JSON).write_text(
        json.dumps({"format": MODEL_FORMAT, "format_version": 99, "software_version": "9.9.9"})
    )
    out = tmp_path / "rep"
    assert main(["report", str(short_run), "--model", str(model), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "format version 99" in err[0] and str(model) in err[0]
    assert not out.exists()
    # a directory that is no model at all (the output beside it: never inside an input)
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["report", str(short_run), "--model", str(empty), "--out", str(out)]) == 2
    assert "model.json" in capsys.readouterr().err


def test_gpso_optimum_on_the_box_edge_is_flagged() -> None:
    from types import SimpleNamespace

    from gyrolab.report.model_section import gpso_edge_note

    cfg = SimpleNamespace(k_range=(3, 11), alpha_range=(50.0, 5000.0))
    note = gpso_edge_note(SimpleNamespace(config=cfg, K=11, alpha=5000.0))
    assert "K = 11 is the upper bound and α = 5000 is the upper bound" in note
    assert "K = 3 is the lower bound" in gpso_edge_note(SimpleNamespace(config=cfg, K=3, alpha=900))
    assert gpso_edge_note(SimpleNamespace(config=cfg, K=7, alpha=1200.0)) == ""


def test_mpe_figure_marks_the_drift_fallback_and_draws_the_thresholds() -> None:
    fig = F.mpe_classes([0.569, 0.8, 0.95], ["drift", "mixed", "noise"], 0.5, 0.9)
    ax = fig.axes[0]
    hatched = [p.get_hatch() for p in ax.patches if p.get_height() > 0]
    assert hatched[0] == "//" and not any(hatched[1:])
    texts = [t.get_text() for t in ax.texts]
    assert "fallback" in texts and "drift ≤ 0.5" in texts and "noise ≥ 0.9" in texts
    plain = F.mpe_classes([0.3, 0.95], ["drift", "noise"], 0.5, 0.9)
    assert "fallback" not in [t.get_text() for t in plain.axes[0].texts]


def test_temperature_figure_draws_the_safe_state_apart() -> None:
    t = np.arange(0.0, 100.0, 10.0)
    sp = np.r_[np.full(9, 60.0), 25.0]
    safe = np.r_[np.zeros(9, bool), True]
    fig = F.temperature_profile(t, sp, sp - 1, t, sp - 2, safe=safe, profile_c=(25.0, 60.0))
    ax = fig.axes[0]
    labels = [line.get_label() for line in ax.lines]
    assert "safe state (end of run)" in labels
    setpoint = ax.lines[labels.index("oven setpoint")]
    assert np.all(setpoint.get_ydata() == 60.0)  # the profile's line never jumps to 25 °C
    assert any(t.get_text() == "safe state 25 °C" for t in ax.texts)
