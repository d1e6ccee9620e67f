"""What ``gyrolab apply MODEL_DIR RUN.mcap --out COMPENSATED.mcap [--unit SERIAL]`` does
(docs/recording-format.md, "Compensated recordings"): :func:`apply` writes a copy of RUN in
which

* ``/gyro/rate`` is the causal, full-rate compensated rate ``raw − d`` of the causal
  headline model (:mod:`gyrolab.compensation.causal`; ``raw − f(T)`` with the GA-BP drift
  model for a model directory without one), same blocks, timestamps and sample indices
  as the input;
* ``/gyro/rate_raw`` is the input's ``/gyro/rate``, byte for byte (same schema);
* ``/gyro/rate_offline`` is the paper's offline output (noise modes removed, mixed modes
  FLP-filtered, drift compensated) at 1000 points/h, as ``GyroRateBlock``s of period 3.6 s;
* every other topic is copied unchanged, and a ``compensation`` metadata record names the
  model (calibration run, format and software versions, what each topic holds).

Of a multi-unit recording it compensates the unit ``--unit`` names, or without it every
unit, each by its own model: the three topics above are each unit's
(``/unit/<serial>/gyro/rate`` …), the other units' topics and the shared ones are copied
unchanged, and the ``compensation`` record names the unit (``unit``), or holds one record
per unit (``units``). MODEL_DIR is the unit's model directory, or the directory
``gyrolab compensate RUN.mcap --out DIR`` wrote for the whole run, of which ``DIR/<serial>``
is taken (:func:`resolve_models`).

Every input is checked before anything is written; bad input is one line and exit 2.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from gyrolab import __version__
from gyrolab.compensation.apply import StreamingCompensator, compensate_offline
from gyrolab.compensation.axis_runs import load_runs
from gyrolab.compensation.commands import recording_serial
from gyrolab.compensation.guards import range_check, warn_outside
from gyrolab.compensation.model_dir import MODEL_FORMAT_VERSION, ModelDir
from gyrolab.compensation.prepare import prepare_file
from gyrolab.errors import InputError, named
from gyrolab.outputs import atomic_file, check_output
from gyrolab.record.blocks import decode_block, encode_block
from gyrolab.record.format import TOPIC_RATE, unit_topic
from gyrolab.record.reader import iter_messages, list_units, select_unit
from gyrolab.record.rewrite import Message, rewrite_recording

TOPIC_RATE_RAW = "/gyro/rate_raw"
TOPIC_RATE_OFFLINE = "/gyro/rate_offline"


@dataclass
class _Target:
    """The rate stream a copy compensates: the file's (``serial`` None) or one unit's;
    ``comp(t, rate)`` its causal compensation, ``t_off``/``y_off`` its offline output."""

    serial: str | None
    comp: Callable[[np.ndarray, np.ndarray], np.ndarray]
    t_off: np.ndarray
    y_off: np.ndarray
    block_s: float  # the offline output's period

    def topic(self, topic: str) -> str:
        return unit_topic(topic, self.serial)


def resolve_models(
    model_dir: str | os.PathLike[str], run_path: str | os.PathLike[str], unit: str | None
) -> list[tuple[str, str | None]]:
    """The model directories ``apply`` uses, each with the unit of ``run_path`` it
    compensates (None for a single-unit recording).

    ``model_dir`` is a model itself, or the directory of unit models ``gyrolab compensate``
    writes for a multi-unit run, of which ``model_dir/<serial>`` is taken (for a
    single-unit run, the serial its metadata names). ``unit`` picks one unit of a
    multi-unit recording; without it a directory of unit models compensates every unit of
    the run (each must have its model), and a single model needs a run of one unit."""
    from gyrolab.logs import detect_format

    model_dir, run_path = str(model_dir), str(run_path)
    if detect_format(run_path) != "gyrolab":  # also checks the file (a damaged one: exit 2)
        raise InputError(run_path, "apply writes a compensated copy of a gyrolab recording only")
    units = list_units(run_path)
    is_model = ModelDir.is_model_dir(model_dir)
    have = (
        []
        if is_model
        else sorted(p.name for p in Path(model_dir).glob("*") if ModelDir.is_model_dir(p))
    )
    if unit is None and len(units) > 1:
        if not have:
            raise InputError(
                run_path,
                f"holds {len(units)} units; choose one with --unit SERIAL: {', '.join(units)} "
                "(or give the directory `gyrolab compensate` wrote for the run, a model per unit)",
            )
        missing = [s for s in units if s not in have]
        if missing:
            raise InputError(
                model_dir,
                f"has no model for unit {', '.join(missing)} of {run_path} (its unit models: "
                f"{', '.join(have)}); choose the units it has with --unit SERIAL",
            )
        return [(str(Path(model_dir) / s), s) for s in units]
    serial = select_unit(run_path, unit)
    if is_model:
        return [(model_dir, serial)]
    name = serial or recording_serial(run_path)
    if name and name in have:
        return [(str(Path(model_dir) / name), serial)]
    if name and have:
        raise InputError(
            model_dir, f"has no model for unit {name}; its unit models: {', '.join(have)}"
        )
    return [(model_dir, serial)]  # not a model directory: ModelDir says what is wrong with it


def rate_axes(path: str, serial: str | None = None) -> int:
    """The axis count of a gyrolab recording's ``/gyro/rate`` (of unit ``serial``); 1
    without rate data (the single-axis path reports that)."""
    for _topic, _ts, data in iter_messages(path, [unit_topic(TOPIC_RATE, serial)]):
        arr = decode_block(data, "rate")[3]
        return 1 if arr.ndim == 1 else int(arr.shape[1])
    return 1


def headline_text(models: list[Any]) -> str:
    """What ``/gyro/rate`` of the compensated copy holds (the apply metadata)."""
    per_axis = " per axis" if len(models) > 1 else ""
    if all(m.causal is not None for m in models):
        fams = "/".join(sorted({m.causal.family for m in models}))
        return (
            f"causal full-rate compensated rate, raw - d (causal {fams} model on PT100 "
            f"readings up to now){per_axis}"
        )
    return f"causal full-rate compensated rate, raw - f(T){per_axis}"


def apply(
    model_dir: str | os.PathLike[str],
    run_path: str | os.PathLike[str],
    out: str | os.PathLike[str],
    force: bool = False,
    unit: str | None = None,
) -> list[str | None]:
    """Apply ``model_dir`` to ``run_path`` (unit ``unit`` of a multi-unit one, or each unit
    by its model in compensate's directory) and write the
    compensated MCAP ``out`` (module docstring): ``/gyro/rate`` of every axis compensated by
    its model's headline drift model
    (:meth:`~gyrolab.compensation.fit.CompensationModel.headline`: the causal model, the one
    ``gyrolab export`` exports by default), whatever the axis count; a run of another axis
    count than the model's is refused. The units compensated (``[None]``: a single-unit
    recording)."""
    given, run_path = str(model_dir), str(run_path)
    inputs = (given, run_path)
    check_output(out, force, inputs=inputs, kind="file")
    targets, infos = [], {}
    for unit_dir, serial in resolve_models(given, run_path, unit):
        where = run_path if serial is None else f"{run_path} (unit {serial})"
        models = [d.load() for _a, d in ModelDir(unit_dir).axes()]
        have = rate_axes(run_path, serial)
        if have != len(models):
            raise InputError(
                where,
                f"has {have} axes, the model {unit_dir} {len(models)}: apply a {have}-axis model",
            )
        target, info = _prepare(unit_dir, run_path, serial, models, where)
        info["topics"] = {
            target.topic(TOPIC_RATE): headline_text(models),
            target.topic(TOPIC_RATE_RAW): "the input's /gyro/rate, unchanged",
            target.topic(TOPIC_RATE_OFFLINE): info.pop("offline"),
        }
        targets.append(target)
        infos[serial] = info
    if len(targets) == 1:
        info = infos[targets[0].serial]
        if targets[0].serial is not None:
            info["unit"] = targets[0].serial
    else:  # every unit of a multi-unit run: each unit's record under its serial
        info = {
            "model_format_version": MODEL_FORMAT_VERSION,
            "software_version": __version__,
            "units": infos,
        }
    with atomic_file(out, force, inputs=inputs) as tmp:
        _write_compensated(run_path, tmp, targets, info)
    return [t.serial for t in targets]


def _prepare(
    model_dir: str, run_path: str, serial: str | None, models: list[Any], where: str
) -> tuple[_Target, dict[str, Any]]:
    """Each axis's model on its run: its causal compensator and offline output, its range
    check (warned on stderr); a single-axis run is streamed from the file (bounded memory),
    a multi-axis one keeps its (n, axes) blocks."""
    cfg = models[0].config
    single = len(models) == 1
    runs = (
        [prepare_file(run_path, cfg, unit=serial)]
        if single
        else load_runs(run_path, cfg, unit=serial)
    )
    comps, y_off, ranges = [], [], []
    for k, (m, r) in enumerate(zip(models, runs, strict=True)):
        ranges.append(range_check(m.calibration, r))
        warn_outside(where if single else f"{where} (axis {'xyz'[k]})", ranges[-1])
        with named(run_path):
            off = compensate_offline(m, r)
        y_off.append(off.series["compensated"])
        comps.append(StreamingCompensator(m.headline(), r.pt_t, r.pt_c))
    common = {
        "model_dir": str(model_dir),
        "model_format_version": MODEL_FORMAT_VERSION,
        "software_version": __version__,
    }
    if single:
        info = common | {
            "calibration_run": models[0].calibration.get("path", ""),
            "vmd": {"K": models[0].K, "alpha": models[0].alpha},
            "calibrated_range": ranges[0],
            "offline": f"offline GPSO-VMD/MPE/FLP/GA-BP output, {cfg.block_s} s averages",
        }
        return _Target(serial, comps[0], off.t, y_off[0], cfg.block_s), info

    def comp(t: np.ndarray, arr: np.ndarray) -> np.ndarray:
        return np.column_stack([c(t, arr[:, k]) for k, c in enumerate(comps)])

    info = common | {
        "axes": len(models),
        "calibrated_range": ranges,
        "calibration_run": models[0].calibration.get("path", ""),
        "vmd": [{"K": m.K, "alpha": m.alpha} for m in models],
        "offline": f"offline GPSO-VMD/MPE/FLP/GA-BP output per axis, {cfg.block_s} s averages",
    }
    return _Target(serial, comp, off.t, np.column_stack(y_off), cfg.block_s), info


def _write_compensated(src: str, dst: Path, targets: list[_Target], info: dict[str, Any]) -> None:
    """Copy ``src`` to ``dst`` (:func:`~gyrolab.record.rewrite.rewrite_recording`), with each
    target's ``/gyro/rate`` compensated block by block and its two extra rate channels
    added (module docstring). Memory: one block at a time."""
    by_rate = {t.topic(TOPIC_RATE): t for t in targets}
    start_ns = _start_time_ns(src, targets[0].topic(TOPIC_RATE))

    def compensate(m: Message) -> list[Message]:
        target = by_rate.get(m.topic)
        if target is None:
            return [m]
        t0, period, first, arr = decode_block(m.data, "rate")
        t = t0 + np.arange(arr.shape[0]) * period
        data = encode_block(t0, period, first, target.comp(t, arr.astype(float)), "rate")
        return [replace(m, topic=target.topic(TOPIC_RATE_RAW)), replace(m, data=data)]

    per = 1000  # offline samples per message: 1 h at 1000 points/h
    derived: dict[str, str] = {}
    offline = []
    for rate, target in by_rate.items():
        off_topic = target.topic(TOPIC_RATE_OFFLINE)
        derived |= {target.topic(TOPIC_RATE_RAW): rate, off_topic: rate}
        y_off = target.y_off
        for k, s in enumerate(range(0, y_off.shape[0], per)):
            t0 = float(target.t_off[s])
            ts = start_ns + int(round(t0 * 1e9))
            data = encode_block(t0, target.block_s, s, y_off[s : s + per], "rate")
            offline.append(Message(off_topic, ts, ts, k, data))
    rewrite_recording(
        src,
        dst,
        transform=compensate,
        derived=derived,
        tail=offline,
        metadata={"compensation": {k: json.dumps(v) for k, v in info.items()}},
    )


def _start_time_ns(path: str, topic: str = TOPIC_RATE) -> int:
    """The run's start (Unix ns): ``log_time − t0·1e9`` of the first block of ``topic``."""
    for _topic, log_ns, data in iter_messages(path, [topic]):
        t0 = decode_block(data, "rate")[0]
        return int(log_ns - round(t0 * 1e9))
    raise InputError(path, f"recording has no {topic} data")
