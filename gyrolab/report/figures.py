"""The report's figures, drawn from plain numpy arrays (no recording or model objects).

Every function returns a :class:`matplotlib.figure.Figure` built without ``pyplot``, so
figures never leak global state, work under any backend and can be saved to PNG (HTML
report) and to a PDF page alike. Figure numbers in the docstrings refer to the paper in
``shared/paper`` (Figs 9-15).

Long series are expected pre-averaged (:func:`gyrolab.numerics.averaging.block_average`): a
13 h run at 100 Hz has 4.7 M samples, far more than a figure can show, and the paper itself
plots 1000 points/h.
"""

from __future__ import annotations

import io
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from matplotlib.figure import Figure

# One colour per IMF class, used by every VMD/MPE figure so the classes read the same.
CLASS_COLORS: dict[str, str] = {"noise": "#d62728", "mixed": "#ff7f0e", "drift": "#1f77b4"}
RAW_COLOR = "#7f7f7f"
COMP_COLOR = "#2ca02c"  # the causal output: the compensated output
OFFLINE_COLOR = "#ff7f0e"  # the paper's offline reconstruction


def to_png(fig: Figure, dpi: int = 110) -> bytes:
    """PNG bytes of a figure (Agg canvas; deterministic metadata)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, metadata={"Software": None})
    return buf.getvalue()


def _figure(width: float, height: float) -> Figure:
    fig = Figure(figsize=(width, height), layout="constrained")
    return fig


def _hours(t: np.ndarray) -> np.ndarray:
    return np.asarray(t, dtype=float) / 3600.0


def temperature_profile(
    oven_t: np.ndarray,
    setpoint_c: np.ndarray,
    pv_c: np.ndarray,
    pt100_t: np.ndarray,
    pt100_c: np.ndarray,
    safe: np.ndarray | None = None,
    profile_c: tuple[float, float] | None = None,
    temperature_label: str = "gyro case (PT100)",
) -> Figure:
    """Oven setpoint, chamber process value and the PT100 on the gyro case against time
    (``temperature_label``: a unit read by its internal sensor says so).

    ``safe`` marks the oven readings taken in the end-of-run safe state: the setpoint's
    step to the safe setpoint is drawn apart (red, dashed, annotated) so it reads as the
    safe state and not as a glitch of the profile. ``profile_c`` shades the profile's
    setpoint range, against which the reached temperatures are read.
    """
    fig = _figure(9.0, 3.6)
    ax = fig.add_subplot()
    if profile_c is not None:
        ax.axhspan(*profile_c, color="#1f4e79", alpha=0.06, lw=0, label="profile range")
    if np.size(oven_t):
        th = _hours(oven_t)
        sp = np.asarray(setpoint_c, dtype=float)
        s = np.zeros(th.size, bool) if safe is None or len(safe) != th.size else np.asarray(safe)
        run = ~s
        ax.step(th[run], sp[run], where="post", color="k", lw=1.2, label="oven setpoint")
        if s.any():
            k = int(np.flatnonzero(s)[0])
            xs = th[max(0, k - 1) :] if k else th[s]
            ys = np.concatenate([sp[max(0, k - 1) : k], sp[s]]) if k else sp[s]
            ax.step(xs, ys, where="post", color="#d62728", lw=1.4, ls="--",
                    label="safe state (end of run)")
            ax.annotate(
                f"safe state {sp[k]:g} °C",
                (th[k], sp[k]),
                xytext=(-6, 8),
                textcoords="offset points",
                ha="right",
                fontsize=8,
                color="#d62728",
            )
        ax.plot(th, pv_c, color="#ff7f0e", lw=1.0, label="chamber air (PV)")
    if np.size(pt100_t):
        ax.plot(_hours(pt100_t), pt100_c, color="#1f77b4", lw=1.2, label=temperature_label)
    ax.set_xlabel("time since power-on (h)")
    ax.set_ylabel("temperature (°C)")
    ax.set_title("Temperature profile")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    return fig


def raw_output(t: np.ndarray, rate: np.ndarray, temp_t: np.ndarray, temp_c: np.ndarray) -> Figure:
    """Raw gyro output against time (with temperature) and against temperature (paper Fig. 9).

    ``t``/``rate`` should be averaged already; the temperature is interpolated onto ``t``
    for the right-hand panel.
    """
    fig = _figure(10.0, 3.8)
    a1, a2 = fig.subplots(1, 2, width_ratios=[1.6, 1.0])
    a1.plot(_hours(t), rate, color=RAW_COLOR, lw=0.7)
    a1.set_xlabel("time since power-on (h)")
    a1.set_ylabel("output (°/s)")
    a1.set_title("Raw output and temperature")
    a1.grid(alpha=0.3)
    if np.size(temp_t):
        tw = a1.twinx()
        tw.plot(_hours(temp_t), temp_c, color="#1f77b4", lw=1.0, alpha=0.8)
        tw.set_ylabel("PT100 (°C)", color="#1f77b4")
        tw.tick_params(axis="y", colors="#1f77b4")
        temp_on_t = np.interp(t, temp_t, temp_c)
        sc = a2.scatter(temp_on_t, rate, c=_hours(t), s=2, cmap="viridis", rasterized=True)
        fig.colorbar(sc, ax=a2, label="time (h)")
        a2.set_xlabel("gyro case temperature (°C)")
    else:
        a2.text(0.5, 0.5, "no temperature channel", ha="center", va="center")
    a2.set_ylabel("output (°/s)")
    a2.set_title("Raw output against temperature")
    a2.grid(alpha=0.3)
    return fig


def vmd_modes(
    t: np.ndarray, modes: np.ndarray, classes: Sequence[str], mpe: Sequence[float]
) -> Figure:
    """The VMD modes, one row each, coloured by class and labelled with their MPE (Fig. 11)."""
    modes = np.atleast_2d(np.asarray(modes, dtype=float))
    k = modes.shape[0]
    fig = _figure(9.0, max(3.0, 0.85 * k + 0.8))
    axes = np.atleast_1d(fig.subplots(k, 1, sharex=True))
    th = _hours(t)
    for i, ax in enumerate(axes):
        cls = classes[i] if i < len(classes) else "?"
        ax.plot(th, modes[i], color=CLASS_COLORS.get(cls, "k"), lw=0.6)
        ax.set_ylabel(f"IMF{i + 1}", rotation=0, ha="right", va="center", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.yaxis.get_offset_text().set_fontsize(6)
        label = f"{cls}  MPE {mpe[i]:.3f}" if i < len(mpe) else cls
        ax.text(
            1.0,
            0.5,
            label,
            transform=ax.transAxes,
            ha="left",
            va="center",
            fontsize=8,
            color=CLASS_COLORS.get(cls, "k"),
        )
    axes[0].set_title("VMD decomposition (modes ordered by centre frequency)")
    axes[-1].set_xlabel("time since power-on (h)")
    return fig


def mpe_classes(
    mpe: Sequence[float],
    classes: Sequence[str],
    drift_max: float | None = None,
    noise_min: float | None = None,
) -> Figure:
    """Mean multiscale permutation entropy of each IMF and its class (paper Fig. 12).

    With the thresholds given they are drawn; a mode labelled drift above ``drift_max``
    (the pipeline's fallback: no mode under the threshold, the most regular one is the
    drift) is hatched and marked "fallback".
    """
    mpe = np.asarray(mpe, dtype=float)
    fig = _figure(7.0, 3.2)
    ax = fig.add_subplot()
    idx = np.arange(1, mpe.size + 1)
    colors = [CLASS_COLORS.get(c, "k") for c in classes]
    bars = ax.bar(idx, mpe, color=colors)
    for i, (b, c) in enumerate(zip(bars, classes, strict=False)):
        if c == "drift" and drift_max is not None and mpe[i] > drift_max:
            b.set_hatch("//")
            b.set_edgecolor("k")
            ax.annotate("fallback", (idx[i], mpe[i]), xytext=(0, 3),
                        textcoords="offset points", ha="center", fontsize=7)
    for thr, name in ((drift_max, "drift ≤"), (noise_min, "noise ≥")):
        if thr is not None:
            ax.axhline(thr, color="k", lw=0.8, ls=":")
            ax.text(idx[-1] + 0.45, thr, f"{name} {thr:g}", fontsize=7, va="bottom", ha="right")
    for cls, col in CLASS_COLORS.items():
        ax.bar([np.nan], [np.nan], color=col, label=cls)
    ax.set_xticks(idx, [f"IMF{i}" for i in idx], fontsize=8)
    ax.set_ylabel("mean MPE")
    ax.set_title("IMF classification by multiscale permutation entropy")
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    return fig


def gpso(
    best_fitness: Sequence[float],
    particles_k: np.ndarray,
    particles_alpha: np.ndarray,
    best_k: float,
    best_alpha: float,
    mean_fitness: Sequence[float] | None = None,
) -> Figure:
    """GPSO convergence and the particle distribution in (K, α) space (paper Fig. 10).

    ``particles_k``/``particles_alpha`` may hold every particle of every iteration (they are
    shaded by iteration when 2-D: iterations × particles) or only the final swarm.
    """
    fig = _figure(10.0, 3.6)
    a1, a2 = fig.subplots(1, 2)
    it = np.arange(1, len(best_fitness) + 1)
    a1.plot(it, best_fitness, "o-", ms=3, color="k", label="best")
    if mean_fitness is not None and len(mean_fitness):
        a1.plot(it, mean_fitness, color="#999999", lw=1, label="swarm mean")
        a1.legend(fontsize=8)
    a1.set_xlabel("iteration")
    a1.set_ylabel("fitness (lower is better)")
    a1.set_title("GPSO convergence")
    a1.grid(alpha=0.3)
    pk = np.asarray(particles_k, dtype=float)
    pa = np.asarray(particles_alpha, dtype=float)
    if pk.ndim == 2:
        shade = np.repeat(np.arange(pk.shape[0]), pk.shape[1])
        sc = a2.scatter(pk.ravel(), pa.ravel(), c=shade, s=8, cmap="viridis", alpha=0.6)
        fig.colorbar(sc, ax=a2, label="iteration")
    else:
        a2.scatter(pk, pa, s=10, color="#1f77b4", alpha=0.7, label="particles")
    a2.scatter(
        [best_k],
        [best_alpha],
        marker="*",
        s=220,
        color="#d62728",
        zorder=5,
        label=f"best K={best_k:g}, α={best_alpha:.0f}",
    )
    a2.set_xlabel("K (number of modes)")
    a2.set_ylabel("α (bandwidth penalty)")
    a2.set_title("Particle distribution")
    a2.grid(alpha=0.3)
    a2.legend(fontsize=8, loc="best")
    return fig


def drift_fit(
    t: np.ndarray,
    target: np.ndarray,
    predicted: np.ndarray,
    temp_c: np.ndarray | None = None,
) -> Figure:
    """The drift items and the drift model's prediction, with the residual (paper Fig. 13)."""
    fig = _figure(9.0, 4.6)
    a1, a2 = fig.subplots(2, 1, sharex=True, height_ratios=[2.2, 1.0])
    th = _hours(t)
    a1.plot(th, target, color=RAW_COLOR, lw=0.9, label="drift items (VMD)")
    a1.plot(th, predicted, color="#d62728", lw=1.0, ls="--", label="model prediction")
    a1.set_ylabel("drift (°/s)")
    a1.set_title("Temperature-drift model fit")
    a1.grid(alpha=0.3)
    a1.legend(fontsize=8, loc="upper left")
    if temp_c is not None and np.size(temp_c):
        tw = a1.twinx()
        tw.plot(th, temp_c, color="#1f77b4", lw=0.8, alpha=0.5)
        tw.set_ylabel("temperature (°C)", color="#1f77b4")
        tw.tick_params(axis="y", colors="#1f77b4")
    resid = np.asarray(target, dtype=float) - np.asarray(predicted, dtype=float)
    a2.plot(th, resid, color="k", lw=0.6)
    a2.set_ylabel("residual (°/s)")
    a2.set_xlabel("time since power-on (h)")
    a2.grid(alpha=0.3)
    return fig


def compensated(
    t: np.ndarray,
    raw: np.ndarray,
    comp: np.ndarray,
    title: str = "Compensated against raw",
    label: str = "compensated",
    color: str = COMP_COLOR,
) -> Figure:
    """Raw and one compensated output (``label``) on one time axis (paper Fig. 14)."""
    fig = _figure(9.0, 3.6)
    ax = fig.add_subplot()
    th = _hours(t)
    ax.plot(th, raw, color=RAW_COLOR, lw=0.7, label="raw")
    ax.plot(th, comp, color=color, lw=0.9, label=label)
    ax.set_xlabel("time since power-on (h)")
    ax.set_ylabel("output (°/s)")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return fig


@dataclass
class AllanCurve:
    """One Allan-deviation curve; ``adev``/``lo``/``hi`` in °/h, ``tau`` in s.

    ``arw_deg_per_sqrt_h`` draws the −½ line σ = 60·ARW/√τ (°/h) over ``arw_tau`` (the τ
    range it was identified on; the whole curve when not given).
    ``bias_instability_deg_per_h`` draws the floor 0.664·B over ``bi_tau`` and marks the
    minimum at ``tau_b``; ``None`` with ``bi_upper_bound`` labels the curve "no floor
    within the record" instead. Terms that are ``None``/NaN draw nothing.
    """

    label: str
    tau: np.ndarray
    adev: np.ndarray
    lo: np.ndarray | None = None
    hi: np.ndarray | None = None
    arw_deg_per_sqrt_h: float | None = None
    bias_instability_deg_per_h: float | None = None
    color: str = RAW_COLOR
    arw_tau: tuple[float, float] | None = None
    bi_tau: tuple[float, float] | None = None
    tau_b: float | None = None
    bi_upper_bound: float | None = None


def _finite(x: float | None) -> bool:
    return x is not None and bool(np.isfinite(x)) and x > 0


def _span(tau: np.ndarray, rng: tuple[float, float] | None) -> np.ndarray:
    """τ grid for an annotation line: the identified range (log-spaced), else the curve's."""
    if rng is None:
        return tau
    lo, hi = float(rng[0]), float(rng[1])
    return np.geomspace(lo, hi, 32) if hi > lo else np.array([lo])


def allan(curves: Sequence[AllanCurve]) -> Figure:
    """Allan deviation with confidence bands, ARW and bias-instability lines (paper Fig. 15).

    Each annotation is drawn only over the τ range its term was identified on, so a line
    lies on the stretch of curve it describes; a curve without a floor says so."""
    fig = _figure(8.0, 4.8)
    ax = fig.add_subplot()
    for c in curves:
        tau = np.asarray(c.tau, dtype=float)
        ok = np.isfinite(c.adev) & (np.asarray(c.adev) > 0)
        ax.loglog(
            tau[ok], np.asarray(c.adev)[ok], "o-", ms=2.5, lw=1.2, color=c.color, label=c.label
        )
        if c.lo is not None and c.hi is not None:
            lo, hi = np.asarray(c.lo, dtype=float), np.asarray(c.hi, dtype=float)
            okb = ok & np.isfinite(lo) & np.isfinite(hi) & (lo > 0)
            ax.fill_between(tau[okb], lo[okb], hi[okb], color=c.color, alpha=0.2, lw=0)
        if _finite(c.arw_deg_per_sqrt_h) and tau.size:
            # N in °/√h → σ(τ) = 60·N / √τ in °/h with τ in seconds.
            n = 60.0 * float(c.arw_deg_per_sqrt_h)  # type: ignore[arg-type]
            t = _span(tau, c.arw_tau)
            ax.loglog(
                t,
                n / np.sqrt(t),
                ls=":",
                lw=1.6,
                color=c.color,
                label=f"{c.label} ARW {c.arw_deg_per_sqrt_h:.3g} °/√h",
            )
        if _finite(c.bias_instability_deg_per_h):
            level = 0.664 * float(c.bias_instability_deg_per_h)  # type: ignore[arg-type]
            t = _span(tau, c.bi_tau)
            ax.loglog(
                t,
                np.full(t.size, level),
                ls="--",
                lw=1.6,
                color=c.color,
                label=f"{c.label} bias instability {c.bias_instability_deg_per_h:.3g} °/h",
            )
            if c.tau_b is not None:
                ax.plot([c.tau_b], [level], marker="v", ms=7, color=c.color, ls="none")
        elif c.bi_upper_bound is not None:
            ax.plot(
                [],
                [],
                ls="none",
                label=f"{c.label}: no floor within the record (B ≤ {c.bi_upper_bound:.3g} °/h)",
            )
    ax.set_xlabel("averaging time τ (s)")
    ax.set_ylabel("Allan deviation (°/h)")
    ax.set_title("Allan deviation: " + ", ".join(c.label for c in curves), fontsize=9)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7, loc="best")
    return fig


def causal_headline(
    t: np.ndarray,
    series: Sequence[tuple[str, np.ndarray, str]],
    block_s: float,
    window_s: float,
) -> Figure:
    """Raw output (top) and the residual of every method (bottom), all as ``window_s``
    averages (whole blocks) of the ``block_s`` series ``(label, values, colour)`` at ``t``."""
    from gyrolab.numerics.averaging import block_means

    def means(x: np.ndarray) -> np.ndarray:
        return block_means(np.asarray(x[: t.size], float), 1.0 / block_s, window_s)

    fig = _figure(9.0, 5.0)
    top, bot = fig.subplots(2, 1, sharex=True, height_ratios=[1, 1.4])
    th = _hours(means(t))
    for label, x, color in series:
        xm = means(x)
        ax = top if label == "raw" else bot
        lw = 1.2 if label.startswith("causal") else 0.8
        ax.plot(th, xm, color=color, lw=lw, label=label)
    below = [label for label, _x, _c in series if label != "raw"]
    top.set_ylabel("raw (°/s)")
    bot.set_ylabel("compensated (°/s)")
    bot.set_xlabel("time since power-on (h)")
    for ax in (top, bot):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="best")
    # the title names exactly what is drawn (no oracle where none is known)
    title = f"{window_s:g} s averages. Top: raw. Bottom: " + "; ".join(below)
    top.set_title(textwrap.fill(title, 120), fontsize=8.5)
    return fig


def plateau_noise(
    temp_c: np.ndarray,
    arw: np.ndarray,
    bi: np.ndarray,
    bi_lo: np.ndarray,
    bi_hi: np.ndarray,
) -> Figure:
    """ARW (°/√h) and bias instability (°/h, bars: its interval) of each soaked step
    against the step's mean PT100 temperature (°C)."""
    fig = _figure(8.0, 3.2)
    ax1, ax2 = fig.subplots(1, 2)
    ax1.plot(temp_c, arw, "o", color="#1f77b4")
    ax1.set_xlabel("PT100 (°C)")
    ax1.set_ylabel("ARW (°/√h)")
    ax1.set_ylim(bottom=0.0)  # the spread read against the level, not magnified
    b = np.asarray(bi, dtype=float)
    err = np.array([b - np.asarray(bi_lo, float), np.asarray(bi_hi, float) - b])
    ax2.errorbar(temp_c, b, yerr=np.where(np.isfinite(err), err, 0.0), fmt="o", color="#d62728")
    ax2.set_xlabel("PT100 (°C)")
    ax2.set_ylabel("bias instability (°/h)")
    for ax in (ax1, ax2):
        ax.grid(True, alpha=0.3)
    return fig
