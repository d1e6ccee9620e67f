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

Which units count (:func:`mark`): a unit whose metrics are in-sample (its model was fitted
without ``--validate``) is marked "not validated", one whose model covers less than
``min_calibrated_span_c`` of temperature (default
:data:`~gyrolab.report.spec_limits.DEFAULT_MIN_CALIBRATED_SPAN_C`) "narrow range"; neither is
counted in the yield unless the spec says so (``allow_in_sample = true``, a smaller
``min_calibrated_span_c``). Units are named by the serial their model records.

Yield against ``--spec`` (:mod:`gyrolab.report.spec_limits`): each counted unit's ``metrics.json``
is checked against the spec's metric limits (by default on the causal output, the
compensated output the gyro delivers); the yield is passed/counted with a Wilson 95 %
interval. Run limits (temperature coverage, gaps, run complete, safe state) need the
recording and are checked per run by ``gyrolab report --spec``; the fleet record lists them
as not checked. :mod:`gyrolab.report.fleet_record` lays out and writes the record.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gyrolab.report.spec_limits import DEFAULT_MIN_CALIBRATED_SPAN_C, SERIES, load_spec

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


#: The outputs whose metrics the fleet tabulates (column prefix -> label), read from
#: metrics.json as the spec reads them (:data:`gyrolab.report.spec_limits.SERIES`): ``causal`` is
#: the compensated output; ``offline`` the paper's low-passed reconstruction.
OUTPUTS: dict[str, str] = {
    "raw": "raw",
    "causal": "causal output",
    "offline": "offline reconstruction",
}


@dataclass
class UnitRow:
    """One unit of the fleet: where it came from and its numbers. ``serial``: the model
    records the unit's serial (else ``unit`` is its directory's name); ``flags``: why it
    is not counted in the yield ("not validated", "narrow range"), ``notes`` say more."""

    unit: str
    model_dir: str
    run: str
    held_out: bool
    values: dict[str, float] = field(default_factory=dict)
    verdict: str = ""  # PASS / FAIL with a spec
    failed: list[str] = field(default_factory=list)
    serial: bool = True
    flags: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    counted: bool = True

    @property
    def status(self) -> str:
        """``validated``, or its flags with their reasons."""
        if not self.flags:
            return "validated"
        return "; ".join(f"{f} ({n})" for f, n in zip(self.flags, self.notes, strict=True))


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
    if lo <= REF_TEMP_C <= hi:
        # slope over ±1 °C, one-sided where 25 °C is within 1 °C of the range's edge
        a, b = max(lo, REF_TEMP_C - 1), min(hi, REF_TEMP_C + 1)
        fa, f0, fb = f(np.array([a, REF_TEMP_C, b]))
        v["bias_at_25c_dps"] = float(f0)
        v["tempco_at_25c_dps_per_c"] = float((fb - fa) / (b - a)) if b > a else math.nan
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
    serial = model.calibration.get("unit") or metrics.get("unit")
    unit = str(serial or model_dir.name)
    row = UnitRow(unit, str(model_dir), str(metrics.get("run", "")), bool(metrics.get("held_out")))
    row.serial = bool(serial)
    row.values.update(_coefficients(model))
    for name in OUTPUTS:
        keys = SERIES[name][0]
        block = next((metrics[k] for k in keys if isinstance(metrics.get(k), dict)), {})
        for k in METRICS:
            x = block.get(k)
            row.values[f"{name}.{k}"] = float(x) if isinstance(x, (int, float)) else math.nan
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
    return [*COEFFICIENTS, *(f"{s}.{k}" for s in OUTPUTS for k in METRICS)]


def mark(rows: list[UnitRow], allow_in_sample: bool, min_span_c: float) -> None:
    """Flag the units the yield may not count (module docstring): in-sample metrics
    ("not validated"), a calibrated range narrower than ``min_span_c`` ("narrow range")."""
    for r in rows:
        r.flags, r.notes = [], []
        if not r.held_out:
            r.flags.append("not validated")
            r.notes.append("in-sample metrics: fitted without --validate")
        lo, hi = r.values.get("temp_min_c", math.nan), r.values.get("temp_max_c", math.nan)
        span = hi - lo
        if not math.isfinite(span) or span < min_span_c:
            r.flags.append("narrow range")
            r.notes.append(
                f"calibrated {lo:.1f} … {hi:.1f} °C, a span of {span:.1f} °C < {min_span_c:g} °C"
            )
        r.counted = (r.held_out or allow_in_sample) and "narrow range" not in r.flags


def analyse(rows: list[UnitRow], spec_path: str | None = None) -> dict[str, Any]:
    """Summary per quantity, outliers, which units count (:func:`mark`) and (with a spec)
    verdicts and yield."""
    spec = load_spec(spec_path) if spec_path is not None else None
    rules = spec.fleet if spec is not None else {}
    allow = bool(rules.get("allow_in_sample", False))
    min_span = float(rules.get("min_calibrated_span_c", DEFAULT_MIN_CALIBRATED_SPAN_C))
    mark(rows, allow, min_span)
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
    result["counting"] = {"allow_in_sample": allow, "min_calibrated_span_c": min_span}
    if spec is not None:
        from gyrolab.report.spec_limits import FLAGS, METRIC_LIMITS, RUN_LIMITS, Spec, evaluate

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
        counted = [r for r in rows if r.counted]
        k = sum(r.verdict == "PASS" for r in counted)
        lo, hi = wilson(k, len(counted))
        result["yield"] = {
            "spec": spec.name or Path(str(spec_path)).name,
            "series": SERIES[spec.series or "causal"][1],
            "limits": metric_only.limits,
            "passed": k,
            "total": len(counted),
            "yield": k / len(counted) if counted else math.nan,
            "wilson95": [lo, hi],
            "excluded": [{"unit": r.unit, "status": r.status} for r in rows if not r.counted],
            "not_checked": unchecked,
        }
    return result


def unit_table(rows: list[UnitRow], outliers: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """``units.csv``: one flat dict per unit."""
    flagged: dict[str, list[str]] = {}
    for o in outliers:
        flagged.setdefault(o["unit"], []).append(o["quantity"])
    out = []
    for r in rows:
        d: dict[str, Any] = {
            "unit": r.unit,
            "serial_in_model": r.serial,
            "model_dir": r.model_dir,
            "run": r.run,
            "held_out": r.held_out,
            "status": r.status,
            "counted_in_yield": r.counted,
        }
        d.update({c: r.values.get(c, math.nan) for c in columns()})
        d["outlier_in"] = ";".join(flagged.get(r.unit, []))
        if r.verdict:
            d["verdict"] = r.verdict
            d["failed_limits"] = ";".join(r.failed)
        out.append(d)
    return out


__all__ = ["analyse", "find_model_dirs", "mark", "read_unit", "robust_z", "unit_table", "wilson"]
