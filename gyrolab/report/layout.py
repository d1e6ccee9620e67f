"""The report's layout: a :class:`~gyrolab.report.data.ReportData` becomes a
:class:`~gyrolab.report.document.Document` of sections (figures, tables, text).

Nothing is computed here: every number and series is in the data. The order is the
record's: header summary, the run (temperature, raw output), the causal headline and the
model (with a model), performance (Allan deviation, metrics, baselines), noise per
plateau, run log, bench identity, verdict and sign-off.
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path
from typing import Any

import numpy as np

from gyrolab import __version__
from gyrolab.record.reader import Recording
from gyrolab.report import figures as F
from gyrolab.report.causal_section import causal_headline_section
from gyrolab.report.data import CAUSAL_LABEL, METRIC_ROWS, AllanData, ReportData, offline_label
from gyrolab.report.document import Document, FigureBlock, Section, TableBlock, TextBlock
from gyrolab.report.model_section import model_section
from gyrolab.report.record_sections import identity_section, log_section, plateau_noise_section
from gyrolab.report.text import dotted, fmt, hms


def run_id(rec: Recording) -> str:
    """The run's identity for headers: the recording's name and its start time."""
    start = rec.run.get("start_time")
    return Path(rec.path).name + (f" · {start}" if start else "")


def document(data: ReportData) -> Document:
    """The whole report of one run (module docstring)."""
    rec, mr = data.rec, data.model
    doc = Document(
        title="Temperature test report — "
        + (data.serial if data.serial != "—" else Path(rec.path).stem),
        subtitle="MEMS gyroscope temperature test"
        + (" with drift compensation" if mr is not None else " (raw record)"),
        summary=summary(data),
        status=data.outcome.status,
        running_header=f"{data.serial} · {run_id(rec)}",
    )
    doc.sections.append(run_section(data))
    if mr is not None:
        headline = causal_headline_section(mr)  # the causal headline (issue 11)
        if headline is not None:
            doc.sections.append(headline)
        doc.sections.append(model_section(mr))
    doc.sections.append(performance_section(data))
    doc.sections.append(plateau_noise_section(data.plateaus))
    doc.sections.append(log_section(rec))
    cal = None if mr is None else str(mr.model.calibration.get("path"))
    also = [] if mr is None else [str(a.get("path")) for a in mr.model.calibration.get("also", [])]
    doc.sections.append(identity_section(rec, cal, also))
    doc.sections.append(signoff_section(data))
    return doc


def summary(data: ReportData) -> list[tuple[str, str]]:
    """The header's (label, value) rows: outcome, verdict, unit, run, coverage, model."""
    rec, mr = data.rec, data.model
    run = rec.run
    rate = rec.require_rate()
    prof = run.get("profile")
    prof_name = str(prof.get("name", "?")) if isinstance(prof, dict) else "?"
    dur = float(rate.t[-1] - rate.t[0] + rate.period)
    v = data.verdict
    rows = [
        ("run outcome", data.outcome.line),
        ("verdict", v.summary() if v is not None else "no spec given (no verdict)"),
        ("recording", Path(rec.path).name),
        ("unit under test", data.serial),
        ("operator", str(run.get("operator", "—"))),
        ("start time", str(run.get("start_time", "—"))),
        ("source", str(run.get("source", "—"))),
        ("profile", prof_name),
        ("duration", f"{dur / 3600:.2f} h ({hms(dur)})"),
        ("temperatures reached", data.coverage.temperature_line()),
        ("gyro samples", data.coverage.samples_line()),
        ("recorded by", f"gyrolab {run.get('software_version', '?')}"),
        ("report by", f"gyrolab {__version__}"),
    ]
    if mr is not None:
        cal = Path(str(mr.model.calibration.get("path", "?"))).name
        rows.append(("compensation model", f"fitted on {cal}"))
        rows.append(
            (
                "metrics are",
                "held out (run not used for fitting)"
                if mr.held_out
                else "in sample (this run is the calibration run)",
            )
        )
        rows.append(
            (
                "model results",
                "computed by this report (see the model section)"
                if mr.computed
                else "read from the model directory (as gyrolab compensate computed them)",
            )
        )
    else:
        rows.append(("compensation model", "none (raw record)"))
    return rows


def run_section(data: ReportData) -> Section:
    """Temperature profile and the raw output (against time and temperature)."""
    rec, block_s = data.rec, data.block_s
    sec = Section("run", "Run: temperature profile and raw output")
    comp_meta = rec.metadata.get("compensation")
    if isinstance(comp_meta, dict):
        # A `gyrolab apply` output: its /gyro/rate is already compensated; say so up front.
        sec.blocks.append(
            TextBlock(
                "This recording was written by gyrolab apply: its /gyro/rate is the compensated "
                f"output of the model in {comp_meta.get('model_dir', '?')} (the input's rate is "
                "kept as /gyro/rate_raw). 'Raw' below means this recording's /gyro/rate.",
                "note",
            )
        )
    if data.model is not None and data.model.computed:
        sec.blocks.append(TextBlock(data.model.computed, "note"))
    internal = rec.temperature_source == "internal"
    if rec.oven_t.size or rec.pt100_t.size:
        safe = np.array([m == "safe" for m in rec.oven_mode], dtype=bool)
        sec.blocks.append(
            FigureBlock(
                "temperature",
                "Temperature profile",
                F.temperature_profile(
                    rec.oven_t,
                    rec.oven_setpoint_c,
                    rec.oven_pv_c,
                    rec.pt100_t,
                    rec.pt100_c,
                    safe=safe,
                    profile_c=data.coverage.profile_c,
                    temperature_label=(
                        "gyro die (internal sensor)" if internal else "gyro case (PT100)"
                    ),
                ),
                "Oven setpoint (commanded), chamber air (oven process value) and "
                + (
                    "the unit's internal (die) temperature sensor, its model input"
                    if internal
                    else "the PT100 on the gyro case"
                )
                + "; the shaded band is the profile's setpoint range. "
                + (
                    "The red dashed step at the end is the end-of-run safe state (the oven "
                    "commanded to its safe setpoint and read back), not part of the profile."
                    if safe.any()
                    else "No safe-state command is recorded."
                ),
            )
        )
    else:
        sec.blocks.append(TextBlock("No oven or PT100 data in this recording.", "note"))
    sec.blocks.append(
        FigureBlock(
            "raw-output",
            "Raw output against time and temperature",
            F.raw_output(data.tb, data.xb, rec.pt100_t, rec.pt100_c),
            f"Gyro output averaged over {block_s:g} s ({3600 / block_s:.0f} points/h, the paper's "
            "rate); right: against the gyro case temperature, coloured by time (paper Fig. 9).",
        )
    )
    return sec


def allan_figure_curve(a: AllanData, color: str) -> F.AllanCurve:
    """The figure's curve in °/h, annotated over the τ ranges its terms were read on."""
    c = a.curve
    return F.AllanCurve(
        a.label,
        c.tau,
        c.adev * 3600.0,
        c.lo * 3600.0,
        c.hi * 3600.0,
        c.arw,
        c.bi,
        color=color,
        arw_tau=c.arw_tau,
        bi_tau=c.bi_tau,
        tau_b=None if c.bi is None else c.tau_b,
        bi_upper_bound=c.bi_upper_bound,
    )


def allan_caption(a: AllanData) -> str:
    """What the curve identifies and on which τ, for the figure caption."""
    c = a.curve

    def rng(r: tuple[float, float] | None) -> str:
        lo, hi = r if r is not None else (float("nan"), float("nan"))
        return f"τ = {lo:.3g}–{hi:.3g} s"

    parts = []
    if c.arw is not None:
        parts.append(f"ARW {c.arw:.3g} °/√h from the −½ slope over {rng(c.arw_tau)} (read at 1 s)")
    else:
        parts.append("ARW not identifiable (no −½ slope at τ ≤ T/10)")
    if c.bi is not None:
        parts.append(
            f"bias instability {c.bi:.3g} °/h at the floor, minimum at τ = "
            f"{c.tau_b:.3g} s (flat over {rng(c.bi_tau)})"
        )
    else:
        ub = float("nan") if c.bi_upper_bound is None else c.bi_upper_bound
        parts.append(
            f"no floor within the record (the minimum, at τ = {c.tau_b:.3g} s, is not on a "
            f"flat stretch; σ_min/0.664 = {ub:.3g} °/h is an upper bound on B)"
        )
    return f"{a.label}: " + "; ".join(parts)


def metrics_table(metrics: dict[str, Any], columns: list[tuple[str, str]]) -> TableBlock:
    """Rows: the five metrics; columns: ``(label, dotted key into metrics)``."""
    rows = []
    for key, label in METRIC_ROWS:
        rows.append([label] + [fmt(dotted(metrics, path).get(key)) for _, path in columns])
    return TableBlock("metrics", "Performance metrics", ["metric"] + [c for c, _ in columns], rows)


def performance_section(data: ReportData) -> Section:
    """Allan deviation of the raw (and compensated) averages, the metrics, the baselines."""
    metrics, block_s, mr = data.metrics, data.block_s, data.model
    sec = Section("performance", "Performance: Allan deviation and metrics")
    colors = {"raw": F.RAW_COLOR, "causal": F.COMP_COLOR, "compensated": F.OFFLINE_COLOR}
    curves = [allan_figure_curve(a, colors.get(a.key, F.RAW_COLOR)) for a in data.allan]
    if curves:
        notes = [allan_caption(a) for a in data.allan]
        sec.blocks.append(
            FigureBlock(
                "allan",
                "Allan deviation: " + ", ".join(a.label for a in data.allan),
                F.allan(curves),
                (
                    f"The compensated output is the {CAUSAL_LABEL} (what the gyro delivers in "
                    "real time); the offline reconstruction is low-passed, so its curve is not "
                    "comparable at short τ. "
                    if mr is not None
                    else ""
                )
                + f"Overlapping Allan deviation of the {block_s:g} s averages, with 1σ confidence "
                "bands (Greenhall EDF); dotted: angle random walk line (−½ slope), drawn over "
                "the τ it was identified on; dashed: bias-instability floor 0.664·B (IEEE 952) "
                "over the flat stretch, ▼ its minimum. Terms are read only at τ ≤ T/10 and where "
                "the confidence intervals support the slope (docs/allan.md) (paper Fig. 15). "
                + ". ".join(notes)
                + ".",
            )
        )
    else:
        sec.blocks.append(TextBlock("Run too short for an Allan deviation.", "note"))
    cols = [("raw", "raw")]
    if mr is not None:
        if "causal" in metrics:
            cols.append((CAUSAL_LABEL, "causal"))
        if "compensated_drift_only" in metrics:
            cols.append(("GA-BP drift only (causal)", "compensated_drift_only"))
        if "compensated_streaming" in metrics:
            cols.append(("GA-BP streaming (causal, full rate)", "compensated_streaming"))
        cols.append((offline_label(metrics), "compensated"))
    if data.range_note:
        sec.blocks.append(TextBlock(data.range_note, "note"))
    tab = metrics_table(metrics, cols)
    tab.note = f"All metrics on {block_s:g} s averages of the output" + (
        "; held out: the model was not fitted on this run." if metrics.get("held_out") else "."
    )
    sec.blocks.append(tab)
    if mr is not None and metrics.get("baselines"):
        bcols = [(CAUSAL_LABEL, "causal")] if "causal" in metrics else []
        bcols += [("GA-BP drift only", "compensated_drift_only")]
        bcols += [(f"baseline: {n}", f"baselines.{n}") for n in metrics["baselines"]]
        bcols += [("GPSO-VMD + GA-BP, " + offline_label(metrics), "compensated")]
        bt = metrics_table(metrics, [("raw", "raw")] + bcols)
        bt.key, bt.title = "baselines", "Baseline comparison"
        bt.note = (
            "poly: polynomial in temperature (order by blocked cross-validation); bp: plain BP "
            "network with random initial weights; both fitted on the calibration run's raw "
            "averages and applied causally. 'GA-BP drift only' is the paper's drift model "
            "applied the same way (no noise removal): the like-for-like comparison."
        )
        sec.blocks.append(bt)
    if data.firmware_note:
        sec.blocks.append(TextBlock(data.firmware_note, "note"))
    return sec


def signoff_section(data: ReportData) -> Section:
    """Per-limit pass/fail (with a spec), the overall verdict and the signature block."""
    verdict, rec = data.verdict, data.rec
    sec = Section("signoff", "Verdict and sign-off")
    if verdict is not None:
        name = verdict.spec.name or Path(verdict.spec.path).name
        sec.blocks.append(
            TableBlock(
                "verdict",
                f"Spec limits: {name}",
                ["quantity", "limit", "measured", "result"],
                [
                    [x.quantity, x.limit, x.measured, "PASS" if x.passed else "FAIL"]
                    for x in verdict.lines
                ],
                note=f"Overall verdict: {verdict.word}. Metric limits apply to the "
                f"{verdict.series} output"
                + (
                    " (raw − drift estimated from past temperature readings: what the gyro "
                    "delivers in real time, full bandwidth)"
                    if verdict.series == "causal"
                    else ""
                )
                + "; a limit that could not be measured fails.",
            )
        )
    else:
        sec.blocks.append(
            TextBlock("No spec file was given (gyrolab report --spec SPEC.toml): no verdict.")
        )
    op = data.operator or str(rec.run.get("operator") or "")
    sec.blocks.append(
        TableBlock(
            "signoff",
            "Sign-off",
            ["field", "value"],
            [
                ["unit serial", data.serial],
                ["run", run_id(rec)],
                ["run outcome", data.outcome.line],
                ["verdict", verdict.word if verdict is not None else "none (no spec)"],
                ["operator", op or "—"],
                ["report date", dt.date.today().isoformat()],
                ["signature", "_" * 30],
            ],
            align_numbers=False,
        )
    )
    return sec


