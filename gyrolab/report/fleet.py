"""``gyrolab fleet MODEL_DIR... --out REPORT [--spec SPEC.toml]``: the fleet record.

Reads the model directories that ``gyrolab compensate`` wrote (one per unit; a directory
holding several — a multi-unit ``compensate`` output or a ``batch`` output — stands for all
of them) and writes, atomically, ``REPORT/``:

* ``index.html`` — per-unit table, the distribution of every model coefficient and metric
  (strip plots: one point per unit, median and ±3.5 robust-z band), the outliers, the yield;
* ``units.csv`` — one row per unit: every number of the tables, its outlier flags and, with
  a spec, its verdict; ``summary.csv`` — per quantity: n, median, MAD, mean, sd, min, max;
  ``outliers.csv`` — one row per flagged (unit, quantity);
* ``units.parquet``, ``summary.parquet``, ``outliers.parquet`` where pyarrow is installed
  (the same tables);
* ``fleet.json`` — all of it, machine-readable.

Outliers (Iglewicz & Hoaglin 1993, "How to detect and handle outliers"): per quantity, the
modified z-score ``z = 0.6745·(x − median)/MAD`` (MAD: median absolute deviation), a unit
flagged when ``|z| > 3.5``. Where MAD = 0 (half the units identical) the mean absolute
deviation stands in: ``z = (x − median)/(1.253314·MeanAD)``; where that is 0 too, nothing is
flagged. A quantity is screened only when at least :data:`MIN_UNITS_FOR_OUTLIERS` units
have it.

Yield against ``--spec`` (:mod:`gyrolab.report.spec`): each unit's ``metrics.json`` is
checked against the spec's metric limits (by default on the compensated output); the yield
is passed/total with a Wilson 95 % interval. Run limits (temperature coverage, gaps, run
complete, safe state) need the recording and are checked per run by ``gyrolab report
--spec``; the fleet record lists them as not checked.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gyrolab.outputs import atomic_dir, check_output, json_safe

MIN_UNITS_FOR_OUTLIERS = 5
Z_LIMIT = 3.5
REF_TEMP_C = 25.0
METRICS = (
    "drift_pp_deg_per_s",
    "bias_stability_deg_per_h",
    "bias_instability_deg_per_h",
    "arw_deg_per_sqrt_h",
    "rms_deg_per_s",
)
# model coefficients: column -> (label, unit)
COEFFICIENTS: dict[str, tuple[str, str]] = {
    "bias_at_25c_dps": ("drift model f(T) at 25 °C", "°/s"),
    "tempco_at_25c_dps_per_c": ("df/dT at 25 °C", "°/s/°C"),
    "drift_span_dps": ("f(T) span over the calibrated range", "°/s"),
    "vmd_K": ("VMD modes K", ""),
    "vmd_alpha": ("VMD penalty α", ""),
    "n_drift_modes": ("drift modes", ""),
    "n_mixed_modes": ("mixed modes", ""),
    "n_noise_modes": ("noise modes", ""),
    "flp_mixed_order": ("FLP order (mixed modes)", ""),
    "temp_min_c": ("calibrated from", "°C"),
    "temp_max_c": ("calibrated to", "°C"),
}


@dataclass
class UnitRow:
    """One unit of the fleet: where it came from and its numbers."""

    unit: str
    model_dir: str
    run: str
    held_out: bool
    values: dict[str, float] = field(default_factory=dict)
    verdict: str = ""  # PASS / FAIL with a spec
    failed: list[str] = field(default_factory=list)


def find_model_dirs(paths: list[str]) -> list[Path]:
    """Each path: a model directory, or a directory holding model directories (searched
    three levels deep, hidden and temporary directories skipped). Sorted, unique."""
    from gyrolab.compensation.model_dir import ModelDir

    return [m.path for m in ModelDir.find(paths, depth=3)]


def _coefficients(model: Any) -> dict[str, float]:
    """The unit's model in numbers comparable across units (module docstring)."""
    cal = model.calibration
    lo, hi = float(cal.get("temp_min_c", math.nan)), float(cal.get("temp_max_c", math.nan))

    def f(temps: np.ndarray) -> np.ndarray:
        X = temps[:, None]
        if model.config.use_dtdt:  # static: no temperature change
            X = np.column_stack([temps, np.zeros_like(temps)])
        return np.asarray(model.drift.predict(X), dtype=float).ravel()

    v: dict[str, float] = {}
    if lo <= REF_TEMP_C - 1 and REF_TEMP_C + 1 <= hi:
        b = f(np.array([REF_TEMP_C - 1, REF_TEMP_C, REF_TEMP_C + 1]))
        v["bias_at_25c_dps"] = float(b[1])
        v["tempco_at_25c_dps_per_c"] = float((b[2] - b[0]) / 2.0)
    else:  # outside the calibrated range: flagged as missing, never extrapolated
        v["bias_at_25c_dps"] = v["tempco_at_25c_dps_per_c"] = math.nan
    grid = f(np.linspace(lo, hi, 201)) if math.isfinite(lo) and hi > lo else np.array([np.nan])
    v["drift_span_dps"] = float(np.ptp(grid))
    classes = model.decomposition_info.get("classes", {})
    v["vmd_K"] = float(model.K)
    v["vmd_alpha"] = float(model.alpha)
    for c in ("drift", "mixed", "noise"):
        v[f"n_{c}_modes"] = float(len(classes.get(c, [])))
    v["flp_mixed_order"] = 0.0 if model.flp_mixed is None else float(model.flp_mixed.order)
    v["temp_min_c"], v["temp_max_c"] = lo, hi
    return v


def read_unit(model_dir: Path) -> UnitRow:
    """One unit's row from its model directory (the model and its metrics)."""
    from gyrolab.compensation.model_dir import ModelDir

    md = ModelDir(model_dir)
    model = md.load()
    metrics = md.require_metrics()
    unit = str(model.calibration.get("unit") or metrics.get("unit") or model_dir.name)
    row = UnitRow(unit, str(model_dir), str(metrics.get("run", "")), bool(metrics.get("held_out")))
    row.values.update(_coefficients(model))
    for series in ("raw", "compensated"):
        block = metrics.get(series) or {}
        for k in METRICS:
            x = block.get(k)
            row.values[f"{series}.{k}"] = float(x) if isinstance(x, (int, float)) else math.nan
    row.values["_metrics"] = metrics  # type: ignore[assignment]  # for the spec, not a column
    return row


def robust_z(x: np.ndarray) -> np.ndarray:
    """Modified z-scores (Iglewicz & Hoaglin): ``0.6745 (x − median)/MAD``, or with the
    mean absolute deviation ``(x − median)/(1.253314·MeanAD)`` where MAD = 0; NaN for
    non-finite values, 0 where both deviations are 0."""
    z = np.full(x.shape, np.nan)
    ok = np.isfinite(x)
    if not ok.any():
        return z
    med = np.median(x[ok])
    dev = np.abs(x[ok] - med)
    mad = np.median(dev)
    if mad > 0:
        z[ok] = 0.6745 * (x[ok] - med) / mad
    elif dev.mean() > 0:
        z[ok] = (x[ok] - med) / (1.253314 * dev.mean())
    else:
        z[ok] = 0.0
    return z


def wilson(k: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score interval of a proportion k/n (95 % by default)."""
    if n == 0:
        return (math.nan, math.nan)
    p = k / n
    den = 1 + z * z / n
    mid = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (max(0.0, mid - half), min(1.0, mid + half))


def columns() -> list[str]:
    return [*COEFFICIENTS, *(f"{s}.{k}" for s in ("raw", "compensated") for k in METRICS)]


def analyse(rows: list[UnitRow], spec_path: str | None = None) -> dict[str, Any]:
    """Summary per quantity, outliers and (with a spec) verdicts and yield."""
    cols = columns()
    summary, outliers = [], []
    for c in cols:
        x = np.array([r.values.get(c, math.nan) for r in rows], dtype=float)
        fin = x[np.isfinite(x)]
        s: dict[str, Any] = {"quantity": c, "n": int(fin.size)}
        for name, fn in (
            ("median", np.median),
            ("mean", np.mean),
            ("min", np.min),
            ("max", np.max),
        ):
            s[name] = float(fn(fin)) if fin.size else math.nan
        s["mad"] = float(np.median(np.abs(fin - np.median(fin)))) if fin.size else math.nan
        s["sd"] = float(np.std(fin, ddof=1)) if fin.size > 1 else math.nan
        summary.append(s)
        if fin.size >= MIN_UNITS_FOR_OUTLIERS:
            z = robust_z(x)
            for r, zi, xi in zip(rows, z, x, strict=True):
                if np.isfinite(zi) and abs(zi) > Z_LIMIT:
                    outliers.append(
                        {
                            "unit": r.unit,
                            "quantity": c,
                            "value": float(xi),
                            "median": s["median"],
                            "robust_z": float(zi),
                        }
                    )
    result: dict[str, Any] = {
        "n_units": len(rows),
        "summary": summary,
        "outliers": outliers,
        "outlier_rule": f"|0.6745 (x - median) / MAD| > {Z_LIMIT} (Iglewicz & Hoaglin 1993; "
        f"MeanAD where MAD = 0), quantities held by >= {MIN_UNITS_FOR_OUTLIERS} units",
    }
    if spec_path is not None:
        from gyrolab.report.spec import FLAGS, METRIC_LIMITS, RUN_LIMITS, Spec, evaluate, load_spec

        spec = load_spec(spec_path)
        metric_only = Spec(
            path=spec.path,
            name=spec.name,
            description=spec.description,
            series=spec.series,
            limits={k: v for k, v in spec.limits.items() if k in METRIC_LIMITS},
        )
        unchecked = [k for k in spec.limits if k in RUN_LIMITS]
        unchecked += [k for k, on in spec.flags.items() if on and k in FLAGS]
        for r in rows:
            v = evaluate(metric_only, r.values["_metrics"], has_model=True)  # type: ignore[arg-type]
            r.verdict = v.word
            r.failed = [ln.quantity for ln in v.lines if not ln.passed]
        k = sum(r.verdict == "PASS" for r in rows)
        lo, hi = wilson(k, len(rows))
        result["yield"] = {
            "spec": spec.name or Path(spec_path).name,
            "series": spec.series or "compensated",
            "limits": metric_only.limits,
            "passed": k,
            "total": len(rows),
            "yield": k / len(rows) if rows else math.nan,
            "wilson95": [lo, hi],
            "not_checked": unchecked,
        }
    return result


def _fmt(x: float) -> str:
    return f"{x:.4g}" if isinstance(x, (int, float)) and math.isfinite(x) else "—"


def unit_table(rows: list[UnitRow], outliers: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """``units.csv``: one flat dict per unit."""
    flagged: dict[str, list[str]] = {}
    for o in outliers:
        flagged.setdefault(o["unit"], []).append(o["quantity"])
    out = []
    for r in rows:
        d: dict[str, Any] = {
            "unit": r.unit,
            "model_dir": r.model_dir,
            "run": r.run,
            "held_out": r.held_out,
        }
        d.update({c: r.values.get(c, math.nan) for c in columns()})
        d["outlier_in"] = ";".join(flagged.get(r.unit, []))
        if r.verdict:
            d["verdict"] = r.verdict
            d["failed_limits"] = ";".join(r.failed)
        out.append(d)
    return out


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


def _strip_figure(rows: list[UnitRow], cols: list[str], outliers: list[dict[str, Any]]):  # type: ignore[no-untyped-def]
    """One strip per quantity: a point per unit (red: outlier), the median and the
    ±3.5 robust-z band (``median ± 3.5·MAD/0.6745``)."""
    from matplotlib.figure import Figure

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
        label, unit = COEFFICIENTS.get(c, (c, ""))
        ax.set_title(f"{label}" + (f" [{unit}]" if unit else ""), fontsize=8)
        ax.set_yticks([])
        ax.set_ylim(-0.6, 0.6)
        ax.tick_params(labelsize=7)
        ax.locator_params(axis="x", nbins=4)  # readable labels on a narrow spread
        ax.ticklabel_format(axis="x", style="sci", scilimits=(-3, 4), useOffset=False)
    return fig


def build(rows: list[UnitRow], res: dict[str, Any]):  # type: ignore[no-untyped-def]
    """The fleet record as a :class:`~gyrolab.report.document.Document`."""
    from gyrolab.report.document import Document, FigureBlock, Section, TableBlock, TextBlock

    summary = [("units", str(len(rows))), ("outliers flagged", str(len(res["outliers"])))]
    y = res.get("yield")
    if y:
        summary.append(
            (
                "yield",
                f"{y['passed']}/{y['total']} = {100 * y['yield']:.1f} % "
                f"(Wilson 95 %: {100 * y['wilson95'][0]:.1f}–{100 * y['wilson95'][1]:.1f} %) "
                f"against {y['spec']} on the {y['series']} output",
            )
        )
    doc = Document(
        title=f"Fleet record — {len(rows)} units",
        subtitle="per-unit compensation models and metrics",
        summary=summary,
    )
    header = [
        "unit",
        *[
            f"{s} {k}"
            for s in ("raw", "comp.")
            for k in ("drift p-p °/s", "bias stab. °/h", "BI °/h", "ARW °/√h", "RMS °/s")
        ],
    ]
    if y:
        header.append("verdict")
    mrows = []
    for r in rows:
        cells = [r.unit] + [
            _fmt(r.values[f"{s}.{k}"]) for s in ("raw", "compensated") for k in METRICS
        ]
        if y:
            cells.append(r.verdict + (f" ({', '.join(r.failed)})" if r.failed else ""))
        mrows.append(cells)
    held = sum(r.held_out for r in rows)
    sec = Section("units", "Per-unit metrics")
    sec.blocks.append(
        TableBlock(
            "metrics",
            "Metrics per unit",
            header,
            mrows,
            note=f"{held} of {len(rows)} units' metrics are held out "
            "(another run); the others are in-sample (calibration run).",
        )
    )
    crow = [[r.unit] + [_fmt(r.values[c]) for c in COEFFICIENTS] for r in rows]
    sec.blocks.append(
        TableBlock(
            "coefficients",
            "Model coefficients per unit",
            ["unit", *COEFFICIENTS],
            crow,
            note="f(T): the unit's GA-BP drift model, static (dT/dt = 0); "
            "'—' where 25 °C lies outside the unit's calibrated range "
            "(never extrapolated).",
        )
    )
    doc.sections.append(sec)
    dist = Section("distributions", "Distributions across the fleet")
    dist.blocks.append(
        FigureBlock(
            "coef",
            "Model coefficients",
            _strip_figure(rows, list(COEFFICIENTS), res["outliers"]),
            caption="one point per unit (red diamonds: outliers); line: "
            "median; grey: ±3.5 robust z",
        )
    )
    mcols = [f"{s}.{k}" for s in ("raw", "compensated") for k in METRICS]
    dist.blocks.append(
        FigureBlock(
            "metrics",
            "Metrics (raw, then compensated)",
            _strip_figure(rows, mcols, res["outliers"]),
        )
    )
    srows = [
        [
            s["quantity"],
            str(s["n"]),
            *(_fmt(s[k]) for k in ("median", "mad", "mean", "sd", "min", "max")),
        ]
        for s in res["summary"]
    ]
    dist.blocks.append(
        TableBlock(
            "summary",
            "Summary per quantity",
            ["quantity", "n", "median", "MAD", "mean", "sd", "min", "max"],
            srows,
        )
    )
    doc.sections.append(dist)
    out = Section("outliers", "Outliers")
    out.blocks.append(TextBlock(f"Rule: {res['outlier_rule']}.", "note"))
    if len(rows) < MIN_UNITS_FOR_OUTLIERS:
        out.blocks.append(TextBlock(f"Fewer than {MIN_UNITS_FOR_OUTLIERS} units: not screened."))
    orows = [
        [o["unit"], o["quantity"], _fmt(o["value"]), _fmt(o["median"]), f"{o['robust_z']:+.1f}"]
        for o in res["outliers"]
    ]
    out.blocks.append(
        TableBlock(
            "outliers",
            "Flagged units",
            ["unit", "quantity", "value", "fleet median", "robust z"],
            orows or [["none", "", "", "", ""]],
        )
    )
    doc.sections.append(out)
    if y:
        ys = Section("yield", "Yield against the spec")
        lim = ", ".join(f"{k} = {v:g}" for k, v in y["limits"].items()) or "none"
        ys.blocks.append(TextBlock(f"Spec {y['spec']}, {y['series']} output; limits: {lim}."))
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


def write_fleet(
    paths: list[str], out: str | Path, spec: str | None = None, force: bool = False
) -> dict[str, Any]:
    """Read the units, analyse them and write the fleet record (module docstring)."""
    from gyrolab.report.html import render

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
        (tmp / "index.html").write_text(render(build(rows, res)), encoding="utf-8")
        doc = {**res, "units": units, "files": ["index.html", "fleet.json", *files]}
        (tmp / "fleet.json").write_text(json.dumps(json_safe(doc), indent=1) + "\n")
    return doc


__all__ = ["analyse", "find_model_dirs", "robust_z", "wilson", "write_fleet"]
