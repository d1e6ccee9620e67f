"""The exported model: a versioned, self-contained JSON description of a fitted model.

``gyrolab export MODEL_DIR --format json`` writes it; the C exporter (:mod:`.c_code`) is
generated from it, so what the JSON says is what the C computes. Schema
``gyrolab.export`` version 1 (docs/export.md has the full reference)::

    {
      "format": "gyrolab.export", "format_version": 1,
      "software_version": ..., "created_utc": ..., "model_dir": ...,
      "units": {"rate": "deg/s", "temperature": "degC", "time": "s"},
      "correction": "y(t) = raw(t) - f(inputs(t))",
      "temperature_input": "zero-order hold: the last temperature reading at or before t",
      "axes": [{"axis": "x", "calibration_range_c": [lo, hi], "model": MODEL}, ...]
    }

``MODEL`` is the axis's drift model in its own exported form
(:meth:`~gyrolab.compensation.drift_model.DriftModel.spec`), a dict whose ``kind``
names its registered :class:`~gyrolab.compensation.drift_model.SpecKind`
(:mod:`gyrolab.compensation.families`): the reference evaluation :func:`evaluate` and
the C of :mod:`.c_code` come from that kind. The built-in kinds:

* ``mlp``, ``legendre``, ``poly3`` — the eq. 15–17 network of GA-BP / BP, the polynomial
  baseline and the firmware cubic on ``inputs`` ``["T"]`` or ``["T", "dTdt"]``
  (:mod:`gyrolab.compensation.temperature_model`; the equations in
  :mod:`gyrolab.compensation.regressors`);
* ``causal`` — ``{"kind": "causal", "family", "features": {"tau_s", "rate_tau_min_s",
  "width_c", "warmup_tau_s"[, "start_branch"][, "self_heating_c"][, "width_temp_per_c"]
  [, "die_heating_c"]}, "model": INNER}`` (``start_branch``, the play's branch at
  power-on, ``self_heating_c``, the die's self-heating the play follows,
  ``width_temp_per_c``, the play width's change per °C, and ``die_heating_c``, the
  die's own self-heating every term sees, only when not 0), the causal families of
  :mod:`gyrolab.compensation.causal_models`: a state machine run at every temperature
  reading (:func:`~gyrolab.compensation.causal_models.causal_readings` states its
  equations) gives the features F (die temperature), R (its rate), S (hysteresis branch),
  E (warm-up); ``INNER`` (a ``structured`` or an ``mlp`` form on ``["F", "R", "S",
  "E"]``) maps them to the drift, held until the next reading.

dT/dt, when a model uses it, is ``(T(t) − T(t − w)) / w`` with both temperatures taken by
the same zero-order hold (the first reading when ``t − w`` precedes it).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from gyrolab import __version__
from gyrolab.errors import InputError

EXPORT_FORMAT = "gyrolab.export"
EXPORT_FORMAT_VERSION = 1
KINDS = ("chosen", "causal", "gabp", "bp", "poly", "poly3")


def model_spec(model_dir: str | Path, kind: str = "chosen") -> dict[str, Any]:
    """The ``MODEL`` entry of one axis's model directory: the drift model ``kind`` names
    — ``chosen`` (the causal model when the directory has one, else GA-BP), ``causal``,
    ``gabp``, ``bp`` or ``poly`` (the baselines) or ``poly3`` (the firmware cubic) — in
    its own exported form (:meth:`~gyrolab.compensation.drift_model.DriftModel.spec`); a
    model without one is refused in one line."""
    from gyrolab.compensation.model_dir import ModelDir

    return _axis(ModelDir(model_dir), kind)[1]


def _axis(md: Any, kind: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """``(calibration summary, MODEL)`` of one axis's model directory ``md``."""
    from gyrolab.compensation.drift_model import NotExportable
    from gyrolab.compensation.temperature_model import TemperatureModel

    model = md.load()
    try:
        if kind == "poly3":
            drift: Any = TemperatureModel(md.require_firmware(), family="poly3")
        else:
            drift = model.drift_model(kind)
        return model.calibration, drift.spec()
    except NotExportable as e:
        raise InputError(md.path, f"not exportable: {e}") from None
    except ValueError as e:
        raise InputError(md.path, str(e)) from None


def export_spec(model_dir: str | Path, kind: str = "chosen") -> dict[str, Any]:
    """The whole JSON document for every axis of ``model_dir``."""
    from gyrolab.compensation.model_dir import ModelDir

    axes = []
    for name, d in ModelDir(model_dir).axes():
        cal, spec = _axis(d, kind)
        axes.append(
            {
                "axis": name,
                "calibration_range_c": [cal.get("temp_min_c"), cal.get("temp_max_c")],
                "calibration_run": cal.get("path"),
                "model": spec,
            }
        )
    return {
        "format": EXPORT_FORMAT,
        "format_version": EXPORT_FORMAT_VERSION,
        "software_version": __version__,
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "model_dir": str(model_dir),
        "model_kind": kind,
        "units": {"rate": "deg/s", "temperature": "degC", "time": "s"},
        "correction": "y(t) = raw(t) - f(inputs(t))",
        "temperature_input": "zero-order hold: the last temperature reading at or before t "
        "(the first reading before it)",
        "axes": axes,
    }


# ------------------------------------------------------------ reference evaluation


def evaluate(
    model: dict[str, Any], t: np.ndarray, pt_t: np.ndarray, pt_c: np.ndarray
) -> np.ndarray:
    """The drift (°/s, float64) of one axis's exported ``MODEL`` at sample times ``t``
    from temperature readings ``pt_t`` (s), ``pt_c`` (°C): the JSON's own reference
    evaluation (its kind's, :mod:`gyrolab.compensation.families`), independent of the
    fitted model (the tests compare the two, and the compiled C with both)."""
    from gyrolab.compensation.families import spec_kind

    return spec_kind(model["kind"]).evaluate(model, np.asarray(t, dtype=float), pt_t, pt_c)
