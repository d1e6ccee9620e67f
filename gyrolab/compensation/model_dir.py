"""The fitted-model directory: a versioned, code-free on-disk format.

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
from gyrolab.errors import InputError

MODEL_FORMAT = "gyrolab.compensation-model"
MODEL_FORMAT_VERSION = 1
MODEL_JSON = "model.json"
ARRAYS_NPZ = "arrays.npz"


def _jsonable(x: Any) -> Any:
    """numpy scalars/arrays → plain JSON types (NaN/inf become null: JSON has none)."""
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if np.isfinite(v) else None
    if isinstance(x, (np.bool_,)):
        return bool(x)
    return x


def write_json(path: str | os.PathLike[str], obj: Any) -> None:
    Path(path).write_text(json.dumps(_jsonable(obj), indent=2, sort_keys=False) + "\n")


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
        import torch

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
