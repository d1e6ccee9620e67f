"""Where every number of the report comes from: the layers below, never the report.

The only module of :mod:`gyrolab.report` that calls :mod:`gyrolab.compensation`. With a
model, what ``gyrolab compensate`` computed on this run (its calibration run, or its
``--validate`` run) is read from the model directory — ``metrics.json`` and the results
files of :mod:`gyrolab.compensation.results` — and nothing is applied again. For any
other run, or a model directory written before the results were kept, the model is
applied here (the same calls ``compensate`` makes) and :attr:`ModelRun.computed` says
why, so the document can say so. Without a model: the raw averages, their metrics and
Allan curve, and the noise per temperature plateau, all from the recording.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

# the report's Allan curves are compensation.results' own (re-exported, not wrapped)
from gyrolab.compensation.results import RunResults
from gyrolab.compensation.results import allan_summary as allan_summary
from gyrolab.errors import InputError
from gyrolab.record.reader import Recording

#: metrics.json keys of ``compensate`` that describe the fit, not this run's report.
COMPENSATE_ONLY = ("calibration", "timing_s", "timing_breakdown_s")


@dataclass
class ModelRun:
    """A model and its application to the report's run.

    ``results``: the series, modes and Allan curves of the run; ``metrics``: its
    metrics.json content (docs/cli.md keys); ``computed``: ``""`` when both were read from
    the model directory, else the sentence saying why the report applied the model."""

    model: Any  # gyrolab.compensation.fit.CompensationModel
    model_dir: str
    results: RunResults
    metrics: dict[str, Any]
    held_out: bool
    computed: str = ""


def hysteresis(model: Any) -> dict[str, float] | None:
    """The up/down hysteresis width of the model's causal drift model (heating − cooling
    branch at the low end, middle and high end of its calibrated range, °/h:
    :func:`gyrolab.compensation.causal_models.hysteresis_width`); ``None`` without one."""
    causal = getattr(model, "causal", None)
    if causal is None:
        return None
    from gyrolab.compensation.causal_models import hysteresis_width

    return hysteresis_width(causal.model)


def paper_block_s() -> float:
    """The averaging time of a report without a model (the paper's 1000 points/h)."""
    from gyrolab.numerics.averaging import PAPER_BLOCK_S

    return float(PAPER_BLOCK_S)


def block_averages(rec: Recording, block_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The rate averaged over ``block_s`` (the samples themselves for a shorter run)."""
    from gyrolab.numerics.averaging import block_average

    rate = rec.require_rate()
    x = np.asarray(rate.values, dtype=float)
    if rate.t.size and (rate.t[-1] - rate.t[0]) >= 2 * block_s:
        tb, xb, _ = block_average(rate.t, x, block_s, rate.period)
        return tb, xb
    return rate.t, x


def raw_metrics(xb: np.ndarray, block_s: float, keys: list[str]) -> dict[str, Any]:
    """The five metrics (docs/cli.md) of the averaged raw output (NaN when too short)."""
    from gyrolab.compensation.evaluate import series_metrics

    try:
        return series_metrics(xb, block_s)
    except InputError:
        return {k: float("nan") for k in keys}


def plateau_rows(rec: Recording) -> list[Any]:
    """ARW and bias instability of every soaked step (:mod:`.plateau_noise`)."""
    from gyrolab.compensation.plateau_noise import plateau_noise

    return plateau_noise(rec)


def range_note(metrics: dict[str, Any]) -> str:
    """The sentences for a run outside the model's calibrated range, for one whose
    temperature source is not the model's and for another unit's run ('' when none)."""
    rng = metrics.get("temperature") or {}
    from gyrolab.compensation.guards import range_warning, source_warning, unit_warning

    name = Path(str(metrics.get("run", "this run"))).name
    notes = []
    if rng.get("outside_calibration_range"):
        line = range_warning(name, rng) or ""
        notes.append(line.replace("warning: ", "Outside the calibrated range — ", 1))
    line = source_warning(name, rng)
    if line:
        notes.append(line.replace("warning: ", "Another temperature source — ", 1) + ".")
    line = unit_warning(name, rng)
    if line:
        notes.append(line.replace("warning: ", "Another unit — ", 1) + ".")
    return " ".join(notes)


def warn_source(metrics: dict[str, Any]) -> None:
    """The stderr lines of a run whose temperature source or unit is not the model's."""
    from gyrolab.compensation.guards import source_warning, unit_warning

    name, rng = str(metrics.get("run", "this run")), metrics.get("temperature") or {}
    for line in (source_warning(name, rng), unit_warning(name, rng)):
        if line:
            print(line, file=sys.stderr)


def firmware_note(metrics: dict[str, Any]) -> str:
    """What the firmware cubic costs against the chosen output ('' without one)."""
    if "firmware_poly3" not in metrics:
        return ""
    from gyrolab.compensation.firmware import firmware_sentence

    return firmware_sentence(metrics)


def model_run(
    model_dir: str | Path, model: Any, rec: Recording, label: str | None = None
) -> ModelRun:
    """The model on ``rec``: read from ``model_dir`` when ``compensate`` evaluated this
    run (same content hash of the rate and PT100 data), else applied here. ``label``: how
    the metrics name the run (default: its path as given)."""
    from gyrolab.compensation.model_dir import ModelDir
    from gyrolab.compensation.prepare import prepare_run

    run = prepare_run(rec, model.config)  # checks the run and hashes its data
    run.label = label or ""
    md = ModelDir(model_dir)
    stored = md.results()
    match = next(
        (r for r in stored.values() if r.content_hash and r.content_hash == run.content_hash),
        None,
    )
    metrics = None if match is None else md.run_metrics(match.role)
    if match is not None and metrics is not None:
        m = {k: v for k, v in metrics.items() if k not in COMPENSATE_ONLY}
        m["run"] = run.name
        m["calibration_run"] = model.calibration.get("path")
        m["model_timing_s"] = metrics.get("timing_breakdown_s", model.timing_s)
        m["model_results"] = "model_dir"  # docs/cli.md: read, not recomputed
        out = ModelRun(model, str(model_dir), match, m, match.held_out)
        if model.causal is not None and not match.oracle_checked:
            _add_oracle(out, rec)
        return out
    if not stored:
        why = (
            f"{Path(model_dir).name} holds no results of gyrolab compensate (written before "
            "they were kept)"
        )
    elif is_calibration_run(model, run):
        why = (
            "the causal model was also fitted on this run (compensate --also), whose "
            "results compensate does not keep"
        )
    else:
        why = "this run is neither the model's calibration run nor its --validate run"
    return _apply(model_dir, model, run, rec, why)


def _apply(model_dir: str | Path, model: Any, run: Any, rec: Recording, why: str) -> ModelRun:
    """Apply the model to the run as ``compensate`` does (fixed K and α, no search)."""
    from gyrolab.compensation.apply import compensate_offline
    from gyrolab.compensation.evaluate import add_firmware_metrics, evaluate
    from gyrolab.compensation.model_dir import ModelDir
    from gyrolab.compensation.results import run_results

    held_out = not is_calibration_run(model, run)
    app = compensate_offline(model, run)
    metrics = evaluate(model, app, run, held_out=held_out)
    metrics["calibration_run"] = model.calibration.get("path")
    add_firmware_metrics(ModelDir(model_dir).firmware(), run, metrics)
    metrics["model_timing_s"] = model.timing_s
    metrics["model_results"] = "computed"
    res = run_results("report", model, app, run, held_out)
    out = ModelRun(
        model,
        str(model_dir),
        res,
        metrics,
        held_out,
        computed=f"The model was applied to this run by the report: {why}.",
    )
    if model.causal is not None:
        _add_oracle(out, rec)
    return out


def _add_oracle(mr: ModelRun, rec: Recording) -> None:
    """The oracle of a simulated run (true drift removed), where compensate did not look
    for it: its block means in the results, its metrics and 100 s p-p in the metrics."""
    from gyrolab.compensation.evaluate import drift_pp_table, series_metrics
    from gyrolab.compensation.oracle import oracle_block_means
    from gyrolab.compensation.results import keep_oracle

    bs = mr.results.block_s
    ob = oracle_block_means(rec, bs)
    if ob is not None:
        ob = ob[: mr.results.t.size]
        mr.metrics["oracle"] = series_metrics(ob, bs)
        mr.metrics.setdefault("drift_pp_100s_deg_per_s", {}).update(
            drift_pp_table({"oracle": ob}, bs)
        )
    keep_oracle(mr.results, ob)


def is_calibration_run(model: Any, run: Any) -> bool:
    """True when ``run`` is a run the model was fitted on — its calibration run, or one of
    the runs its causal model was also fitted on (``compensate --also``) —: same content
    hash of the rate and temperature data (models that record it), else the same
    averaged series."""
    digest = model.calibration.get("content_hash")
    if digest and getattr(run, "content_hash", ""):
        also = {a.get("content_hash") for a in model.calibration.get("also", [])}
        return bool(run.content_hash == digest or run.content_hash in also)
    cal = model.diagnostics.get("calib_rate")
    if cal is None:
        return Path(str(model.calibration.get("path", ""))).resolve() == Path(run.path).resolve()
    cal = np.asarray(cal, dtype=float)
    return cal.shape == run.rate.shape and bool(np.allclose(cal, run.rate, rtol=0, atol=1e-12))
