"""``DIR/index.html`` of a discrepancy analysis: self-contained (figures embedded as PNG),
opens offline. Figures show the current model (before) against the updated one (after):
low-frequency residual against time, temperature and dT/dt; its spectrum; the Allan curve
of the residual against the model's noise terms; the oven and PT100 residuals.
"""

from __future__ import annotations

import base64
import html
import io
import json
from typing import Any

import numpy as np

from gyrolab.sim.discrepancy.fitting import LF_WINDOW_S, Fitted, moving_average
from gyrolab.sim.discrepancy.workflow import Result


def _png(fig: Any) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def _lf(f: Fitted) -> np.ndarray:
    k = max(1, int(round(LF_WINDOW_S / (f.ctx.t[1] - f.ctx.t[0]))))
    return moving_average(f.resid, k)


def figures(res: Result) -> dict[str, str]:
    """Base64 PNGs of the report's figures."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.signal import welch

    a, b = res.first, res.final
    t_h = a.ctx.t / 3600.0
    T = np.interp(a.ctx.t, a.ctx.grid_t, a.ctx.case_c)
    dT = 60.0 * np.interp(a.ctx.t, a.ctx.grid_t, a.ctx.dcase)
    ra, rb = _lf(a), _lf(b)
    out: dict[str, str] = {}

    fig, ax = plt.subplots(figsize=(9, 3.4))
    ax.plot(t_h, ra * 1e3, lw=0.8, label="before (current model)")
    ax.plot(t_h, rb * 1e3, lw=0.8, label="after (updated model)")
    ax.set_xlabel("time since power-on (h)")
    ax.set_ylabel("LF residual (m°/s)")
    ax2 = ax.twinx()
    ax2.plot(t_h, T, color="0.6", lw=0.6)
    ax2.set_ylabel("case temperature (°C)", color="0.5")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(f"Low-frequency residual ({LF_WINDOW_S:g} s moving average)")
    out["residual_time"] = _png(fig)

    fig, axs = plt.subplots(1, 2, figsize=(9, 3.4))
    axs[0].plot(T, ra * 1e3, ".", ms=1.5, label="before")
    axs[0].plot(T, rb * 1e3, ".", ms=1.5, label="after")
    axs[0].set_xlabel("case temperature (°C)")
    axs[0].set_ylabel("LF residual (m°/s)")
    axs[0].legend(fontsize=8, markerscale=5)
    axs[1].plot(dT, ra * 1e3, ".", ms=1.5)
    axs[1].plot(dT, rb * 1e3, ".", ms=1.5)
    axs[1].set_xlabel("dT/dt (°C/min)")
    fig.suptitle("Residual against temperature and its rate")
    out["residual_temperature"] = _png(fig)

    fig, axs = plt.subplots(1, 2, figsize=(9, 3.6))
    rate_hz = 1.0 / (a.ctx.t[1] - a.ctx.t[0])
    for f, lab in ((a, "before"), (b, "after")):
        fr, p = welch(f.resid, fs=rate_hz, nperseg=min(1024, f.resid.size))
        axs[0].loglog(fr[1:], p[1:], lw=0.8, label=lab)
    axs[0].set_xlabel("frequency (Hz)")
    axs[0].set_ylabel("residual PSD ((°/s)²/Hz)")
    axs[0].legend(fontsize=8)
    for f, lab, col in ((a, "before", "C0"), (b, "after", "C1")):
        c = f.noise.curve
        axs[1].loglog(c.tau, c.adev * 3600, "o", ms=3, color=col, label=f"residual, {lab}")
        axs[1].loglog(
            c.tau, f.noise.model_adev() * 3600, "-", lw=1, color=col, label=f"model noise, {lab}"
        )
    axs[1].set_xlabel("τ (s)")
    axs[1].set_ylabel("Allan deviation (°/h)")
    axs[1].legend(fontsize=7)
    fig.suptitle("Spectrum and Allan deviation of the residual")
    out["spectrum_allan"] = _png(fig)

    fig, axs = plt.subplots(1, 2, figsize=(9, 3.2))
    d_ov = a.oven
    tov = np.linspace(0, 1, d_ov.resid.size)
    axs[0].plot(tov, a.oven.resid, lw=0.7, label="before")
    axs[0].plot(tov, b.oven.resid, lw=0.7, label="after")
    axs[0].set_xlabel("fraction of run")
    axs[0].set_ylabel("oven PV residual (°C)")
    axs[0].legend(fontsize=8)
    tpt = np.linspace(0, 1, a.case.resid.size)
    axs[1].plot(tpt, a.case.resid, lw=0.5)
    axs[1].plot(tpt, b.case.resid, lw=0.5)
    axs[1].set_xlabel("fraction of run")
    axs[1].set_ylabel("PT100 residual (°C)")
    fig.suptitle("Temperature channels")
    out["temperature"] = _png(fig)
    if res.periodic_content:
        from gyrolab.sim.discrepancy.periodic import cycle_residual, local_level, spectrum

        freq, p = spectrum(cycle_residual(b), b.ctx.bin_s)
        fig, ax = plt.subplots(figsize=(9, 3.4))
        ax.loglog(freq, p, lw=0.7, label="residual (cycles put back)")
        ax.loglog(freq, local_level(freq, p) * np.log(2.0), lw=1.0, label="local median")
        for c in res.periodic_content:
            ax.axvline(1.0 / c["period_s"], color="C3", lw=0.8, ls="--")
            ax.annotate(
                f"{c['period_s']:.0f} s: {c['peak_to_local_median']:.0f}× median",
                (1.0 / c["period_s"], float(np.max(p))),
                fontsize=8,
                color="C3",
            )
        ax.set_xlabel("frequency (Hz)")
        ax.set_ylabel("PSD ((°/s)²/Hz)")
        ax.legend(fontsize=8)
        ax.set_title("Periodic content in the measurement (check the bench)")
        out["periodic_content"] = _png(fig)
    return out


def _table(rows: list[list[Any]], head: list[str]) -> str:
    h = "".join(f"<th>{html.escape(str(x))}</th>" for x in head)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(_fmt(x))}</td>" for x in r) + "</tr>" for r in rows
    )
    return f"<table><tr>{h}</tr>{body}</table>"


def _fmt(x: Any) -> str:
    if isinstance(x, float):
        return f"{x:.4g}"
    if isinstance(x, list):
        return ", ".join(_fmt(v) for v in x)
    return str(x)


def render(res: Result, source: str) -> str:
    """The report page."""
    figs = figures(res)
    gap_rows = []
    for k in res.gap_before:
        b, a = res.gap_before[k], res.gap_after[k]
        gap_rows.append([k, b, a, f"{(1 - a / b) * 100:.0f} %" if b else "—"])
    step_rows = []
    for s in res.steps:
        sig = [
            f"{c['effect']} {c['score']:.1f}"
            for c in sorted(s["candidates"], key=lambda c: -c["score"])
            if c["significant"]
        ]
        loc = s["localize"]
        # profile steps and iterations are counted from 1 on the page (0 in the JSON)
        worst = ", ".join(
            f"step {w['step'] + 1} ({w['setpoint_c']:g} °C)" for w in loc["worst_steps"]
        )
        step_rows.append(
            [
                s["iteration"] + 1,
                " + ".join(x for x in (s.get("added"), s.get("added_with")) if x) or "—",
                ", ".join(s.get("ambiguous_with", [])) or "—",
                "; ".join(sig) or "none",
                worst,
                str(loc["allan_tau_range_s"] or "—"),
            ]
        )
    added_rows = []
    for s in res.steps:
        if s.get("added"):
            b, a = s["gap_metric_before_after"]
            moves = "; ".join(
                f"{m['move']} {m['effect']}" + (f" → {m['to']}" if "to" in m else "")
                for m in s.get("revisions", [])
            )
            pair = f" + {s['added_with']}" if s.get("added_with") else ""
            added_rows.append([s["added"] + pair, s["gap_metric"], b, a, moves or "—"])
        for r in s.get("rejected_gap_grew", []):
            b, a = r["gap_metric_before_after"]
            why = "gap grew" + (f"; added with {r['added_with']}" if r.get("added_with") else "")
            added_rows.append([r["effect"] + " (rejected)", r["gap_metric"], b, a, why])
    limit_rows = [
        [
            name,
            e["parameter"],
            "not computed" if e["limit"] is None else e["limit"],
            e["unit"],
            ", ".join(f"{k} = {v:g}" for k, v in e.get("at", {}).items()) or "—",
            e["method"],
        ]
        for name, e in sorted(res.detection_limits.items())
    ]
    imgs = "".join(
        f'<figure><img alt="{k}" src="data:image/png;base64,{v}"></figure>' for k, v in figs.items()
    )
    found = ", ".join(res.effects_found) or "nothing: the model explains this recording"
    amb = "; ".join("{" + ", ".join(s) + "}" for s in res.ambiguous) or "none"
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>gyrolab discrepancy</title>
<style>body{{font-family:sans-serif;max-width:1000px;margin:2em auto;color:#222}}
table{{border-collapse:collapse;margin:1em 0}}td,th{{border:1px solid #bbb;padding:3px 8px;
font-size:13px}}th{{background:#eee}}img{{max-width:100%}}code{{background:#f4f4f4}}</style>
</head><body>
<h1>Discrepancy: simulator model vs recording</h1>
<p>Recording <code>{html.escape(source)}</code>. Effects named (in the order added):
<b>{html.escape(found)}</b>. Ambiguous sets (cannot be told apart on this data):
<b>{html.escape(amb)}</b>.</p>
<h2>Gap before and after</h2>
{_table(gap_rows, ["metric", "before", "after", "shrink"])}
<h2>Each added effect and its own gap</h2>
<p>An effect is added only when the gap metric that belongs to it shrinks.</p>
{_table(added_rows, ["effect", "its gap metric", "before", "after", "revisions"])}
{_ambiguity_html(res)}
{_periodic_html(res)}
<h2>Detection limits</h2>
<p>For every effect not added: the smallest amplitude this run would have revealed
(expected score at the significance threshold). Below it, "not found" means
"not detectable here", not "not there".</p>
{_table(limit_rows, ["effect", "parameter", "limit", "unit", "at", "method"])}
<h2>Iterations</h2>
{
        _table(
            step_rows,
            [
                "#",
                "added",
                "ambiguous with",
                "significant candidates (score)",
                "worst steps",
                "Allan τ range off (s)",
            ],
        )
    }
<h2>Figures</h2>{imgs}
<h2>Updated model</h2><pre>{html.escape(res.model.to_toml())}</pre>
<details><summary>discrepancy.json</summary><pre>{
        html.escape(json.dumps(res.to_json(), indent=1, default=json_default))
    }</pre></details>
</body></html>"""


def _ambiguity_html(res: Result) -> str:
    """Each ambiguous set: its members' evidence, the look-alike separations and the
    profile proposed to separate them."""
    if not res.ambiguity:
        return ""
    parts = ["<h2>Ambiguous sets and the next experiment</h2>"]
    for a in res.ambiguity:
        rows = [
            [m, e["delta_bic"], json.dumps(e["params"], default=json_default)]
            for m, e in a.evidence.items()
        ]
        parts.append(f"<h3>{html.escape(' / '.join(a.members))}</h3>")
        parts.append(_table(rows, ["effect", "ΔBIC", "fitted parameters"]))
        for la in a.look_alikes:
            seps = "; ".join(f"{k}: {v:.1f}" for k, v in la["expected_separation"].items())
            parts.append(
                f"<p>{html.escape(la['explanation'])}: observed margin "
                f"{la['observed_margin']:.1f}; expected ΔBIC had either made the data: "
                f"{html.escape(seps)}.</p>"
            )
        if a.proposal is not None:
            pr = a.proposal
            seps = "; ".join(f"{k}: {v:.0f}" for k, v in pr.separation.items())
            parts.append(
                f"<p>Proposed next run: <code>{html.escape(pr.file)}</code> "
                f"({html.escape(pr.profile.description)}, {pr.profile.duration_s / 3600:.1f} h; "
                f"expected ΔBIC {html.escape(seps)}). Run it with <code>gyrolab simulate "
                f"--profile {html.escape(pr.file)}</code> or <code>gyrolab acquire</code>.</p>"
            )
    return "\n".join(parts)


def _periodic_html(res: Result) -> str:
    """Periodic content, apart from the sensor effects."""
    if not res.periodic_content:
        return ""
    rows = [
        [c["period_s"], c["amplitude_dps"], c["peak_to_local_median"], c["false_alarm_probability"]]
        for c in res.periodic_content
    ]
    return (
        "<h2>Periodic content in the measurement</h2><p>"
        + html.escape(res.periodic_content[0]["note"])
        + ".</p>"
        + _table(rows, ["period (s)", "amplitude (°/s)", "peak / local median", "false-alarm p"])
    )


def json_default(o: Any) -> Any:
    """``json.dumps`` default for numpy scalars and arrays (discrepancy.json, the page)."""
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o))
