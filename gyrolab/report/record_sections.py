"""The report's sections about the recording itself: the run log, the bench identity and
the noise per temperature plateau (layout only; the plateau numbers come from
:func:`gyrolab.report.analysis.plateau_rows`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from gyrolab import __version__
from gyrolab.record.format import TOPIC_RATE
from gyrolab.record.reader import Recording
from gyrolab.report import figures as F
from gyrolab.report.document import FigureBlock, Section, TableBlock, TextBlock
from gyrolab.report.text import flatten, fmt, hms

#: Notable log entries for the run log (everything at warning level or above is kept too).
LOG_KINDS = {
    "fault",
    "recovery",
    "gap",
    "retry",
    "timeout",
    "abort",
    "safe_state",
    "suspend_cleared",
}
MAX_LOG_ROWS = 400


def log_row(m: dict[str, Any]) -> list[str]:
    """One /log message as a table row: time, level, source, kind, message."""
    return [
        hms(float(m.get("t", 0.0))),
        str(m.get("level", "")),
        str(m.get("source", "")),
        str(m.get("kind", "")),
        str(m.get("message", "")),
    ]


def capped_table(
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
            rows.append((float(m.get("t", 0.0)), log_row(m)))
            if kind != "safe_state":  # the normal end of a run: shown, not counted
                counts[kind or level] = counts.get(kind or level, 0) + 1
    logged_gaps = sum(1 for m in rec.logs if m.get("kind") == "gap")
    rate = rec.require_rate()
    gaps = rate.gaps()
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
                        f"{n} samples missing in {TOPIC_RATE} ({n * rate.period:.3g} s)",
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


def _step_number(step: Any) -> str:
    """A profile step as people count it, from 1 (the recording counts from 0; −1, an
    event of no step, is left blank)."""
    ok = isinstance(step, int) and not isinstance(step, bool) and step >= 0
    return str(step + 1) if ok else ""


def event_rows(rec: Recording) -> list[list[str]]:
    out = []
    for e in rec.events:
        sp = e.get("setpoint_c")
        out.append(
            [
                hms(float(e.get("t", 0.0))),
                str(e.get("event", "")),
                _step_number(e.get("step")),
                fmt(sp, 4) if sp is not None else "",
                str(e.get("detail", "")),
            ]
        )
    return out


def suspension_rows(rec: Recording) -> list[list[str]]:
    """Each time the run was held (``suspended`` … ``resumed`` on /profile/event,
    gyrolab/acquisition/suspend.py): when, how long, the step, why, and how it went on —
    the step went on, re-soaked, or the run ended held."""
    rows: list[list[str]] = []
    start: dict[str, Any] | None = None
    for e in rec.events:
        ev = e.get("event")
        if ev == "suspended":
            start = e
        elif start is not None and ev in ("resumed", "aborted"):
            t0, t1 = float(start.get("t", 0.0)), float(e.get("t", 0.0))
            how = str(e.get("detail", "")).split("; ")[-1] if ev == "resumed" else "run ended"
            rows.append(
                [hms(t0), fmt(t1 - t0, 4), str(int(start.get("step", -1)) + 1)]
                + [str(start.get("detail", "")), how]
            )
            start = None
    if start is not None:
        rows.append([hms(float(start.get("t", 0.0))), "—", str(int(start.get("step", -1)) + 1)])
        rows[-1] += [str(start.get("detail", "")), "held when the recording ends"]
    return rows


def log_section(rec: Recording) -> Section:
    sec = Section("log", "Run log: faults, recoveries, gaps")
    rows, counts = run_log_rows(rec)
    held = suspension_rows(rec)
    if held:
        sec.blocks.append(
            TableBlock(
                "suspensions",
                "Suspensions: the run held (setpoint kept, profile not advancing)",
                ["from", "held (s)", "step", "conditions", "then"],
                held,
            )
        )
    sec.blocks.append(
        TextBlock(
            "Counts: "
            + ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
            + f"; log messages in all: {len(rec.logs)}; profile events: {len(rec.events)}."
        )
    )
    log_header = ["time", "level", "source", "kind", "message"]
    sec.blocks.append(
        capped_table(
            "runlog",
            "Faults, recoveries, warnings and gaps",
            log_header,
            rows,
            "entries",
            " All are in the recording.",
        )
    )
    # Every message, info included: the full story of the run (commands, transitions).
    all_rows = [log_row(m) for m in sorted(rec.logs, key=lambda m: float(m.get("t", 0.0)))]
    sec.blocks.append(capped_table("alllog", "All log messages", log_header, all_rows, "messages"))
    sec.blocks.append(
        capped_table(
            "events",
            "Profile events",
            ["time", "event", "step", "setpoint (°C)", "detail"],
            event_rows(rec),
            "events",
        )
    )
    return sec


def identity_section(
    rec: Recording, calibration_run: str | None, also: Sequence[str] = ()
) -> Section:
    """Run metadata, the profile's steps, the bench's instruments and the software;
    ``calibration_run``: the model's, when the report has one; ``also``: the runs its
    causal model was also fitted on, each from its own power-on (``compensate --also``)."""
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
            [list(r) for r in flatten(run)],
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
                [[str(i)] + [fmt(s.get(c, "")) for c in cols] for i, s in enumerate(steps, 1)],
            )
        )
    sec.blocks.append(
        TableBlock(
            "bench",
            "Instruments, serial numbers, calibration",
            ["field", "value"],
            [list(r) for r in flatten(rec.bench)],
            align_numbers=False,
        )
    )
    sw = [
        ["gyrolab (this report)", __version__],
        ["gyrolab (recording)", str(rec.run.get("software_version", "—"))],
        ["recording format", str(rec.run.get("format_version", "—"))],
    ]
    if calibration_run is not None:
        sw.append(["compensation model calibration run", calibration_run])
    for a in also:
        sw.append(["causal model also fitted on (own power-on)", a])
    sec.blocks.append(TableBlock("software", "Software", ["component", "version"], sw))
    return sec


def plateau_noise_section(rows: list[Any]) -> Section:
    """ARW and bias instability at each soaked step, a table and a figure vs temperature
    (``rows``: :class:`gyrolab.compensation.plateau_noise.Plateau`)."""
    sec = Section("plateau-noise", "Noise per temperature plateau")
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
    fig = F.plateau_noise(
        np.array([p.temperature_c for p in rows]),
        np.array([p.arw_deg_per_sqrt_h for p in rows]),
        np.array([p.bias_instability_deg_per_h for p in rows]),
        np.array([p.bi_lo_deg_per_h for p in rows]),
        np.array([p.bi_hi_deg_per_h for p in rows]),
    )
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
