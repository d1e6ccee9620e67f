"""What ``gyrolab compensate`` and ``gyrolab apply`` do (the contract in docs/cli.md), as
library calls with keyword arguments; :mod:`gyrolab.app.compensate` calls them.

:func:`compensate` (``gyrolab compensate RUN.mcap --out MODEL_DIR [--validate
OTHER.mcap]``) fits the hybrid model of :mod:`gyrolab.compensation.fit` on RUN and writes
MODEL_DIR (layout in
:mod:`gyrolab.compensation.model_dir`) with ``metrics.json``. With ``--validate`` the
top-level metrics are those of OTHER (``"held_out": true``) and the calibration run's own
metrics sit under ``"calibration"``; without it they are RUN's (``"held_out": false``).

:func:`apply` (``gyrolab apply``) is :mod:`gyrolab.compensation.apply_command`'s.

Every input is checked before anything is written; bad input is one line and exit 2.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from typing import Any

from gyrolab.compensation.apply import compensate_offline
from gyrolab.compensation.axis_runs import load_runs
from gyrolab.compensation.config import DEFAULT_CONFIG, PipelineConfig, resolve_config
from gyrolab.compensation.evaluate import add_firmware_metrics, evaluate
from gyrolab.compensation.firmware import fit_poly3
from gyrolab.compensation.fit import fit
from gyrolab.compensation.guards import (
    check_also_prior,
    check_not_calibration,
    warn_outside,
)
from gyrolab.compensation.model_dir import ModelDir
from gyrolab.compensation.oracle import add_oracle
from gyrolab.compensation.prepare import PreparedRun
from gyrolab.compensation.results import keep_oracle, run_results
from gyrolab.errors import InputError, named
from gyrolab.outputs import atomic_dir, check_output
from gyrolab.record.reader import list_units, read_metadata, select_unit

#: What :func:`compensate` reports to its ``on_stage`` as each is done (batch's progress).
STAGES = ("read", "fit", "write")
TOPIC_RATE_RAW = "/gyro/rate_raw"
TOPIC_RATE_OFFLINE = "/gyro/rate_offline"


def _prior_lines(cm: dict[str, Any]) -> list[str]:
    """The fleet prior's line (a MAP fit) and the up/down hysteresis width of a
    structured model with a hysteresis term."""
    from gyrolab.compensation.causal_models import hysteresis_width
    from gyrolab.compensation.structured import StructuredModel

    out = []
    pr = cm.get("selection", {}).get("prior")
    if pr:
        mem = pr["membership"]
        out.append(
            f"  fleet prior: {pr['prior_units']} units, cluster {pr['cluster']} of "
            f"{pr['cluster_units']}; this unit's distance d2 = {mem['mahalanobis_d2']:.1f} on "
            f"{mem['dof']} parameters (p = {mem['p_value']:.2g}): belongs"
        )
    st = cm.get("structured")
    if st and (st.get("h") or st.get("hT")):
        w = hysteresis_width(StructuredModel.from_dict(st))
        out.append(
            "  hysteresis width (heating - cooling branch): "
            f"{w['at_low_deg_per_h']:+.3g} / {w['at_mid_deg_per_h']:+.3g} / "
            f"{w['at_high_deg_per_h']:+.3g} deg/h at the low end / middle / high end"
        )
    return out


def _summary(m: dict[str, Any]) -> str:
    r, c = m["raw"], m["compensated"]

    def pct(a: float, b: float) -> str:
        return f"{100.0 * (1.0 - b / a):.1f} %" if a else "n/a"

    tag = "held out" if m["held_out"] else "calibration (in sample)"
    lines = [f"{m['run']} [{tag}]"]
    if "causal" in m:
        # the headline: the causal full-bandwidth output, the floor beside it when known
        pp = m.get("drift_pp_100s_deg_per_s", {})
        cz, fam = m["causal"], m["causal_model"]["family"]
        lines.append(
            f"  CAUSAL ({fam}, full bandwidth): bias stab. {r['bias_stability_deg_per_h']:.4g} -> "
            f"{cz['bias_stability_deg_per_h']:.4g} deg/h "
            f"({pct(r['bias_stability_deg_per_h'], cz['bias_stability_deg_per_h'])} less); "
            f"drift p-p (100 s) {pp.get('raw', float('nan')):.4g} -> "
            f"{pp.get('causal', float('nan')):.4g} deg/s "
            f"({pct(pp.get('raw', 0.0), pp.get('causal', 0.0))} less)"
        )
        if m.get("causal_also"):
            lines.append(
                "  causal model fitted on the calibration run and, each from its own "
                f"power-on, {', '.join(m['causal_also'])}"
            )
        lines += _prior_lines(m["causal_model"])
        mb = m.get("headline", {}).get("mean_bias_deg_per_h")
        band = m.get("causal_band")
        if mb is not None:
            lines.append(
                f"  residual mean bias {mb:+.3g} deg/h (raw "
                f"{m['residual_mean_bias_deg_per_h']['raw']:+.4g})"
                + (
                    f"; 90 % band of 100 s means +/-{band['mean_half_width_deg_per_s']:.3g}"
                    f" deg/s (in range {band['half_width_inside_deg_per_s']:.3g}; covers "
                    f"{100 * (band['coverage_100s'] or 0):.0f} % here); expected error "
                    f"{band['expected_error']['grade']}"
                    if band
                    else ""
                )
            )
        if "oracle" in m:
            lines.append(
                f"  oracle (true drift removed): bias stab. "
                f"{m['oracle']['bias_stability_deg_per_h']:.4g} deg/h, drift p-p (100 s) "
                f"{pp.get('oracle', float('nan')):.4g} deg/s"
            )
    # IMFs counted from 1, as the report names them
    classes = "; ".join(
        f"{c}: {', '.join(f'IMF{i + 1}' for i in m['imf_classes'].get(c, [])) or 'none'}"
        for c in ("noise", "mixed", "drift")
    )
    lines += [
        f"  paper's method (offline, low-passed): VMD K={m['vmd']['K']} "
        f"alpha={m['vmd']['alpha']:.0f}  classes {classes}",
        f"  drift p-p    {r['drift_pp_deg_per_s']:.4g} -> {c['drift_pp_deg_per_s']:.4g} deg/s "
        f"({pct(r['drift_pp_deg_per_s'], c['drift_pp_deg_per_s'])} less)",
        f"  bias stab.   {r['bias_stability_deg_per_h']:.4g} -> "
        f"{c['bias_stability_deg_per_h']:.4g} deg/h "
        f"({pct(r['bias_stability_deg_per_h'], c['bias_stability_deg_per_h'])} less)",
        f"  ARW          {r['arw_deg_per_sqrt_h']:.4g} -> {c['arw_deg_per_sqrt_h']:.4g} deg/rt(h)"
        f" (without noise removal {m['compensated_drift_only']['arw_deg_per_sqrt_h']:.4g})",
    ]
    for key, name in (("firmware_px4", "PX4"), ("firmware_ardupilot", "ArduPilot")):
        fw = m.get(key)
        if fw:
            lines.append(
                f"  firmware cubic as {name} runs it: drift p-p "
                f"{fw['drift_pp_deg_per_s']:.4g} deg/s, "
                f"{fw['vs_chosen']['drift_pp_deg_per_s_ratio']:.3g}x the chosen causal output's"
            )
    ext = m.get("baselines_extrapolation", {})
    for name, b in m["baselines"].items():
        e = ext.get(name, {})
        lines.append(
            f"  baseline {name:<4} drift p-p {b['drift_pp_deg_per_s']:.4g} deg/s, "
            f"bias stab. {b['bias_stability_deg_per_h']:.4g} deg/h"
            + (
                f" (EXTRAPOLATING: {100 * e['fraction_outside_temperature']:.1f} % of the "
                f"points up to {e['max_beyond_c']:.1f} degC beyond its calibrated range)"
                if e.get("extrapolating")
                else ""
            )
        )
    return "\n".join(lines)


def compensate(
    run_path: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    validate: str | os.PathLike[str] | None = None,
    config: str | os.PathLike[str] | None = None,
    seed: int | None = None,
    unit: str | None = None,
    log_options: dict[str, Any] | None = None,
    force: bool = False,
    run_label: str = "",
    validate_label: str = "",
    base_config: PipelineConfig | None = None,
    on_stage: Callable[[str], None] | None = None,
    prior: Any = None,
    also: Sequence[str | os.PathLike[str]] = (),
) -> str:
    """Fit on ``run_path``, optionally evaluate on ``validate``, write ``out``; returns
    the summary the command prints (one block per axis, the calibration run's after the
    held-out one's).

    ``config`` is a CONFIG.toml over ``base_config`` (default :data:`DEFAULT_CONFIG`; batch
    passes its own), its seed overridden by ``seed``. ``unit`` picks one unit of a
    multi-unit recording. A run with several axes (or a foreign log, :mod:`gyrolab.logs`,
    read with ``log_options``) gets one model per axis in one directory
    (:mod:`gyrolab.compensation.axis_runs`). The outputs name the runs as given, or by
    ``run_label``/``validate_label`` (:mod:`gyrolab.app.demo`: paths relative to its
    output directory). ``prior``: a fleet prior
    (:class:`~gyrolab.compensation.prior.FleetPrior`) for the causal model's MAP fit
    (every axis against the same prior). ``on_stage(name)`` is told each of
    :data:`STAGES` as it is done. ``also``: further calibration recordings of the same
    unit, each from its own power-on (a cold start, say): the causal model is fitted on
    the main run and these joined (:func:`also_runs`); the paper's method and the
    baselines on the main run alone."""
    t_start = time.perf_counter()
    stage = on_stage or (lambda _name: None)
    run_s, val_s = str(run_path), None if validate is None else str(validate)
    also_s = [str(a) for a in also]
    inputs = (run_s, val_s, config, *also_s)
    check_output(out, force, inputs=inputs, kind="dir")
    check_also_prior(also_s, prior)
    cfg, seed = resolve_config(config, base_config or DEFAULT_CONFIG, seed)
    if unit is None and units_of(run_s):
        # every unit of a multi-unit run is the fan-out of gyrolab.app.compensate (above
        # this layer: it runs this function once per unit through gyrolab.batch)
        raise InputError(run_s, f"holds units {', '.join(units_of(run_s))}: choose one with --unit")
    opts = log_options or {}
    unit_arg = unit
    unit = select_unit(run_s, unit_arg) if unit_arg is not None or units_of(run_s) else None
    vunit = None
    if val_s and unit is not None:  # the same unit of a multi-unit held-out run
        vunit = select_unit(val_s, unit if units_of(val_s) else None)
    if unit is not None:  # one unit of a multi-unit recording (1–3 axes)
        runs = load_runs(run_s, cfg, unit=unit)
    else:
        runs = load_runs(run_s, cfg, **opts)
    if vunit is not None:
        vals = load_runs(val_s, cfg, unit=vunit)
    else:
        vals = load_runs(val_s, cfg, **opts) if val_s else None
    if vals is not None and len(vals) != len(runs):
        raise InputError(val_s, f"has {len(vals)} axes but the calibration run has {len(runs)}")
    for run, val in zip(runs, vals or [], strict=False):
        check_not_calibration(val_s, val.content_hash, run.content_hash)
    serial = unit or recording_serial(run_s)
    extra = also_runs(also_s, runs, vals, val_s, cfg, unit, serial, opts)
    # how the outputs name the runs: an app's stable labels, else the paths as given
    for prepared, label in ((runs, run_label), (vals or [], validate_label)):
        for r in prepared:
            r.label = label
    # the serial each model and its metrics belong to (docs/fleet.md): the unit of a
    # multi-unit recording, else the one the recording's run metadata names
    vserial = (vunit or recording_serial(val_s)) if val_s else serial
    t_read = time.perf_counter() - t_start
    stage("read")
    fitted = []
    for k, run in enumerate(runs):
        t_axis = time.perf_counter()
        val = None if vals is None else vals[k]
        fitted.append(_fit_axis(val_s, cfg, run, val, seed, prior, [a[k] for a in extra]))
        total = (t_read if k == 0 else 0.0) + time.perf_counter() - t_axis
        model, metrics, metrics_cal, _results = fitted[-1]
        metrics["timing_s"] = total
        metrics["timing_breakdown_s"] = {"read": t_read, **model.timing_s, "total": total}
        model.timing_s = metrics["timing_breakdown_s"]
        if serial:  # the unit the model belongs to (docs/fleet.md)
            model.calibration["unit"] = serial
            metrics_cal["unit"] = serial
        if vserial:
            metrics["unit"] = vserial
    if len(runs) == 1:
        # the floor beside the headline, where the truth is known (gyrolab simulate runs)
        _model, metrics, metrics_cal, results = fitted[0]
        ob = add_oracle(metrics, val_s or run_s, cfg.block_s, vunit if vals else unit)
        keep_oracle(results[-1], ob)
        if vals is not None:
            keep_oracle(results[0], add_oracle(metrics_cal, run_s, cfg.block_s, unit))
    stage("fit")
    with atomic_dir(out, force, command="compensate", inputs=inputs) as tmp:
        md = ModelDir(tmp)
        if len(runs) == 1:
            _write_axis(md, *fitted[0])
        else:
            for k, f in enumerate(fitted):
                _write_axis(md.new_axis(k), *f)
            md.write_head(len(runs), [f[1] for f in fitted])
    stage("write")
    lines = []
    for k, (_model, metrics, metrics_cal, _res) in enumerate(fitted):
        if len(runs) > 1:
            lines.append(f"axis {'xyz'[k]}:")
        lines.append(_summary(metrics))
        if vals is not None:
            lines.append(_summary(metrics_cal))
    return "\n".join(lines)


def _fit_axis(
    validate: str | None,
    cfg: PipelineConfig,
    run: PreparedRun,
    val: PreparedRun | None,
    seed: int = 0,
    prior: Any = None,
    also: Sequence[PreparedRun] = (),
) -> tuple[Any, ...]:
    """Fit one axis → ``(model, metrics, calibration metrics, results)``: the metrics
    (held-out when ``val``) with the firmware cubic's cost, and what the report reads of
    each evaluated run (:mod:`gyrolab.compensation.results`); ``also``: the axis's further
    calibration runs (the causal model's)."""
    with named(run.path):
        model, dec = fit(run, cfg, seed=seed, prior=prior, also=also)
        app = compensate_offline(model, run, dec)
        metrics_cal = evaluate(model, app, run, held_out=False)
        p3 = fit_poly3(run)
        add_firmware_metrics(p3, run, metrics_cal, cfg.block_s)
        results = [run_results("calibration", model, app, run, held_out=False)]
    if val is not None:
        with named(val.path):
            app_val = compensate_offline(model, val)
            metrics = evaluate(model, app_val, val, held_out=True)
            add_firmware_metrics(p3, val, metrics, cfg.block_s)
            results.append(run_results("validation", model, app_val, val, held_out=True))
        metrics["calibration"] = metrics_cal
        warn_outside(validate, metrics.get("temperature", {}))
    else:
        metrics = metrics_cal
    if also:  # what the summary names beside the causal headline
        metrics["causal_also"] = metrics_cal["causal_also"] = [a.name for a in also]
    model.firmware_poly3 = p3  # type: ignore[attr-defined]
    return model, metrics, metrics_cal, results


def _write_axis(
    out: ModelDir, model: Any, metrics: dict[str, Any], _cal: Any, results: list[Any]
) -> None:
    out.write_model(model)
    out.write_metrics(metrics)
    out.write_firmware(model.firmware_poly3)
    out.write_results(results)


def also_runs(
    paths: Sequence[str],
    runs: list[PreparedRun],
    vals: list[PreparedRun] | None,
    val_s: str | None,
    cfg: PipelineConfig,
    unit: str | None,
    serial: str | None,
    log_options: dict[str, Any],
) -> list[list[PreparedRun]]:
    """``compensate --also``: each further calibration recording prepared axis by axis
    (the same ``unit`` of a multi-unit one). Refused, one line naming the file: another
    number of axes, another unit (the serials its metadata and the main run's name), another
    temperature source, or the data of the main run, of an earlier ``--also`` or of the
    held-out run."""
    out: list[list[PreparedRun]] = []
    seen = {r.content_hash for r in runs}
    for path in paths:
        aunit = select_unit(path, unit if units_of(path) else None) if unit is not None else None
        if aunit is not None:
            got = load_runs(path, cfg, unit=aunit)
        else:
            got = load_runs(path, cfg, **log_options)
        if len(got) != len(runs):
            raise InputError(path, f"has {len(got)} axes but the calibration run has {len(runs)}")
        other = aunit or recording_serial(path)
        if serial and other and other != serial:
            raise InputError(
                path, f"is unit {other}, the calibration run unit {serial}: --also is the same unit"
            )
        for a, r in zip(got, runs, strict=True):
            if a.content_hash in seen:
                raise InputError(
                    path,
                    "has the same rate and temperature data as a calibration run already "
                    "given: --also needs another power-on's run",
                )
            seen.add(a.content_hash)
            if a.temperature_source != r.temperature_source:
                raise InputError(
                    path,
                    f"reads temperature from {a.temperature_source}, the calibration run "
                    f"from {r.temperature_source}: one model has one temperature input",
                )
        for a, val in zip(got, vals or [], strict=False):
            check_not_calibration(str(val_s), val.content_hash, a.content_hash)
        out.append(got)
    return out


def recording_serial(path: str) -> str | None:
    """The unit serial a single-unit gyrolab recording's run metadata names (``None`` for
    none, or for a user's log, whose formats carry no serial)."""
    from gyrolab.logs import detect_format

    if detect_format(path) != "gyrolab":
        return None
    serial = read_metadata(path).get("run", {}).get("unit_serial")
    return str(serial) if serial else None


def units_of(path: str) -> list[str]:
    """The units of a multi-unit gyrolab recording; ``[]`` for anything else (a foreign log
    is not an MCAP: its reader says what is wrong with it)."""
    try:
        return list_units(path)
    except InputError:
        return []
