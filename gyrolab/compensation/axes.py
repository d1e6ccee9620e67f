"""Per-axis compensation of 1–3-axis units: one single-axis model per axis, one directory.

The single-axis model (:mod:`.fit`, :mod:`.apply`) is unchanged; a unit with several axes
is a loop over it. A multi-axis model directory holds one complete single-axis model directory
per axis and a head ``model.json`` naming them::

    MODEL_DIR/
      model.json      format, format_version, software_version, created_utc,
                      "axes": ["x", "y", "z"], "axis_dirs": ["axis_x", "axis_y", "axis_z"]
      metrics.json    {"axes": {"x": {...}, ...}, "held_out", "timing_s"}
      axis_x/         a single-axis model directory (model.json, arrays.npz, metrics.json,
      axis_y/         firmware.json, ...), loadable on its own by ``gyrolab apply``
      axis_z/

A single-axis unit keeps the single-axis layout (no ``axis_*`` directory), so everything
written before axis counts existed reads as before. ``firmware.json`` in every model
directory is the 3rd-order firmware polynomial (:mod:`.firmware`).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

from gyrolab import __version__
from gyrolab.compensation.config import PipelineConfig
from gyrolab.compensation.firmware import Poly3
from gyrolab.compensation.model_dir import MODEL_FORMAT, MODEL_FORMAT_VERSION, write_json
from gyrolab.compensation.prepare import PreparedRun, prepare_file, prepare_run
from gyrolab.errors import InputError
from gyrolab.record.format import AXIS_NAMES

FIRMWARE_JSON = "firmware.json"


def axis_dir_name(k: int) -> str:
    return f"axis_{AXIS_NAMES[k]}"


def load_runs(
    path: str, cfg: PipelineConfig, unit: str | None = None, **log_options: Any
) -> list[PreparedRun]:
    """One :class:`~.prepare.PreparedRun` per axis of the run at ``path`` (of unit ``unit``
    of a multi-unit recording).

    A single-axis gyrolab MCAP (unit) is streamed from the file
    (:func:`.prepare.prepare_file`, bounded memory, exactly as before); a multi-axis
    recording (a flight controller's IMU, say) or a foreign log (ROS 2 MCAP, PX4 ULog,
    ArduPilot DataFlash: :func:`gyrolab.logs.read_log` with ``log_options``) is read into
    memory and prepared axis by axis (:func:`.prepare.prepare_run`)."""
    from gyrolab.logs import read_log, single_axis_gyrolab
    from gyrolab.record.reader import read_recording

    if single_axis_gyrolab(path, unit):
        return [prepare_file(path, cfg, unit=unit)]
    rec = read_recording(path, unit=unit) if unit is not None else read_log(path, **log_options)
    return [prepare_run(rec.axis(k), cfg) for k in range(rec.axes)]


def write_head(directory: Path, n_axes: int, axis_metrics: list[dict[str, Any]]) -> None:
    """The head ``model.json`` and ``metrics.json`` of a multi-axis model directory."""
    names = list(AXIS_NAMES[:n_axes])
    write_json(
        directory / "model.json",
        {
            "format": MODEL_FORMAT,
            "format_version": MODEL_FORMAT_VERSION,
            "software_version": __version__,
            "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "axes": names,
            "axis_dirs": [axis_dir_name(k) for k in range(n_axes)],
        },
    )
    write_json(
        directory / "metrics.json",
        {
            "axes": dict(zip(names, axis_metrics, strict=True)),
            "held_out": bool(axis_metrics[0]["held_out"]),
            "timing_s": float(sum(m["timing_s"] for m in axis_metrics)),
        },
    )


def axis_dirs(directory: str | Path) -> list[tuple[str, Path]]:
    """``[(axis name, single-axis model directory)]`` of a model directory of any axis count
    (``[("x", directory)]`` for a single-axis one)."""
    d = Path(directory)
    mj = d / "model.json"
    if not mj.is_file():
        raise InputError(d, "not a gyrolab model directory (no model.json)")
    try:
        meta = json.loads(mj.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise InputError(mj, f"damaged model file ({e.__class__.__name__})") from None
    dirs = meta.get("axis_dirs") if isinstance(meta, dict) else None
    if not dirs:
        return [("x", d)]
    return [(str(a), d / str(s)) for a, s in zip(meta["axes"], dirs, strict=True)]


def load_poly3(directory: str | Path) -> Poly3:
    """The firmware polynomial of a single-axis model directory."""
    p = Path(directory) / FIRMWARE_JSON
    if not p.is_file():
        raise InputError(
            directory, f"model has no {FIRMWARE_JSON} (fitted by an older gyrolab: refit it)"
        )
    try:
        return Poly3.from_dict(json.loads(p.read_text())["poly3"])
    except (KeyError, TypeError, ValueError, IndexError) as e:
        raise InputError(p, f"damaged firmware polynomial ({e!r})") from None
