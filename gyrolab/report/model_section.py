"""The report's compensation-model section: GPSO search, VMD modes, MPE classes, drift
fit, compensated output (paper Figs 10–14), laid out from a
:class:`~gyrolab.report.analysis.ModelRun` (no computation here)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from gyrolab.report import figures as F
from gyrolab.report.analysis import ModelRun
from gyrolab.report.data import CAUSAL_LABEL, offline_label
from gyrolab.report.document import FigureBlock, Section, TextBlock


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


def model_section(mr: ModelRun) -> Section:
    sec = Section("model", "Compensation model (GPSO-VMD, MPE, FLP, GA-BP)")
    model, res, held_out = mr.model, mr.results, mr.held_out
    d = model.diagnostics
    names = {i: c for c, idx in res.classes.items() for i in idx}
    classes = [names.get(i, "?") for i in range(res.K)]
    sec.blocks.append(
        TextBlock(
            f"VMD parameters K = {model.K}, α = {model.alpha:.0f}; IMF classes by mean MPE: "
            + "; ".join(
                f"{c}: {', '.join(f'IMF{i + 1}' for i in res.classes.get(c, [])) or 'none'}"
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
            F.vmd_modes(res.t, res.modes, classes, res.mpe),
            "The averaged output of this run decomposed by VMD with the model's (K, α); each "
            "mode is coloured by its MPE class (red noise, orange mixed, blue drift) "
            "(paper Fig. 11).",
        )
    )
    cfg = model.config
    fallback = [i for i in res.classes.get("drift", []) if res.mpe[i] > cfg.mpe_drift_max]
    mpe_caption = (
        f"Mean multiscale permutation entropy (scales 1–{cfg.mpe_scale}) of each "
        f"mode; noise ≥ {cfg.mpe_noise_min}, drift ≤ {cfg.mpe_drift_max} "
    )
    if fallback:
        mpe_caption += (
            "— no mode fell under the drift threshold, so the most regular one, "
            + ", ".join(f"IMF{i + 1} (MPE {res.mpe[i]:.3f})" for i in fallback)
            + ", is taken as the drift (the pipeline's fallback, hatched) "
        )
    sec.blocks.append(
        FigureBlock(
            "mpe",
            "MPE classification",
            F.mpe_classes(res.mpe, classes, cfg.mpe_drift_max, cfg.mpe_noise_min),
            mpe_caption + "(paper Fig. 12).",
        )
    )
    sec.blocks.append(
        FigureBlock(
            "drift-fit",
            "Drift model fit",
            F.drift_fit(res.t, res.part("drift"), res.series["drift_prediction"], res.temp),
            "Drift modes of this run and the GA-BP model's prediction from the PT100 temperature "
            + ("(held out: the model never saw this run)" if held_out else "(calibration run)")
            + " (paper Fig. 13).",
        )
    )
    offline = offline_label(mr.metrics)
    sec.blocks.append(
        FigureBlock(
            "compensated",
            f"The paper's {offline} against raw",
            F.compensated(
                res.t,
                res.series["raw"],
                res.series["compensated"],
                title=f"Raw and the {offline}",
                label=offline,
                color=F.OFFLINE_COLOR,
            ),
            "Raw output and the paper's offline reconstruction (noise modes removed, mixed "
            "modes filtered, temperature drift subtracted): low-passed and offline, not the "
            f"compensated output the gyro delivers (that is the {CAUSAL_LABEL}, in the "
            "headline) (paper Fig. 14).",
        )
    )
    return sec
