"""The fitted-model directory: a versioned, code-free on-disk format, and the
:class:`~gyrolab.compensation.fit.CompensationModel` written to it (:func:`save_model`)
and read back (:func:`load_model`).

Layout (``MODEL_FORMAT_VERSION`` 1)::

    MODEL_DIR/
      model.json         format name + version, software version, creation time, the
                         pipeline configuration, VMD (K, alpha), mode classes and MPE
                         values, FLP settings, every drift model's metadata (kind, scalers,
                         chosen order, ...), the calibration run's summary
      arrays.npz         every array, numpy ``.npz`` (read with ``allow_pickle=False``):
                         decimated calibration series, VMD modes and centre frequencies,
                         GPSO history, drift target and fit, network weights, polynomial
                         coefficients
      drift_gabp.pt      the GA-BP network as a ``torch.nn.Sequential`` state dict
      baseline_bp.pt     the plain-BP baseline, same form (both load with
                         ``torch.load(..., weights_only=True)``; the .npz is authoritative)
      metrics.json       written by ``gyrolab compensate`` (docs/cli.md keys)

Nothing is pickled: a model directory can be read by any numpy/JSON reader, and loading it
never runs code from the file. A directory whose ``format`` or ``format_version`` this
gyrolab does not know is refused with an :class:`~gyrolab.errors.InputError` (one line,
exit 2) rather than mis-read.
"""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from gyrolab import __version__
from gyrolab.compensation.baselines import PolyDriftModel
from gyrolab.compensation.causal import CausalDriftModel
from gyrolab.compensation.config import PipelineConfig
from gyrolab.compensation.fit import CompensationModel, DriftModel
from gyrolab.compensation.flp import ForwardLinearPredictor
from gyrolab.compensation.gabp import MLPDriftModel
from gyrolab.compensation.guards import check_finite
from gyrolab.errors import InputError
from gyrolab.outputs import json_safe

MODEL_FORMAT = "gyrolab.compensation-model"
MODEL_FORMAT_VERSION = 1
MODEL_JSON = "model.json"
ARRAYS_NPZ = "arrays.npz"


def write_json(path: str | os.PathLike[str], obj: Any) -> None:
    Path(path).write_text(json.dumps(json_safe(obj), indent=2, sort_keys=False) + "\n")


def save_model_dir(
    directory: str | os.PathLike[str],
    meta: dict[str, Any],
    arrays: dict[str, np.ndarray],
    torch_states: dict[str, dict[str, Any]] | None = None,
) -> None:
    """Write model.json, arrays.npz and the ``.pt`` state dicts into an existing directory
    (the caller makes it atomic with :func:`gyrolab.outputs.atomic_dir`)."""
    d = Path(directory)
    head = {
        "format": MODEL_FORMAT,
        "format_version": MODEL_FORMAT_VERSION,
        "software_version": __version__,
    }  # no clock readings: same inputs and seed give the same bytes (when: the dir's marker)
    write_json(d / MODEL_JSON, {**head, **meta})
    clean = {}
    for k, v in arrays.items():
        a = np.asarray(v)
        if a.dtype == object:
            raise TypeError(f"array {k!r} has dtype object; the model format stores no pickles")
        clean[k] = a
    np.savez_compressed(d / ARRAYS_NPZ, **clean)
    if torch_states:
        import torch  # heavy: imported only when a network is written

        for name, state in torch_states.items():
            torch.save(state, d / f"{name}.pt")


def load_model_dir(
    directory: str | os.PathLike[str],
) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Read and check a model directory → ``(meta, arrays)``.

    Raises :class:`InputError` naming the directory when it is missing, damaged, not a
    gyrolab model, or written in a format version this gyrolab does not read."""
    d = Path(directory)
    if not d.is_dir():
        raise InputError(d, "model directory not found")
    mj = d / MODEL_JSON
    if not mj.is_file():
        raise InputError(d, f"not a gyrolab model directory (no {MODEL_JSON})")
    try:
        meta = json.loads(mj.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise InputError(mj, f"damaged model file ({e.__class__.__name__})") from None
    if not isinstance(meta, dict) or meta.get("format") != MODEL_FORMAT:
        raise InputError(d, f"not a gyrolab compensation model (format {meta.get('format')!r})")
    if meta.get("axis_dirs"):
        raise InputError(
            d,
            f"a {len(meta['axis_dirs'])}-axis model: give one axis's directory "
            f"({', '.join(str(x) for x in meta['axis_dirs'])} inside it)",
        )
    ver = meta.get("format_version")
    if ver != MODEL_FORMAT_VERSION:
        raise InputError(
            d,
            f"model format version {ver} (written by gyrolab {meta.get('software_version')}); "
            f"this gyrolab {__version__} reads version {MODEL_FORMAT_VERSION} — refit with "
            "`gyrolab compensate`",
        )
    npz = d / ARRAYS_NPZ
    if not npz.is_file():
        raise InputError(d, f"model directory is missing {ARRAYS_NPZ}")
    try:
        with np.load(npz, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
        raise InputError(npz, f"damaged model arrays ({e.__class__.__name__})") from None
    return meta, arrays


def _drift_from_state(
    meta: dict[str, Any], arrays: dict[str, np.ndarray], prefix: str
) -> DriftModel:
    if meta["kind"] == "mlp":
        return MLPDriftModel.from_state(meta, arrays, prefix)
    if meta["kind"] == "poly":
        return PolyDriftModel.from_state(meta, arrays, prefix)
    raise ValueError(f"unknown drift model kind {meta['kind']!r}")


def save_model(model: CompensationModel, directory: str) -> None:
    """Write ``model`` into an existing directory (layout in the module docstring)."""
    arrays: dict[str, np.ndarray] = dict(model.diagnostics)
    cmeta = None
    if model.causal is not None:
        cmeta, carr = model.causal.to_state("causal.")
        arrays.update(carr)
    dmeta, darr = model.drift.to_state("drift.")
    arrays.update(darr)
    bmeta: dict[str, Any] = {}
    for name, m in model.baselines.items():
        meta, arr = m.to_state(f"baseline.{name}.")
        bmeta[name] = meta
        arrays.update(arr)
    meta = {
        "seed": model.seed,
        "config": model.config.to_dict(),
        "vmd": {"K": model.K, "alpha": model.alpha},
        "decomposition": model.decomposition_info,
        "drift_model": dmeta,
        "baselines": bmeta,
        "calibration": model.calibration,
        "flp": {
            "mixed": None if model.flp_mixed is None else model.flp_mixed.to_dict(),
            "stream": None if model.flp_stream is None else model.flp_stream.to_dict(),
        },
        "causal_model": cmeta,
        "streaming": {
            "temperature": "zero-order hold of the last PT100 reading",
            "dtdt": "backward difference over config.dtdt_window_s"
            if model.config.use_dtdt
            else None,
        },
    }
    torch_states = {}
    if isinstance(model.drift, MLPDriftModel):
        torch_states["drift_gabp"] = model.drift.torch_state_dict()
    bp = model.baselines.get("bp")
    if isinstance(bp, MLPDriftModel):
        torch_states["baseline_bp"] = bp.torch_state_dict()
    save_model_dir(directory, meta, arrays, torch_states)


def load_model(directory: str) -> CompensationModel:
    """Read a model directory written by :func:`save_model` (format checked)."""
    meta, arrays = load_model_dir(directory)
    try:
        check_finite(directory, meta, arrays)
        flp = meta.get("flp") or {}
        flp_mixed = flp.get("mixed")
        flp_stream = flp.get("stream")
        cfg = PipelineConfig.from_dict(meta["config"])
        drift = _drift_from_state(meta["drift_model"], arrays, "drift.")
        baselines = {
            name: _drift_from_state(bm, arrays, f"baseline.{name}.")
            for name, bm in meta.get("baselines", {}).items()
        }
        diagnostics = {
            k: v for k, v in arrays.items() if not k.startswith(("drift.", "baseline.", "causal."))
        }
        cmeta = meta.get("causal_model")
        causal = None if cmeta is None else CausalDriftModel.from_state(cmeta, arrays, "causal.")
        return CompensationModel(
            config=cfg,
            drift=drift,
            baselines=baselines,
            K=int(meta["vmd"]["K"]),
            alpha=float(meta["vmd"]["alpha"]),
            calibration=dict(meta.get("calibration", {})),
            flp_mixed=None if flp_mixed is None else ForwardLinearPredictor.from_dict(flp_mixed),
            flp_stream=None if flp_stream is None else ForwardLinearPredictor.from_dict(flp_stream),
            diagnostics=diagnostics,
            decomposition_info=dict(meta.get("decomposition", {})),
            timing_s=dict(meta.get("timing_s", {})),
            causal=causal,
            seed=None if meta.get("seed") is None else int(meta["seed"]),
        )
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(directory, f"incomplete or damaged model ({e!r})") from None
