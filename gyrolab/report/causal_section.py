"""The report's headline section: the causal full-bandwidth output, the baselines and the
paper's offline method beside it, and the oracle where the truth is known.

Laid out from a :class:`~gyrolab.report.analysis.ModelRun` (called by
:func:`gyrolab.report.layout.document`): the series are those ``gyrolab compensate`` kept
(or the report computed, :mod:`gyrolab.report.analysis`), the oracle's among them for a
``gyrolab simulate`` output (:mod:`gyrolab.compensation.oracle`). One :class:`Section`
with a table and a figure. Every column is measured on the same averages (3.6 s, and
100 s for the drift peak-to-peak), so no method gets a low-pass the others do not.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from gyrolab.report import figures as F
from gyrolab.report.analysis import ModelRun
from gyrolab.report.data import CAUSAL_LABEL, offline_label
from gyrolab.report.document import FigureBlock, Section, TableBlock, TextBlock
from gyrolab.report.text import dotted

ORACLE_COLOR = "#000000"
POLY_COLOR = "#9467bd"


def _fmt(x: Any) -> str:
    if x is None or not isinstance(x, (int, float)) or not np.isfinite(x):
        return "—"
    return f"{x:.4g}"


def causal_headline_section(mr: ModelRun) -> Section | None:
    """The headline section (module docstring); ``None`` for a model without a causal
    part (a model directory written before it existed)."""
    metrics, res = mr.metrics, mr.results
    if getattr(mr.model, "causal", None) is None or "causal" not in metrics:
        return None
    n = res.t.size
    oracle = res.series.get("oracle")
    series: list[tuple[str, Any, str]] = [("raw", res.series["raw"], F.RAW_COLOR)]
    if oracle is not None:
        series.append(("oracle (true drift removed)", oracle, ORACLE_COLOR))
    fam = metrics["causal_model"]["family"]
    offline = offline_label(metrics)
    series += [
        (f"{CAUSAL_LABEL} ({fam})", res.series.get("causal"), F.COMP_COLOR),
        ("baseline: poly(T), causal", res.series.get("baselines.poly"), POLY_COLOR),
        (offline, res.series["compensated"], F.OFFLINE_COLOR),
    ]
    series = [s for s in series if s[1] is not None]

    cols: list[tuple[str, str]] = [(f"{CAUSAL_LABEL} (headline)", "causal")]
    if oracle is not None:
        cols.append(("oracle", "oracle"))
    cols += [("raw", "raw")]
    cols += [(f"baseline {k} (T), causal", f"baselines.{k}") for k in metrics.get("baselines", {})]
    cols += [("paper GA-BP (T), causal", "compensated_drift_only"), (offline, "compensated")]

    def get(path: str) -> dict[str, Any]:
        return dotted(metrics, path)

    pp = metrics.get("drift_pp_100s_deg_per_s", {})
    rows = [
        ["bias stability (°/h, std of 3.6 s)"]
        + [_fmt(get(k).get("bias_stability_deg_per_h")) for _, k in cols],
        ["drift p-p of 100 s averages (°/s)"] + [_fmt(pp.get(k)) for _, k in cols],
        ["drift p-p of 3.6 s averages (°/s)"]
        + [_fmt(get(k).get("drift_pp_deg_per_s")) for _, k in cols],
        ["residual mean bias (°/h)"] + [_fmt(_mean_bias(res, metrics, k)) for _, k in cols],
        ["ARW (°/√h)"] + [_fmt(get(k).get("arw_deg_per_sqrt_h")) for _, k in cols],
        ["bias instability (°/h)"]
        + [_fmt(get(k).get("bias_instability_deg_per_h")) for _, k in cols],
    ]
    tab = TableBlock(
        "causal-headline",
        "Headline: the causal output beside the other outputs, on the same averages",
        ["metric"] + [c for c, _ in cols],
        rows,
    )
    cm = metrics["causal_model"]
    feat = cm.get("features", {})
    tab.note = (
        f"Causal headline: {fam} model (chosen by cross-validation inside the calibration run "
        f"among {', '.join(cm.get('cv_rmse_deg_per_s', {}))}), die lag τ = "
        f"{feat.get('tau_s', 0.0):.0f} s; output raw − d(PT100 readings up to now), full "
        f"bandwidth ({metrics.get('headline', {}).get('bandwidth_hz', float('nan')):.3g} Hz). "
        "Every column on the same 3.6 s and 100 s averages."
        + (
            " Oracle: this simulated run minus its true deterministic drift."
            if oracle is not None
            else " No oracle: the true drift of this run is not known."
        )
    )
    tab.note += band_sentence(metrics) + extrapolation_sentence(metrics)
    sec = Section("headline", "Headline: causal compensation (real-time, full bandwidth)")
    sec.blocks.append(
        TextBlock(
            "The causal output is what the gyro can deliver in real time: the drift estimate "
            "uses past temperature readings only and never looks at the gyro output, so real "
            "rotation passes through untouched. The paper's method is offline and low-passes "
            "the output (see the bandwidth in its column).",
            "note",
        )
    )
    sec.blocks.append(tab)
    hyst = hysteresis_table(metrics)
    if hyst is not None:
        sec.blocks.append(hyst)
    sec.blocks.append(
        FigureBlock(
            "causal-headline",
            "Causal output against the baselines"
            + (", the oracle" if oracle is not None else "")
            + " and the offline reconstruction",
            F.causal_headline(
                res.t[:n],
                [(a, np.asarray(b)[:n], c) for a, b, c in series],
                res.block_s,
                float(metrics["headline"]["drift_pp_window_s"]),
            ),
            "100 s averages of the raw output (top) and of each compensated output (bottom).",
        )
    )
    return sec


def hysteresis_table(metrics: dict[str, Any]) -> TableBlock | None:
    """The causal model's up/down hysteresis width (metrics.json
    ``causal_hysteresis_width``) at the low end, middle and high end of its calibrated
    range; ``None`` when the report has none."""
    w = metrics.get("causal_hysteresis_width")
    if not w:
        return None
    ends = ("low", "mid", "high")
    tab = TableBlock(
        "causal-hysteresis",
        "Up/down hysteresis width of the causal model",
        ["", "low end", "middle", "high end"],
        [
            ["die temperature (°C)"] + [f"{w[f'{e}_c']:.1f}" for e in ends],
            ["heating − cooling branch (°/h)"] + [f"{w[f'at_{e}_deg_per_h']:+.3g}" for e in ends],
        ],
    )
    fam = metrics.get("causal_model", {}).get("family", "")
    tab.note = (
        f"The drift of the {fam} model on the heating branch minus the cooling branch at the "
        "same die temperature, at rest and warmed up: the width of the up/down loop it "
        "compensates (0 when the model has no hysteresis term)."
    )
    return tab


def hysteresis_axes_section(axes: dict[str, dict[str, Any]]) -> Section | None:
    """A multi-axis report's overview: each axis's up/down hysteresis width (its
    metrics); ``None`` when no axis has a causal model."""
    rows = []
    for name, m in axes.items():
        w = m.get("causal_hysteresis_width")
        if w:
            rows.append(
                [name, m.get("causal_model", {}).get("family", "")]
                + [f"{w[f'at_{e}_deg_per_h']:+.3g}" for e in ("low", "mid", "high")]
                + [f"{w['low_c']:.1f} … {w['high_c']:.1f}"]
            )
    if not rows:
        return None
    sec = Section("hysteresis-axes", "Up/down hysteresis width per axis")
    tab = TableBlock(
        "hysteresis-axes",
        "Heating − cooling branch of each axis's causal model (°/h)",
        ["axis", "model", "low end", "middle", "high end", "calibrated range (°C)"],
        rows,
    )
    tab.note = (
        "At rest and warmed up, at the ends and the middle of each axis's calibrated range "
        "of the die temperature; each axis's headline section has its own table."
    )
    sec.blocks.append(tab)
    return sec


def _mean_bias(res: Any, metrics: dict[str, Any], key: str) -> float | None:
    """Residual mean bias (°/h) of one column: metrics.json's, else from the kept series."""
    mb = metrics.get("residual_mean_bias_deg_per_h", {})
    if key in mb:
        return mb[key]
    x = res.series.get(key)
    return None if x is None else float(np.mean(x) * 3600.0)


def band_sentence(metrics: dict[str, Any]) -> str:
    """The causal model's 90 % band and the graded expected error ('' without a band)."""
    b = metrics.get("causal_band")
    if not b:
        return ""
    cov = b.get("coverage_100s")
    ee = b["expected_error"]
    return (
        f" Prediction band ({100 * b['level']:.0f} %, measured by the calibration's "
        f"cross-validation): 100 s means within ±{b['half_width_inside_deg_per_s']:.3g} °/s "
        f"inside the calibrated range, widening by {b['per_c_deg_per_s']:.3g} °/s per °C "
        f"and {b['per_c_per_min_deg_per_s']:.3g} °/s per °C/min beyond it"
        + ("" if b.get("law_measured", True) else " (default law: not measurable here)")
        + (f"; on this run {100 * cov:.0f} % of the 100 s means lie inside it" if cov else "")
        + f". Expected error on this run: {ee['grade']} (90th percentile of the band "
        f"{ee['ratio_p90']:.2f}× its in-range width)."
    )


def extrapolation_sentence(metrics: dict[str, Any]) -> str:
    """Which baselines extrapolate on this run ('' when none does)."""
    ex = metrics.get("baselines_extrapolation") or {}
    names = [n for n, e in ex.items() if e.get("extrapolating")]
    if not names:
        return ""
    e = ex[names[0]]
    return (
        f" Baselines extrapolating on this run: {', '.join(names)} — "
        f"{100 * e['fraction_outside_temperature']:.1f} % of the points up to "
        f"{e['max_beyond_c']:.1f} °C beyond the calibrated temperature range"
        + (
            f", {100 * e['fraction_outside_rate']:.1f} % beyond the calibrated dT/dt range"
            if "fraction_outside_rate" in e
            else ""
        )
        + "; there each continues with "
        + "; ".join(f"{n}: {ex[n]['continues_with']}" for n in names)
        + "."
    )
