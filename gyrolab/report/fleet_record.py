"""The fleet record written (``gyrolab fleet``, docs/fleet.md): the units read and
analysed by :mod:`gyrolab.report.fleet` laid out as a
:class:`~gyrolab.report.document.Document` (no computation here), rendered to
``index.html``, and the tables written as CSV (and Parquet) beside ``fleet.json``.

Every unit is named by its serial; its status says whether it is validated (held-out
metrics, a calibrated range wide enough) and whether the yield counts it. The metric tables
show the raw and the causal output (the compensated output the gyro delivers); the offline
reconstruction is in ``units.csv`` under its own name. Each table has few enough columns to
fit a page, and a cell left empty says why.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from gyrolab.outputs import atomic_dir, check_output, json_safe
from gyrolab.report.document import Document, FigureBlock, Section, TableBlock, TextBlock
from gyrolab.report.fleet import (
    COEFFICIENTS,
    METRICS,
    MIN_UNITS_FOR_OUTLIERS,
    OUTPUTS,
    REF_TEMP_C,
    Z_LIMIT,
    UnitRow,
    analyse,
    find_model_dirs,
    read_unit,
    unit_table,
)
from gyrolab.report.text import fmt

#: metric column -> (short label, unit)
METRIC_LABELS: dict[str, tuple[str, str]] = {
    "drift_pp_deg_per_s": ("drift p-p", "°/s"),
    "bias_stability_deg_per_h": ("bias stability", "°/h"),
    "bias_instability_deg_per_h": ("bias instability", "°/h"),
    "arw_deg_per_sqrt_h": ("ARW", "°/√h"),
    "rms_deg_per_s": ("RMS", "°/s"),
}
DRIFT_COLUMNS = (
    "bias_at_25c_dps",
    "tempco_at_25c_dps_per_c",
    "drift_span_dps",
    "temp_min_c",
    "temp_max_c",
)
DECOMPOSITION_COLUMNS = (
    "vmd_K",
    "vmd_alpha",
    "n_drift_modes",
    "n_mixed_modes",
    "n_noise_modes",
    "flp_mixed_order",
)


def _header(column: str) -> str:
    """A column's header with its unit."""
    if "." in column:
        out, metric = column.split(".", 1)
        label, unit = METRIC_LABELS[metric]
        return f"{OUTPUTS[out]} {label} ({unit})"
    label, unit = COEFFICIENTS.get(column, (column, ""))
    return f"{label} ({unit})" if unit else label


def _coefficient_cell(r: UnitRow, column: str) -> str:
    """A coefficient, or why it is missing (25 °C outside the unit's calibrated range)."""
    x = r.values.get(column, math.nan)
    if not math.isfinite(x) and column in ("bias_at_25c_dps", "tempco_at_25c_dps_per_c"):
        lo, hi = r.values.get("temp_min_c", math.nan), r.values.get("temp_max_c", math.nan)
        return f"{REF_TEMP_C:g} °C outside {fmt(lo)} … {fmt(hi)} °C"
    return fmt(x)


def strip_figure(rows: list[UnitRow], cols: list[str], outliers: list[dict[str, Any]]) -> Figure:
    """One strip per quantity: a point per unit (red: outlier), the median and the
    ±3.5 robust-z band (``median ± 3.5·MAD/0.6745``)."""
    n = len(cols)
    ncol = 3
    nrow = math.ceil(n / ncol)
    fig = Figure(figsize=(9.0, 1.6 * nrow + 0.4), layout="constrained")
    bad = {(o["unit"], o["quantity"]) for o in outliers}
    rng = np.random.default_rng(0)  # jitter only
    for i, c in enumerate(cols):
        ax = fig.add_subplot(nrow, ncol, i + 1)
        x = np.array([r.values.get(c, math.nan) for r in rows], dtype=float)
        jit = rng.uniform(-0.3, 0.3, x.size)
        red = np.array([(r.unit, c) in bad for r in rows])
        ax.scatter(x[~red], jit[~red], s=14, color="#1f77b4")
        ax.scatter(x[red], jit[red], s=22, color="#d62728", marker="D")
        fin = x[np.isfinite(x)]
        if fin.size:
            med = float(np.median(fin))
            mad = float(np.median(np.abs(fin - med)))
            ax.axvline(med, color="k", lw=0.8)
            if mad > 0:
                ax.axvspan(
                    med - Z_LIMIT * mad / 0.6745,
                    med + Z_LIMIT * mad / 0.6745,
                    color="0.9",
                    zorder=0,
                )
        ax.set_title(_header(c), fontsize=8)
        ax.set_yticks([])
        ax.set_ylim(-0.6, 0.6)
        ax.tick_params(labelsize=7)
        ax.locator_params(axis="x", nbins=4)  # readable labels on a narrow spread
        ax.ticklabel_format(axis="x", style="sci", scilimits=(-3, 4), useOffset=False)
    return fig


def _summary(rows: list[UnitRow], res: dict[str, Any]) -> list[tuple[str, str]]:
    counted = sum(r.counted for r in rows)
    out = [
        ("units", str(len(rows))),
        (
            "validated",
            f"{counted} of {len(rows)} (held-out metrics and a calibrated range of at least "
            f"{res['counting']['min_calibrated_span_c']:g} °C)",
        ),
        ("outliers flagged", str(len(res["outliers"]))),
    ]
    y = res.get("yield")
    if y:
        share = (
            f" = {100 * y['yield']:.1f} % (Wilson 95 %: {100 * y['wilson95'][0]:.1f}–"
            f"{100 * y['wilson95'][1]:.1f} %)"
            if y["total"]
            else " (no validated unit to count)"
        )
        out.append(
            (
                "yield",
                f"{y['passed']}/{y['total']}{share} against {y['spec']} on the "
                f"{y['series']} output, counting the validated units only "
                f"({len(y['excluded'])} not counted)",
            )
        )
    return out


def _units_section(rows: list[UnitRow], res: dict[str, Any]) -> Section:
    y = res.get("yield")
    sec = Section("units", "Units")
    head = ["unit (serial)", "status", "counted in the yield"] + (["verdict"] if y else [])
    urows = []
    for r in rows:
        cells = [r.unit + ("" if r.serial else " (no serial in the model: its folder)")]
        cells += [r.status, "yes" if r.counted else "no"]
        if y:
            cells.append(r.verdict + (f" (failed: {', '.join(r.failed)})" if r.failed else ""))
        urows.append(cells)
    sec.blocks.append(
        TableBlock(
            "units",
            "Units and their status",
            head,
            urows,
            note="validated: held-out metrics (compensate --validate) on a model calibrated "
            f"over at least {res['counting']['min_calibrated_span_c']:g} °C; the others are "
            "shown but not counted in the yield"
            + (" (the spec allows in-sample metrics)" if res["counting"]["allow_in_sample"] else "")
            + ".",
            align_numbers=False,
        )
    )
    for out in ("raw", "causal"):
        cols = [f"{out}.{k}" for k in METRICS]
        sec.blocks.append(
            TableBlock(
                f"metrics-{out}",
                f"Metrics per unit: {OUTPUTS[out]}",
                ["unit"] + [_header(c).removeprefix(OUTPUTS[out] + " ") for c in cols],
                [[r.unit] + [fmt(r.values[c]) for c in cols] for r in rows],
                note=(
                    "The causal output is the compensated output the gyro delivers (raw − "
                    "drift from past temperature readings, full bandwidth); the paper's "
                    "offline reconstruction is in units.csv as offline.*."
                    if out == "causal"
                    else ""
                ),
            )
        )
    sec.blocks.append(
        TableBlock(
            "drift-model",
            "Drift model per unit",
            ["unit"] + [_header(c) for c in DRIFT_COLUMNS],
            [[r.unit] + [_coefficient_cell(r, c) for c in DRIFT_COLUMNS] for r in rows],
            note="f(T): the unit's GA-BP drift model, static (dT/dt = 0), never extrapolated: "
            f"at {REF_TEMP_C:g} °C only where that lies in the unit's calibrated range (slope "
            "over ±1 °C, one-sided at the range's edge).",
        )
    )
    sec.blocks.append(
        TableBlock(
            "decomposition",
            "Decomposition per unit (GPSO-VMD, MPE, FLP)",
            ["unit"] + [_header(c) for c in DECOMPOSITION_COLUMNS],
            [[r.unit] + [fmt(r.values[c]) for c in DECOMPOSITION_COLUMNS] for r in rows],
        )
    )
    return sec


def _write_tables(tmp: Path, tables: dict[str, list[dict[str, Any]]]) -> list[str]:
    written = []
    for name, rows in tables.items():
        keys: list[str] = []
        for r in rows:
            keys.extend(k for k in r if k not in keys)
        with open(tmp / f"{name}.csv", "w", newline="", encoding="utf-8") as fh:
            w = csv.DictWriter(fh, fieldnames=keys or ["empty"])
            w.writeheader()
            w.writerows(rows)
        written.append(f"{name}.csv")
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:  # optional: CSV is always there
        return written
    for name, rows in tables.items():
        if rows:
            pq.write_table(pa.Table.from_pylist(rows), tmp / f"{name}.parquet")
            written.append(f"{name}.parquet")
    return written


def write_fleet(
    paths: list[str], out: str | Path, spec: str | None = None, force: bool = False
) -> dict[str, Any]:
    """Read the units, analyse them and write the fleet record (module docstring)."""
    from gyrolab.report.html import render
    from gyrolab.report.pdf import write_pdf

    dirs = find_model_dirs(paths)
    inputs = [*paths, spec]
    check_output(out, force, inputs=inputs, kind="dir")
    rows = [read_unit(d) for d in dirs]
    seen: dict[str, int] = {}
    for r in rows:  # one name per row: the same serial fitted twice keeps both
        seen[r.unit] = seen.get(r.unit, 0) + 1
        if seen[r.unit] > 1:
            r.unit = f"{r.unit}#{seen[r.unit]}"
    res = analyse(rows, spec)
    units = unit_table(rows, res["outliers"])
    with atomic_dir(out, force, command="fleet", inputs=inputs) as tmp:
        files = _write_tables(
            tmp, {"units": units, "summary": res["summary"], "outliers": res["outliers"]}
        )
        page = build(rows, res)
        (tmp / "index.html").write_text(render(page), encoding="utf-8")
        write_pdf(page, tmp / "report.pdf")  # the same page on A4, to sign
        doc = {**res, "units": units, "files": ["index.html", "report.pdf", "fleet.json", *files]}
        (tmp / "fleet.json").write_text(json.dumps(json_safe(doc), indent=1) + "\n")
    return doc


def build(rows: list[UnitRow], res: dict[str, Any]) -> Document:
    """The fleet record as a :class:`~gyrolab.report.document.Document`."""
    doc = Document(
        title=f"Fleet record — {len(rows)} units",
        subtitle="per-unit compensation models and metrics",
        summary=_summary(rows, res),
    )
    doc.sections.append(_units_section(rows, res))
    dist = Section("distributions", "Distributions across the fleet")
    dist.blocks.append(
        FigureBlock(
            "coef",
            "Model coefficients",
            strip_figure(rows, list(COEFFICIENTS), res["outliers"]),
            caption="one point per unit (red diamonds: outliers); line: "
            "median; grey: ±3.5 robust z",
        )
    )
    mcols = [f"{s}.{k}" for s in ("raw", "causal") for k in METRICS]
    dist.blocks.append(
        FigureBlock(
            "metrics",
            "Metrics: raw, then the causal output",
            strip_figure(rows, mcols, res["outliers"]),
        )
    )
    srows = [
        [
            _header(s["quantity"]),
            str(s["n"]),
            *(fmt(s[k]) for k in ("median", "mad", "mean", "sd", "min", "max")),
        ]
        for s in res["summary"]
    ]
    dist.blocks.append(
        TableBlock(
            "summary",
            "Summary per quantity (every unit)",
            ["quantity", "n", "median", "MAD", "mean", "sd", "min", "max"],
            srows,
            note="n: the units that have the quantity ('—' in a unit's row: it has none).",
        )
    )
    doc.sections.append(dist)
    out = Section("outliers", "Outliers")
    out.blocks.append(TextBlock(f"Rule: {res['outlier_rule']}.", "note"))
    if len(rows) < MIN_UNITS_FOR_OUTLIERS:
        out.blocks.append(TextBlock(f"Fewer than {MIN_UNITS_FOR_OUTLIERS} units: not screened."))
    orows = [
        [
            o["unit"],
            _header(o["quantity"]),
            fmt(o["value"]),
            fmt(o["median"]),
            f"{o['robust_z']:+.1f}",
        ]
        for o in res["outliers"]
    ]
    out.blocks.append(
        TableBlock(
            "outliers",
            "Flagged units",
            ["unit", "quantity", "value", "fleet median", "robust z"],
            orows,
        )
    )
    doc.sections.append(out)
    y = res.get("yield")
    if y:
        ys = Section("yield", "Yield against the spec")
        lim = ", ".join(f"{k} = {v:g}" for k, v in y["limits"].items()) or "none"
        ys.blocks.append(
            TextBlock(
                f"Spec {y['spec']}, {y['series']} output; limits: {lim}. Counted: "
                f"{y['total']} validated unit(s); passed {y['passed']}."
            )
        )
        if y["excluded"]:
            ys.blocks.append(
                TextBlock(
                    "Not counted: "
                    + "; ".join(f"{e['unit']}: {e['status']}" for e in y["excluded"])
                    + " (the spec may allow them: allow_in_sample = true, "
                    "min_calibrated_span_c = …).",
                    "note",
                )
            )
        if y["not_checked"]:
            ys.blocks.append(
                TextBlock(
                    "Not checked here (they need the recording; `gyrolab report --spec` checks "
                    f"them per run): {', '.join(y['not_checked'])}.",
                    "note",
                )
            )
        doc.sections.append(ys)
    return doc
