"""The report as typed data: everything it shows, computed (or read) once.

:func:`assemble` turns a recording, an optional model directory and an optional spec into
one :class:`ReportData`; :mod:`gyrolab.report.layout` lays it out as a
:class:`~gyrolab.report.document.Document` (no computation there), which the HTML and PDF
writers render. Numbers come from :mod:`gyrolab.report.analysis` (model results read from
the model directory where ``gyrolab compensate`` kept them).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gyrolab.errors import InputError
from gyrolab.record.format import ALL_TOPICS, TOPIC_ADC, TOPIC_RATE
from gyrolab.record.reader import Recording, read_recording
from gyrolab.report import analysis
from gyrolab.report.analysis import ModelRun
from gyrolab.report.outcome import Coverage, Outcome, run_coverage, run_outcome

METRIC_ROWS: list[tuple[str, str]] = [
    ("arw_deg_per_sqrt_h", "angle random walk (°/√h)"),
    ("bias_instability_deg_per_h", "bias instability, Allan floor/0.664 (°/h)"),
    ("bias_stability_deg_per_h", "bias stability, std of 3.6 s averages (°/h)"),
    ("drift_pp_deg_per_s", "drift peak-to-peak (°/s)"),
    ("rms_deg_per_s", "RMS (°/s)"),
]


def _noop(_: str) -> None:
    return None


@dataclass
class AllanData:
    """One labelled Allan curve with its noise terms
    (:class:`~gyrolab.compensation.results.AllanSummary`); ``key``: its series
    (``raw``, ``causal``, ``compensated`` — the offline reconstruction)."""

    label: str
    curve: Any  # AllanSummary
    key: str = "raw"


def offline_label(metrics: dict[str, Any]) -> str:
    """How every table and figure names the paper's offline reconstruction (metrics key
    ``compensated``): by what it is, with its −3 dB bandwidth where known."""
    f3 = metrics.get("denoising", {}).get("bandwidth", {}).get("f3db_hz")
    bw = f", f3dB {1e3 * f3:.2g} mHz" if isinstance(f3, (int, float)) else ""
    return f"offline reconstruction (low-passed{bw})"


#: The causal output's name in every table, figure and verdict of the report.
CAUSAL_LABEL = "causal output"


@dataclass
class ReportData:
    """Everything the report shows of one run (one axis of it).

    ``tb``/``xb``: the raw rate averaged over ``block_s`` (s, °/s); ``metrics``: the
    ``metrics.json`` content; ``model``: the model on this run (``None``: raw record);
    ``allan``: the raw (and compensated) Allan curves; ``plateaus``: the noise per soaked
    step; ``verdict``: against the spec (``None`` without one)."""

    rec: Recording
    block_s: float
    tb: np.ndarray
    xb: np.ndarray
    outcome: Outcome
    coverage: Coverage
    serial: str
    operator: str | None
    metrics: dict[str, Any]
    allan: list[AllanData] = field(default_factory=list)
    plateaus: list[Any] = field(default_factory=list)
    model: ModelRun | None = None
    verdict: Any = None
    range_note: str = ""
    firmware_note: str = ""

    @property
    def held_out(self) -> bool | None:
        return None if self.model is None else self.model.held_out


def read_run(
    path: str | Path, log_options: dict | None = None, unit: str | None = None
) -> Recording:
    """Read every topic but the raw ADC counts (the report uses the rate); check the gyro.

    A recording without ``/gyro/rate`` samples is refused with an :class:`InputError` that
    names the missing topic and lists the topics the file does have.
    """
    from gyrolab.logs import detect_format, read_log

    if detect_format(path) == "gyrolab":
        topics = [t for t in ALL_TOPICS if t != TOPIC_ADC]
        rec = read_recording(path, topics=topics, unit=unit)
    else:  # ROS 2 / ULog / DataFlash: the same in-memory recording (gyrolab.logs)
        rec = read_log(path, **(log_options or {}))
    if rec.rate is None or rec.rate.t.size == 0:
        present = sorted(rec.topic_counts) or ["none"]
        raise InputError(
            path,
            f"no gyro output: topic {TOPIC_RATE} is missing or empty "
            f"(topics present: {', '.join(present)})",
        )
    if rec.rate.t.size < 16:
        raise InputError(path, f"{TOPIC_RATE} has only {rec.rate.t.size} samples")
    return rec


def unit_serial(rec: Recording) -> str:
    """The unit under test's serial number as the recording gives it ('—' if none)."""
    return str(rec.run.get("unit_serial") or "—")


def assemble(
    rec: Recording,
    model_dir: str | Path | None = None,
    model: Any = None,
    step: Any = _noop,
    spec: Any = None,
    operator: str | None = None,
    serial: str | None = None,
    unit: str | None = None,
    label: str | None = None,
) -> ReportData:
    """:class:`ReportData` of ``rec`` (one axis), with ``model`` (loaded from
    ``model_dir``) applied or its results read, and ``spec`` (a loaded
    :class:`~gyrolab.report.spec_limits.Spec`) judged. ``step(name)`` marks each stage.
    ``label``: how metrics.json names the run (default: its path as given)."""
    mr: ModelRun | None = None
    if model is not None and model_dir is not None:
        step("apply model")
        mr = analysis.model_run(model_dir, model, rec, label)
    block_s = float(model.config.block_s) if model is not None else analysis.paper_block_s()
    tb, xb = analysis.block_averages(rec, block_s)
    step("metrics")
    if mr is not None:
        metrics = mr.metrics
        hyst = analysis.hysteresis(mr.model)
        if hyst is not None:
            metrics["causal_hysteresis_width"] = hyst
    else:
        metrics = {
            "run": label or str(rec.path),
            "raw": analysis.raw_metrics(xb, block_s, [k for k, _ in METRIC_ROWS]),
            "held_out": False,
            "sample_period_s": block_s,
            "n_points": int(tb.size),
        }
    if unit is not None:
        metrics["unit"] = unit
    outcome, coverage = run_outcome(rec), run_coverage(rec)
    data = ReportData(
        rec=rec,
        block_s=block_s,
        tb=tb,
        xb=xb,
        outcome=outcome,
        coverage=coverage,
        serial=serial or unit_serial(rec),
        operator=operator,
        metrics=metrics,
        model=mr,
    )
    if spec is not None:
        from gyrolab.report.spec_limits import evaluate

        data.verdict = evaluate(
            spec,
            metrics,
            has_model=mr is not None,
            coverage_fraction=coverage.fraction("case"),
            gap_s=coverage.gap_s,
            complete=outcome.status == "complete",
            safe_state_ok=outcome.safe_state == "verified",
        )
    metrics["outcome"] = {
        "status": outcome.status,
        "line": outcome.line,
        "safe_state": outcome.safe_state,
        "end_t": outcome.end_t,
    }
    metrics["coverage"] = {
        "profile_c": coverage.profile_c,
        "chamber_c": coverage.chamber_c,
        "case_c": coverage.case_c,
        "case_fraction": coverage.fraction("case"),
        "samples": coverage.samples,
        "gaps": coverage.gaps,
        "samples_missing": coverage.samples_missing,
        "gap_s": coverage.gap_s,
    }
    if data.verdict is not None:
        metrics["verdict"] = data.verdict.to_dict()
    step("allan")
    data.allan = _allan_curves(data)
    data.range_note = analysis.range_note(metrics) if mr is not None else ""
    if mr is not None:
        analysis.warn_source(metrics)
    data.firmware_note = analysis.firmware_note(metrics)
    step("plateau noise")
    data.plateaus = analysis.plateau_rows(rec)
    return data


def _allan_curves(data: ReportData) -> list[AllanData]:
    """The raw curve, the causal output's and the offline reconstruction's (under its own
    label): read from the model's results (the causal one computed from its series for a
    model directory written before it was kept), else the raw curve computed."""
    if data.model is None:
        a = analysis.allan_summary(data.xb, 1.0 / data.block_s)
        return [] if a is None else [AllanData("raw", a)]
    res = data.model.results
    stored = dict(res.allan)
    if "causal" not in stored and "causal" in res.series:
        a = analysis.allan_summary(res.series["causal"], 1.0 / res.block_s)
        if a is not None:
            stored["causal"] = a
    labels = {"raw": "raw", "causal": CAUSAL_LABEL, "compensated": offline_label(data.metrics)}
    return [AllanData(labels[k], stored[k], k) for k in labels if k in stored]
