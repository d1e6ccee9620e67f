"""The report's headline section: the causal full-bandwidth output, the baselines and the
paper's offline method beside it, and the oracle where the truth is known.

Self-contained (one function called by :func:`gyrolab.report.build.build_report`): it
adds ``oracle`` to the metrics when the recording is a ``gyrolab simulate`` output
(:mod:`gyrolab.compensation.oracle`) and returns one :class:`Section` with a table and a
figure. Every column is measured on the same averages (3.6 s, and 100 s for the drift
peak-to-peak), so no method gets a low-pass the others do not.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib.figure import Figure

from gyrolab.numerics.averaging import PAPER_BLOCK_S, block_means
from gyrolab.report import figures as F
from gyrolab.report.document import FigureBlock, Section, TableBlock, TextBlock

ORACLE_COLOR = "#000000"
OFFLINE_COLOR = "#ff7f0e"
POLY_COLOR = "#9467bd"


def _fmt(x: Any) -> str:
    if x is None or not isinstance(x, (int, float)) or not np.isfinite(x):
        return "—"
    return f"{x:.4g}"


def headline_figure(t: np.ndarray, series: list[tuple[str, np.ndarray, str]]) -> Figure:
    """Raw output (top) and the residual of every method (bottom), all as 100 s averages."""
    from gyrolab.compensation.evaluate import DRIFT_PP_WINDOW_S

    fig = Figure(figsize=(9.0, 5.0), layout="constrained")
    top, bot = fig.subplots(2, 1, sharex=True, height_ratios=[1, 1.4])

    def means(x: np.ndarray) -> np.ndarray:  # of the 3.6 s series: 28 blocks, 100.8 s
        return block_means(np.asarray(x[: t.size], float), 1.0 / PAPER_BLOCK_S, DRIFT_PP_WINDOW_S)

    th = means(t) / 3600.0
    for label, x, color in series:
        xm = means(x)
        ax = top if label == "raw" else bot
        lw = 1.2 if label.startswith("causal") else 0.8
        ax.plot(th, xm, color=color, lw=lw, label=label)
    top.set_ylabel("raw (°/s)")
    bot.set_ylabel("compensated (°/s)")
    bot.set_xlabel("time since power-on (h)")
    for ax in (top, bot):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="best")
    top.set_title("100 s averages: the causal headline, the baselines, the oracle")
    return fig


def causal_headline_section(
    metrics: dict[str, Any], model: Any, app: Any, run: Any, rec: Any
) -> Section | None:
    """The headline section (module docstring); ``None`` for a model without a causal
    part (a model directory written before it existed)."""
    from gyrolab.compensation.apply import streaming_block_means
    from gyrolab.compensation.evaluate import drift_pp_table, series_metrics
    from gyrolab.compensation.oracle import oracle_block_means

    if getattr(model, "causal", None) is None or "causal" not in metrics:
        return None
    bs = model.config.block_s
    n = run.t.size
    causal = streaming_block_means(model, run, "causal")[:n]
    oracle = oracle_block_means(rec, bs)
    series: list[tuple[str, np.ndarray, str]] = [("raw", app.series["raw"], F.RAW_COLOR)]
    if oracle is not None:
        oracle = oracle[:n]
        metrics["oracle"] = series_metrics(oracle, bs)
        metrics.setdefault("drift_pp_100s_deg_per_s", {}).update(
            drift_pp_table({"oracle": oracle}, bs)
        )
        series.append(("oracle (true drift removed)", oracle, ORACLE_COLOR))
    fam = metrics["causal_model"]["family"]
    series += [
        (f"causal headline ({fam})", causal, F.COMP_COLOR),
        ("baseline: poly(T), causal", app.series.get("baselines.poly"), POLY_COLOR),
        ("paper's method, offline", app.series["compensated"], OFFLINE_COLOR),
    ]
    series = [s for s in series if s[1] is not None]

    bw = metrics.get("denoising", {}).get("bandwidth", {})
    f3 = bw.get("f3db_hz")
    cols: list[tuple[str, str]] = [("causal headline", "causal")]
    if oracle is not None:
        cols.append(("oracle", "oracle"))
    cols += [("raw", "raw")]
    cols += [(f"baseline {k} (T), causal", f"baselines.{k}") for k in metrics.get("baselines", {})]
    cols += [
        ("paper GA-BP (T), causal", "compensated_drift_only"),
        (
            "paper's method, offline"
            + (f" (f3dB {1e3 * f3:.2g} mHz)" if isinstance(f3, float) else ""),
            "compensated",
        ),
    ]

    def get(path: str) -> dict[str, Any]:
        d: Any = metrics
        for p in path.split("."):
            d = d.get(p, {}) if isinstance(d, dict) else {}
        return d if isinstance(d, dict) else {}

    pp = metrics.get("drift_pp_100s_deg_per_s", {})
    rows = [
        ["bias stability (°/h, std of 3.6 s)"]
        + [_fmt(get(k).get("bias_stability_deg_per_h")) for _, k in cols],
        ["drift p-p of 100 s averages (°/s)"] + [_fmt(pp.get(k)) for _, k in cols],
        ["drift p-p of 3.6 s averages (°/s)"]
        + [_fmt(get(k).get("drift_pp_deg_per_s")) for _, k in cols],
        ["ARW (°/√h)"] + [_fmt(get(k).get("arw_deg_per_sqrt_h")) for _, k in cols],
        ["bias instability (°/h)"]
        + [_fmt(get(k).get("bias_instability_deg_per_h")) for _, k in cols],
    ]
    tab = TableBlock("causal-headline", "Causal headline", ["metric"] + [c for c, _ in cols], rows)
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
    sec.blocks.append(
        FigureBlock(
            "causal-headline",
            "Causal headline against the baselines",
            headline_figure(run.t[:n], [(a, np.asarray(b)[:n], c) for a, b, c in series]),
            "100 s averages of the raw output (top) and of each compensated output (bottom).",
        )
    )
    return sec
