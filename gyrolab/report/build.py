"""Assemble the report of one run: read the recording (and the model), compute, lay out.

:func:`build_report` returns the :class:`~gyrolab.report.document.Document` and the
``metrics.json`` content; :mod:`gyrolab.report.commands` writes them. Everything numeric
comes from the layers below (``gyrolab.compensation``): the report never re-implements a
metric, so its numbers are the ones ``gyrolab compensate`` prints.

Without a model the report is the raw record of the run (temperature profile, raw output,
raw Allan deviation and metrics, run log, bench identity); with ``--model`` the model is
applied to the run and its figures (GPSO, VMD/MPE, drift fit, compensated output,
compensated Allan deviation, baseline comparison) are added.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gyrolab import __version__
from gyrolab.errors import InputError
from gyrolab.record.recording import (
    ALL_TOPICS,
    TOPIC_ADC,
    TOPIC_PT100,
    TOPIC_RATE,
    Recording,
    read_recording,
)
from gyrolab.report import figures as F
from gyrolab.report.document import Document, FigureBlock, Section, TableBlock, TextBlock
from gyrolab.report.outcome import Coverage, Outcome, run_coverage, run_outcome

METRIC_ROWS: list[tuple[str, str]] = [
    ("arw_deg_per_sqrt_h", "angle random walk (°/√h)"),
    ("bias_instability_deg_per_h", "bias instability, Allan floor/0.664 (°/h)"),
    ("bias_stability_deg_per_h", "bias stability, std of 3.6 s averages (°/h)"),
    ("drift_pp_deg_per_s", "drift peak-to-peak (°/s)"),
    ("rms_deg_per_s", "RMS (°/s)"),
]
#: Notable log entries for the run log (everything at warning level or above is kept too).
LOG_KINDS = {"fault", "recovery", "gap", "retry", "timeout", "abort", "safe_state"}
MAX_LOG_ROWS = 400

Step = Callable[[str], None]


def _noop(_: str) -> None:
    return None


# ------------------------------------------------------------------------- formatting


def fmt(x: Any, digits: int = 4) -> str:
    """A number for a table: ``digits`` significant digits, '—' for missing/NaN."""
    if x is None:
        return "—"
    if isinstance(x, (int, np.integer)) and not isinstance(x, bool):
        return str(int(x))
    try:
        v = float(x)
    except (TypeError, ValueError):
        return str(x)
    if not math.isfinite(v):
        return "—"
    return f"{v:.{digits}g}"


def hms(t: float) -> str:
    """Seconds since run start as ``h:mm:ss``."""
    t = max(0.0, float(t))
    h, rem = divmod(int(round(t)), 3600)
    m, s = divmod(rem, 60)
    return f"{h}:{m:02d}:{s:02d}"


def _flatten(d: Any, prefix: str = "") -> list[tuple[str, str]]:
    """Nested metadata as ``(dotted.key, value)`` rows (lists of scalars joined)."""
    rows: list[tuple[str, str]] = []
    if isinstance(d, dict):
        for k, v in d.items():
            rows.extend(_flatten(v, f"{prefix}.{k}" if prefix else str(k)))
    elif isinstance(d, list) and d and all(isinstance(v, dict) for v in d):
        for i, v in enumerate(d):
            rows.extend(_flatten(v, f"{prefix}[{i}]"))
    elif isinstance(d, list):
        rows.append((prefix, ", ".join(str(v) for v in d)))
    else:
        rows.append((prefix, "" if d is None else str(d)))
    return rows


def _clean(x: Any) -> Any:
    """JSON-safe copy: numpy → Python, NaN/inf → None (JSON has neither)."""
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, np.ndarray):
        return _clean(x.tolist())
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        v = float(x)
        return v if math.isfinite(v) else None
    if isinstance(x, np.bool_):
        return bool(x)
    return x


# --------------------------------------------------------------------------- reading


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


@dataclass
class AllanData:
    """One Allan curve plus its noise terms, in °/h for plotting.

    ``arw``/``bi`` are ``None`` when the curve does not identify them
    (:func:`gyrolab.numerics.noise_terms.noise_terms`); ``terms`` keeps the full result
    (τ ranges, reasons, the upper bound on B when there is no floor)."""

    label: str
    tau: np.ndarray
    adev_dph: np.ndarray
    lo_dph: np.ndarray
    hi_dph: np.ndarray
    arw: float | None
    bi: float | None
    terms: Any = None

    def figure_curve(self, color: str) -> F.AllanCurve:
        t = self.terms
        ub = None if t is None else t.upper_bounds.get("B")
        return F.AllanCurve(
            self.label,
            self.tau,
            self.adev_dph,
            self.lo_dph,
            self.hi_dph,
            self.arw,
            self.bi,
            color=color,
            arw_tau=None if t is None else t.tau_ranges.get("N"),
            bi_tau=None if t is None else t.tau_ranges.get("B"),
            tau_b=None if t is None or self.bi is None else t.tau_b,
            bi_upper_bound=None if ub is None else 3600.0 * ub,
        )

    def caption(self) -> str:
        """What the curve identifies and on which τ, for the figure caption."""
        t = self.terms
        if t is None:
            return ""

        def rng(name: str) -> str:
            lo, hi = t.tau_ranges[name]
            return f"τ = {lo:.3g}–{hi:.3g} s"

        parts = []
        if self.arw is not None:
            parts.append(f"ARW {self.arw:.3g} °/√h from the −½ slope over {rng('N')} (read at 1 s)")
        else:
            parts.append("ARW not identifiable (no −½ slope at τ ≤ T/10)")
        if self.bi is not None:
            parts.append(
                f"bias instability {self.bi:.3g} °/h at the floor, minimum at τ = "
                f"{t.tau_b:.3g} s (flat over {rng('B')})"
            )
        else:
            ub = 3600.0 * t.upper_bounds.get("B", float("nan"))
            parts.append(
                f"no floor within the record (the minimum, at τ = {t.tau_b:.3g} s, is not on a "
                f"flat stretch; σ_min/0.664 = {ub:.3g} °/h is an upper bound on B)"
            )
        return f"{self.label}: " + "; ".join(parts)


def allan_curve(x: np.ndarray, rate_hz: float, label: str) -> AllanData | None:
    """Allan deviation (octave taus, 1σ Greenhall bounds) and the IEEE 952 ARW/B of ``x``
    (°/s) that the curve identifies (T/10 rule, slopes supported by the confidence
    intervals, B only at a true floor).

    ``None`` when the series is too short or constant (the figure then omits the curve).
    """
    from gyrolab.numerics.allan import allan_deviation
    from gyrolab.numerics.noise_terms import noise_terms

    try:
        res = allan_deviation(np.asarray(x, dtype=float), rate_hz, taus="octave")
        nt = noise_terms(res, terms=("N", "B"))
    except InputError:
        return None
    terms = nt.deg_h()
    return AllanData(
        label=label,
        tau=res.taus,
        adev_dph=res.adev * 3600.0,
        lo_dph=res.adev_lo * 3600.0,
        hi_dph=res.adev_hi * 3600.0,
        arw=terms["arw_deg_per_sqrt_h"],
        bi=terms["bias_instability_deg_per_h"],
        terms=nt,
    )


def raw_metrics(tb: np.ndarray, xb: np.ndarray, block_s: float) -> dict[str, Any]:
    """The five metrics (docs/cli.md) of the averaged raw output (NaN when too short)."""
    from gyrolab.compensation.evaluate import series_metrics

    try:
        return series_metrics(xb, block_s)
    except InputError:
        return {k: float("nan") for k, _ in METRIC_ROWS}


# ------------------------------------------------------------------------- sections


def unit_serial(rec: Recording) -> str:
    """The unit under test's serial number as the recording gives it ('—' if none)."""
    return str(rec.run.get("unit_serial") or rec.bench.get("unit_serial") or "—")


def run_id(rec: Recording) -> str:
    """The run's identity for headers: the recording's name and its start time."""
    start = rec.run.get("start_time")
    return Path(rec.path).name + (f" · {start}" if start else "")


def _summary(
    rec: Recording,
    model: Any,
    held_out: bool | None,
    outcome: Outcome | None = None,
    coverage: Coverage | None = None,
) -> list[tuple[str, str]]:
    run = rec.run
    rate = rec.rate
    assert rate is not None
    prof = run.get("profile")
    prof_name = prof.get("name", "?") if isinstance(prof, dict) else str(prof or "?")
    dur = float(rate.t[-1] - rate.t[0] + rate.period)
    outcome = outcome or run_outcome(rec)
    coverage = coverage or run_coverage(rec)
    rows = [
        ("run outcome", outcome.line),
        ("recording", Path(rec.path).name),
        ("unit under test", unit_serial(rec)),
        ("operator", str(run.get("operator", "—"))),
        ("start time", str(run.get("start_time", "—"))),
        ("source", str(run.get("source", "—"))),
        ("profile", prof_name),
        ("duration", f"{dur / 3600:.2f} h ({hms(dur)})"),
        ("temperatures reached", coverage.temperature_line()),
        ("gyro samples", coverage.samples_line()),
        ("recorded by", f"gyrolab {run.get('software_version', '?')}"),
        ("report by", f"gyrolab {__version__}"),
    ]
    if model is not None:
        cal = Path(str(model.calibration.get("path", "?"))).name
        rows.append(("compensation model", f"fitted on {cal}"))
        rows.append(
            (
                "metrics are",
                "held out (run not used for fitting)"
                if held_out
                else "in sample (this run is the calibration run)",
            )
        )
    else:
        rows.append(("compensation model", "none (raw record)"))
    return rows


def _log_row(m: dict[str, Any]) -> list[str]:
    """One /log message as a table row: time, level, source, kind, message."""
    return [
        hms(float(m.get("t", 0.0))),
        str(m.get("level", "")),
        str(m.get("source", "")),
        str(m.get("kind", "")),
        str(m.get("message", "")),
    ]


def _capped_table(
    key: str, title: str, header: list[str], rows: list[list[str]], what: str, more: str = ""
) -> TableBlock:
    """A table of at most ``MAX_LOG_ROWS`` rows; the note says how many were left out."""
    note = ""
    if len(rows) > MAX_LOG_ROWS:
        note = f"First {MAX_LOG_ROWS} of {len(rows)} {what} shown.{more}"
        rows = rows[:MAX_LOG_ROWS]
    return TableBlock(key, title, header, rows, note)


def run_log_rows(rec: Recording) -> tuple[list[list[str]], dict[str, int]]:
    """Faults, recoveries, warnings and gaps, in time order; plus counts per kind."""
    rows: list[tuple[float, list[str]]] = []
    counts: dict[str, int] = {}
    for m in rec.logs:
        level = str(m.get("level", ""))
        kind = str(m.get("kind", ""))
        if level in ("warning", "error", "fault") or kind in LOG_KINDS:
            rows.append((float(m.get("t", 0.0)), _log_row(m)))
            if kind != "safe_state":  # the normal end of a run: shown, not counted
                counts[kind or level] = counts.get(kind or level, 0) + 1
    logged_gaps = sum(1 for m in rec.logs if m.get("kind") == "gap")
    assert rec.rate is not None
    gaps = rec.rate.gaps()
    counts["gaps in /gyro/rate"] = len(gaps)
    if len(gaps) > logged_gaps:
        # Gaps the acquisition did not log (e.g. a recovered file): the reader still sees them.
        for t, n in gaps:
            rows.append(
                (
                    t,
                    [
                        hms(t),
                        "warning",
                        "reader",
                        "gap",
                        f"{n} samples missing in {TOPIC_RATE} ({n * rec.rate.period:.3g} s)",
                    ],
                )
            )
    logged = {str(m.get("kind", "")) for m in rec.logs}
    for e in rec.events:
        ev = str(e.get("event", ""))
        # The runner logs its end on /log too (kinds abort / safe_state); the events are
        # shown only for a recording without those messages. A verified safe state is the
        # normal end of every run, not a fault.
        if ev == "aborted" and "abort" not in logged:
            t, detail = float(e.get("t", 0.0)), str(e.get("detail", ""))
            level = "warning" if detail.startswith("interrupted") else "fault"
            rows.append((t, [hms(t), level, "profile", "abort", detail]))
            counts["abort"] = counts.get("abort", 0) + 1
        elif ev == "safe_state" and "safe_state" not in logged:
            t, detail = float(e.get("t", 0.0)), str(e.get("detail", ""))
            failed = detail.startswith("FAILED")
            kind = "fault" if failed else "safe_state"
            rows.append((t, [hms(t), "fault" if failed else "info", "profile", kind, detail]))
            counts[kind] = counts.get(kind, 0) + 1
    rows.sort(key=lambda r: r[0])
    return [r for _, r in rows], counts


def event_rows(rec: Recording) -> list[list[str]]:
    out = []
    for e in rec.events:
        sp = e.get("setpoint_c")
        out.append(
            [
                hms(float(e.get("t", 0.0))),
                str(e.get("event", "")),
                str(e.get("step", "")),
                fmt(sp, 4) if sp is not None else "",
                str(e.get("detail", "")),
            ]
        )
    return out


def _metrics_table(metrics: dict[str, Any], columns: list[tuple[str, str]]) -> TableBlock:
    """Rows: the five metrics; columns: ``(label, dotted key into metrics)``."""

    def get(path: str) -> dict[str, Any]:
        d: Any = metrics
        for p in path.split("."):
            d = d.get(p, {}) if isinstance(d, dict) else {}
        return d if isinstance(d, dict) else {}

    rows = []
    for key, label in METRIC_ROWS:
        rows.append([label] + [fmt(get(path).get(key)) for _, path in columns])
    return TableBlock("metrics", "Performance metrics", ["metric"] + [c for c, _ in columns], rows)


# -------------------------------------------------------------------------- building


def build_report(
    run_path: str | Path,
    model_dir: str | Path | None = None,
    step: Step = _noop,
    spec: str | Path | None = None,
    operator: str | None = None,
    serial: str | None = None,
    axis: int | None = None,
    log_options: dict | None = None,
    unit: str | None = None,
) -> tuple[Document, dict[str, Any]]:
    """The report document and ``metrics.json`` content of ``run_path`` (and the model).

    ``step(name)`` is called as each stage starts (progress display). Bad input raises
    :class:`InputError` before anything heavy runs: the spec file and the model are read
    (and the model's format version checked) first, then the recording is checked for a
    gyro topic. ``spec`` (a spec TOML, :mod:`gyrolab.report.spec`) adds the verdict;
    ``operator``/``serial`` override the recording's for the sign-off block.
    """
    from gyrolab.report.spec import load_spec

    t_start = time.perf_counter()
    spec_obj = load_spec(spec) if spec is not None else None
    model = None
    if model_dir is not None:
        from gyrolab.compensation.model_dir import load_model

        step("load model")
        model = load_model(str(model_dir))
    step("read recording")
    rec = read_run(run_path, log_options, unit)  # unit: of a multi-unit recording
    if axis is not None:  # one axis of a multi-axis unit (gyrolab.report.axes)
        rec = rec.axis(axis)
    rate = rec.rate
    assert rate is not None
    from gyrolab.numerics.averaging import PAPER_BLOCK_S, block_average

    block_s = model.config.block_s if model is not None else PAPER_BLOCK_S
    x = np.asarray(rate.values, dtype=float)
    if rate.t.size and (rate.t[-1] - rate.t[0]) >= 2 * block_s:
        tb, xb, _ = block_average(rate.t, x, block_s, rate.period)
    else:
        tb, xb = rate.t, x
    has_temp = rec.pt100_t.size > 0

    metrics: dict[str, Any]
    app = run = None
    held_out: bool | None = None
    if model is not None:
        from gyrolab.compensation.apply import compensate_offline
        from gyrolab.compensation.evaluate import evaluate
        from gyrolab.compensation.prepare import prepare_run

        step("apply model")
        run = prepare_run(rec, model.config)
        held_out = not _is_calibration_run(model, run)
        app = compensate_offline(model, run)
        step("metrics")
        metrics = evaluate(model, app, run, held_out=held_out)
        metrics["calibration_run"] = model.calibration.get("path")
        from gyrolab.compensation.firmware import firmware_metrics_for_dir

        firmware_metrics_for_dir(model_dir, run, metrics)
    else:
        step("metrics")
        metrics = {
            "run": str(run_path),
            "raw": raw_metrics(tb, xb, block_s),
            "held_out": False,
            "sample_period_s": block_s,
            "n_points": int(tb.size),
        }

    if unit is not None:
        metrics["unit"] = unit
    step("figures")
    outcome, coverage = run_outcome(rec), run_coverage(rec)
    serial = serial or unit_serial(rec)
    verdict = None
    if spec_obj is not None:
        from gyrolab.report.spec import evaluate

        verdict = evaluate(
            spec_obj,
            metrics,
            has_model=model is not None,
            coverage_fraction=coverage.fraction("case"),
            gap_s=coverage.gap_s,
            complete=outcome.status == "complete",
            safe_state_ok=outcome.safe_state == "verified",
        )
    summary = _summary(rec, model, held_out, outcome, coverage)
    summary.insert(1, ("verdict", verdict.summary() if verdict else "no spec given (no verdict)"))
    if serial != unit_serial(rec):
        summary = [
            ("unit under test", serial) if k == "unit under test" else (k, v) for k, v in summary
        ]
    doc = Document(
        title=f"Temperature test report — {serial if serial != '—' else Path(rec.path).stem}",
        subtitle="MEMS gyroscope temperature test"
        + (" with drift compensation" if model is not None else " (raw record)"),
        summary=summary,
        status=outcome.status,
        running_header=f"{serial} · {run_id(rec)}",
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
    if verdict is not None:
        metrics["verdict"] = verdict.to_dict()

    # 1. temperature and raw output
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
    if rec.oven_t.size or has_temp:
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
                    safe=np.array([m == "safe" for m in rec.oven_mode], dtype=bool),
                    profile_c=coverage.profile_c,
                ),
                "Oven setpoint (commanded), chamber air (oven process value) and the PT100 on "
                "the gyro case; the shaded band is the profile's setpoint range. "
                + (
                    "The red dashed step at the end is the end-of-run safe state (the oven "
                    "commanded to its safe setpoint and read back), not part of the profile."
                    if any(m == "safe" for m in rec.oven_mode)
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
            F.raw_output(tb, xb, rec.pt100_t, rec.pt100_c),
            f"Gyro output averaged over {block_s:g} s ({3600 / block_s:.0f} points/h, the paper's "
            "rate); right: against the gyro case temperature, coloured by time (paper Fig. 9).",
        )
    )
    doc.sections.append(sec)

    # the causal headline (issue 11): its own self-contained section
    if model is not None and app is not None and run is not None:
        from gyrolab.report.causal_section import causal_headline_section

        headline = causal_headline_section(metrics, model, app, run, rec)
        if headline is not None:
            doc.sections.append(headline)

    # 2. compensation model
    if model is not None and app is not None and run is not None:
        doc.sections.append(_model_section(model, app, run, held_out))

    # 3. performance: Allan + metrics
    step("allan")
    doc.sections.append(_performance_section(metrics, xb, block_s, app, model, rate))
    if "firmware_poly3" in metrics:
        from gyrolab.compensation.firmware import firmware_sentence

        doc.sections[-1].blocks.append(TextBlock(firmware_sentence(metrics), "note"))

    # 3b. noise per temperature plateau (raw rate of each soaked step)
    step("plateau noise")
    doc.sections.append(plateau_noise_section(rec))

    # 4. run log and bench identity
    doc.sections.append(_log_section(rec))
    doc.sections.append(_identity_section(rec, model))
    # 5. verdict against the spec and the sign-off block
    doc.sections.append(_signoff_section(rec, outcome, verdict, operator, serial))

    metrics["timing_s"] = time.perf_counter() - t_start
    if model is not None and "timing_s" not in metrics.get("model", {}):
        metrics["model_timing_s"] = model.timing_s
    return doc, _clean(metrics)


def _signoff_section(
    rec: Recording, outcome: Outcome, verdict: Any, operator: str | None, serial: str
) -> Section:
    """Per-limit pass/fail (with a spec), the overall verdict and the signature block."""
    import datetime as _dt

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
                f"{verdict.series} output; a limit that could not be measured fails.",
            )
        )
    else:
        sec.blocks.append(
            TextBlock("No spec file was given (gyrolab report --spec SPEC.toml): no verdict.")
        )
    op = operator or str(rec.run.get("operator") or "")
    sec.blocks.append(
        TableBlock(
            "signoff",
            "Sign-off",
            ["field", "value"],
            [
                ["unit serial", serial],
                ["run", run_id(rec)],
                ["run outcome", outcome.line],
                ["verdict", verdict.word if verdict is not None else "none (no spec)"],
                ["operator", op or "—"],
                ["report date", _dt.date.today().isoformat()],
                ["signature", "_" * 30],
            ],
            align_numbers=False,
        )
    )
    return sec


def _is_calibration_run(model: Any, run: Any) -> bool:
    """True when ``run`` is the run the model was fitted on: same content hash of the rate
    and temperature data (models that record it), else the same averaged series."""
    digest = model.calibration.get("content_hash")
    if digest and getattr(run, "content_hash", ""):
        return bool(digest == run.content_hash)
    cal = model.diagnostics.get("calib_rate")
    if cal is None:
        return Path(str(model.calibration.get("path", ""))).resolve() == Path(run.path).resolve()
    cal = np.asarray(cal, dtype=float)
    return cal.shape == run.rate.shape and bool(np.allclose(cal, run.rate, rtol=0, atol=1e-12))


def gpso_edge_note(model: Any) -> str:
    """A warning when GPSO's optimum (K, α) lies on the edge of its search box, where a
    wider box might hold a better optimum; '' when it is inside."""
    cfg = model.config
    (k_lo, k_hi), (a_lo, a_hi) = cfg.k_range, cfg.alpha_range
    on: list[str] = []
    if model.K in (k_lo, k_hi):
        on.append(f"K = {model.K} is the {'lower' if model.K == k_lo else 'upper'} bound")
    tol = 1e-3 * (a_hi - a_lo)
    if abs(model.alpha - a_lo) <= tol or abs(model.alpha - a_hi) <= tol:
        which = "lower" if abs(model.alpha - a_lo) <= tol else "upper"
        on.append(f"α = {model.alpha:.0f} is the {which} bound")
    if not on:
        return ""
    return (
        f"GPSO's optimum lies on the edge of the search box (K {k_lo}…{k_hi}, "
        f"α {a_lo:g}…{a_hi:g}): {' and '.join(on)}. The true optimum may lie outside "
        "the box; the model is the best found within it."
    )


def _model_section(model: Any, app: Any, run: Any, held_out: bool | None) -> Section:
    sec = Section("model", "Compensation model (GPSO-VMD, MPE, FLP, GA-BP)")
    d = model.diagnostics
    dec = app.decomposition
    names = {i: c for c, idx in dec.classes.items() for i in idx}
    classes = [names.get(i, "?") for i in range(dec.K)]
    sec.blocks.append(
        TextBlock(
            f"VMD parameters K = {model.K}, α = {model.alpha:.0f}; IMF classes by mean MPE: "
            + "; ".join(
                f"{c}: {', '.join(f'IMF{i + 1}' for i in dec.classes.get(c, [])) or 'none'}"
                for c in ("noise", "mixed", "drift")
            )
            + f". The model was fitted on {Path(str(model.calibration.get('path', '?'))).name}; "
            + ("this run is held out." if held_out else "this run is the calibration run.")
        )
    )
    # only when GPSO ran (K and α may also be fixed in the configuration)
    edge = gpso_edge_note(model) if d.get("gpso_positions") is not None else ""
    if edge:  # said before the figure too, where a reader of the text sees it
        sec.blocks.append(TextBlock(edge, "note"))
    pos = d.get("gpso_positions")
    best_hist = d.get("gpso_best_fitness", d.get("gpso_best_history"))
    if pos is not None and best_hist is not None and np.ndim(pos) == 3:
        fit = d.get("gpso_fitness")
        mean_fit = None
        if fit is not None and np.ndim(fit) == 2:
            f = np.asarray(fit, dtype=float)
            mean_fit = np.nanmean(np.where(np.isfinite(f), f, np.nan), axis=1)
        sec.blocks.append(
            FigureBlock(
                "gpso",
                "GPSO search of the VMD parameters",
                F.gpso(best_hist, pos[:, :, 0], pos[:, :, 1], model.K, model.alpha, mean_fit),
                "Left: best and mean fitness per generation. Right: every evaluated particle in "
                "(K, α), shaded by generation; the star is the optimum (paper Fig. 10)."
                + (f" {edge}" if edge else ""),
            )
        )
    else:
        sec.blocks.append(
            TextBlock(
                "GPSO search: not recorded in this model (K and α were fixed in its configuration, "
                "or the model predates the search history).",
                "note",
            )
        )
    sec.blocks.append(
        FigureBlock(
            "vmd-modes",
            "VMD modes and their classes",
            F.vmd_modes(run.t, dec.modes, classes, list(dec.mpe)),
            "The averaged output of this run decomposed by VMD with the model's (K, α); each "
            "mode is coloured by its MPE class (red noise, orange mixed, blue drift) "
            "(paper Fig. 11).",
        )
    )
    cfg = model.config
    fallback = [i for i in dec.classes.get("drift", []) if dec.mpe[i] > cfg.mpe_drift_max]
    mpe_caption = (
        f"Mean multiscale permutation entropy (scales 1–{cfg.mpe_scale}) of each "
        f"mode; noise ≥ {cfg.mpe_noise_min}, drift ≤ {cfg.mpe_drift_max} "
    )
    if fallback:
        mpe_caption += (
            "— no mode fell under the drift threshold, so the most regular one, "
            + ", ".join(f"IMF{i + 1} (MPE {dec.mpe[i]:.3f})" for i in fallback)
            + ", is taken as the drift (the pipeline's fallback, hatched) "
        )
    sec.blocks.append(
        FigureBlock(
            "mpe",
            "MPE classification",
            F.mpe_classes(list(dec.mpe), classes, cfg.mpe_drift_max, cfg.mpe_noise_min),
            mpe_caption + "(paper Fig. 12).",
        )
    )
    sec.blocks.append(
        FigureBlock(
            "drift-fit",
            "Drift model fit",
            F.drift_fit(run.t, dec.part("drift"), app.series["drift_prediction"], run.temp),
            "Drift modes of this run and the GA-BP model's prediction from the PT100 temperature "
            + ("(held out: the model never saw this run)" if held_out else "(calibration run)")
            + " (paper Fig. 13).",
        )
    )
    sec.blocks.append(
        FigureBlock(
            "compensated",
            "Compensated against raw",
            F.compensated(run.t, app.series["raw"], app.series["compensated"]),
            "Raw output and the reconstructed output (noise modes removed, mixed modes filtered, "
            "temperature drift subtracted) (paper Fig. 14).",
        )
    )
    return sec


def _performance_section(
    metrics: dict[str, Any], xb: np.ndarray, block_s: float, app: Any, model: Any, rate: Any
) -> Section:
    sec = Section("performance", "Performance: Allan deviation and metrics")
    curves: list[F.AllanCurve] = []
    notes: list[str] = []
    series = [("raw", xb, F.RAW_COLOR)]
    if app is not None:
        series.append(("compensated", app.series["compensated"], F.COMP_COLOR))
    for label, x, color in series:
        a = allan_curve(x, 1.0 / block_s, label)
        if a is not None:
            curves.append(a.figure_curve(color))
            notes.append(a.caption())
    if curves:
        sec.blocks.append(
            FigureBlock(
                "allan",
                "Allan deviation",
                F.allan(curves),
                f"Overlapping Allan deviation of the {block_s:g} s averages, with 1σ confidence "
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
    if model is not None:
        cols.append(("compensated", "compensated"))
        if "compensated_drift_only" in metrics:
            cols.append(("drift only (GA-BP)", "compensated_drift_only"))
        if "compensated_streaming" in metrics:
            cols.append(("streaming (causal)", "compensated_streaming"))
    rng = metrics.get("temperature") or {}
    if rng.get("outside_calibration_range"):
        from gyrolab.compensation.guards import range_warning

        line = range_warning(Path(str(metrics.get("run", "this run"))).name, rng) or ""
        sec.blocks.append(
            TextBlock(line.replace("warning: ", "Outside the calibrated range — ", 1), "note")
        )
    tab = _metrics_table(metrics, cols)
    tab.note = f"All metrics on {block_s:g} s averages of the output" + (
        "; held out: the model was not fitted on this run." if metrics.get("held_out") else "."
    )
    sec.blocks.append(tab)
    if model is not None and metrics.get("baselines"):
        bcols = [
            ("GPSO-VMD + GA-BP", "compensated"),
            ("GA-BP drift only", "compensated_drift_only"),
        ]
        bcols += [(f"baseline: {n}", f"baselines.{n}") for n in metrics["baselines"]]
        bt = _metrics_table(metrics, [("raw", "raw")] + bcols)
        bt.key, bt.title = "baselines", "Baseline comparison"
        bt.note = (
            "poly: polynomial in temperature (order by blocked cross-validation); bp: plain BP "
            "network with random initial weights; both fitted on the calibration run's raw "
            "averages and applied causally. 'GA-BP drift only' is the paper's drift model "
            "applied the same way (no noise removal): the like-for-like comparison."
        )
        sec.blocks.append(bt)
    return sec


def plateau_noise_section(rec: Recording) -> Section:
    """ARW and bias instability at each soaked step, a table and a figure vs temperature."""
    from matplotlib.figure import Figure

    from gyrolab.compensation.plateau_noise import plateau_noise

    sec = Section("plateau-noise", "Noise per temperature plateau")
    rows = plateau_noise(rec)
    if not rows:
        sec.blocks.append(TextBlock("No soaked step with PT100 data in this recording.", "note"))
        return sec
    sec.blocks.append(
        TextBlock(
            "For each profile step (step_started … step_ended on /profile/event), the soaked "
            "segment is the tail in which the PT100 stays within ±0.5 °C of its final value. "
            "On its raw rate samples (gaps left out, never interpolated): overlapping Allan "
            "deviation, ARW = 60 N read at τ = 1 s on the −½ slope, bias instability "
            "B = σ_min/0.664 (IEEE 952), B's interval from the curve's one-sigma bounds at τ_B "
            "(Greenhall–Riley EDF). B is read at τ ≤ a tenth of the segment: on a short "
            "plateau the curve may still fall there (white noise), and B is then an upper "
            "bound — compare τ_B with the segment. docs/allan.md has the definitions."
        )
    )
    sec.blocks.append(
        TableBlock(
            "plateau-noise",
            "Noise terms per soaked step",
            [
                "step",
                "setpoint (°C)",
                "PT100 mean (°C)",
                "PT100 span (°C)",
                "segment",
                "samples",
                "missing",
                "ARW (°/√h)",
                "bias instability (°/h)",
                "B 68 % interval",
                "τ_B (s)",
            ],
            [
                [
                    str(p.step + 1),
                    fmt(p.setpoint_c),
                    fmt(p.temperature_c),
                    fmt(p.temperature_span_c, 2),
                    f"{hms(p.t_start)}–{hms(p.t_end)}",
                    str(p.n_samples),
                    str(p.missing),
                    fmt(p.arw_deg_per_sqrt_h),
                    fmt(p.bias_instability_deg_per_h),
                    f"{fmt(p.bi_lo_deg_per_h, 3)}–{fmt(p.bi_hi_deg_per_h, 3)}",
                    fmt(p.tau_b_s),
                ]
                for p in rows
            ],
        )
    )
    fig = Figure(figsize=(8.0, 3.2), layout="constrained")
    ax1, ax2 = fig.subplots(1, 2)
    tc = np.array([p.temperature_c for p in rows])
    ax1.plot(tc, [p.arw_deg_per_sqrt_h for p in rows], "o", color="#1f77b4")
    ax1.set_xlabel("PT100 (°C)")
    ax1.set_ylabel("ARW (°/√h)")
    ax1.set_ylim(bottom=0.0)  # the spread read against the level, not magnified
    b = np.array([p.bias_instability_deg_per_h for p in rows])
    err = np.array([b - [p.bi_lo_deg_per_h for p in rows], [p.bi_hi_deg_per_h for p in rows] - b])
    ax2.errorbar(tc, b, yerr=np.where(np.isfinite(err), err, 0.0), fmt="o", color="#d62728")
    ax2.set_xlabel("PT100 (°C)")
    ax2.set_ylabel("bias instability (°/h)")
    for ax in (ax1, ax2):
        ax.grid(True, alpha=0.3)
    sec.blocks.append(
        FigureBlock(
            "plateau-noise",
            "Noise against temperature",
            fig,
            "One point per soaked step, at the step's mean PT100 temperature; bars: B's 68 % "
            "interval.",
        )
    )
    return sec


def _log_section(rec: Recording) -> Section:
    sec = Section("log", "Run log: faults, recoveries, gaps")
    rows, counts = run_log_rows(rec)
    sec.blocks.append(
        TextBlock(
            "Counts: "
            + ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
            + f"; log messages in all: {len(rec.logs)}; profile events: {len(rec.events)}."
        )
    )
    log_header = ["time", "level", "source", "kind", "message"]
    sec.blocks.append(
        _capped_table(
            "runlog",
            "Faults, recoveries, warnings and gaps",
            log_header,
            rows,
            "entries",
            " All are in the recording.",
        )
    )
    # Every message, info included: the full story of the run (commands, transitions).
    all_rows = [_log_row(m) for m in sorted(rec.logs, key=lambda m: float(m.get("t", 0.0)))]
    sec.blocks.append(_capped_table("alllog", "All log messages", log_header, all_rows, "messages"))
    sec.blocks.append(
        _capped_table(
            "events",
            "Profile events",
            ["time", "event", "step", "setpoint (°C)", "detail"],
            event_rows(rec),
            "events",
        )
    )
    return sec


def _identity_section(rec: Recording, model: Any) -> Section:
    sec = Section("identity", "Bench identity and software")
    run: dict[str, Any] = {}
    steps: list[dict[str, Any]] = []
    for k, v in rec.run.items():
        key = next((s for s in ("steps", "step") if isinstance(v, dict) and s in v), None)
        if key and isinstance(v[key], list):
            # a profile table: its steps get a table of their own below
            steps = [s for s in v[key] if isinstance(s, dict)]
            v = {kk: vv for kk, vv in v.items() if kk != key}
            v["steps"] = f"{len(steps)} (table below)"
        run[k] = v
    sec.blocks.append(
        TableBlock(
            "run-meta",
            "Run",
            ["field", "value"],
            [list(r) for r in _flatten(run)],
            align_numbers=False,
        )
    )
    if steps:
        cols = ["label", "setpoint_c", "duration_s"]
        cols += sorted({c for s in steps for c in s} - set(cols))
        sec.blocks.append(
            TableBlock(
                "profile-steps",
                "Profile steps (as commanded)",
                ["#"] + cols,
                [[str(i)] + [fmt(s.get(c, "")) for c in cols] for i, s in enumerate(steps)],
            )
        )
    sec.blocks.append(
        TableBlock(
            "bench",
            "Instruments, serial numbers, calibration",
            ["field", "value"],
            [list(r) for r in _flatten(rec.bench)],
            align_numbers=False,
        )
    )
    sw = [
        ["gyrolab (this report)", __version__],
        ["gyrolab (recording)", str(rec.run.get("software_version", "—"))],
        ["recording format", str(rec.run.get("format_version", "—"))],
    ]
    if model is not None:
        sw.append(["compensation model calibration run", str(model.calibration.get("path"))])
    sec.blocks.append(TableBlock("software", "Software", ["component", "version"], sw))
    return sec


__all__ = ["build_report", "read_run", "run_log_rows", "fmt", "hms", "TOPIC_PT100"]
