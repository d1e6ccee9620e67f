"""What ``gyrolab export MODEL_DIR --format px4|ardupilot|c|json|kalibr --out FILE`` writes:
:func:`export` (called by :mod:`gyrolab.app.export`).

* ``px4`` / ``ardupilot``: the firmware cubic of every axis (:mod:`.params`);
  ``--instance`` picks the gyro/IMU instance, ``--device-id`` PX4's ``TC_Gi_ID``.
* ``c``: ``FILE`` (``NAME.c``) and ``NAME.h`` implementing ``--kind`` for every axis
  (default ``chosen``: the causal model when the model has one, else GA-BP; :mod:`.c_code`).
* ``json``: the versioned model description (:mod:`.spec`).
* ``kalibr``: ``imu.yaml`` from the Allan analysis of ``--run`` after compensation
  (:mod:`.kalibr`).

Everything is checked before anything is written; outputs appear atomically.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from gyrolab.errors import InputError
from gyrolab.outputs import atomic_file, check_output

FORMATS = ("px4", "ardupilot", "c", "json", "kalibr")
# The options one format requires (the command line's help and docs/cli.md list them)
REQUIRED_FOR = {"px4": "--device-id", "kalibr": "--run"}


def check_request(
    fmt: str, *, device_id: int | None, run: object | None, instance: int = 0
) -> None:
    """The format is known and the options it requires are given (:data:`REQUIRED_FOR`),
    and ``--instance`` is one of the firmware's calibration slots (PX4 ``TC_G0…3``: 0–3,
    ArduPilot ``INS_TCAL1…3``: 0–2): checked before anything is read, one line and exit 2
    otherwise. Light (no numerical import), so that the command line answers at once."""
    from gyrolab.autopilot import GYRO_CAL_SLOTS

    if fmt not in FORMATS:
        raise InputError("--format", f"unknown format {fmt!r}")
    if fmt == "px4" and device_id is None:
        raise InputError("--device-id", "PX4 needs the gyro's device id (TC_Gi_ID)")
    if fmt == "kalibr" and run is None:
        raise InputError("--run", "the kalibr format needs a run to analyse (--run RUN)")
    n = GYRO_CAL_SLOTS.get(fmt)
    if n is not None and not 0 <= instance < n:
        raise InputError(
            "--instance", f"{fmt} has gyro calibration instances 0..{n - 1}, not {instance}"
        )


def _polys(model_dir: str) -> list[Any]:
    from gyrolab.compensation.model_dir import ModelDir

    return [d.require_firmware() for _name, d in ModelDir(model_dir).axes()]


def _header(model_dir: str, line: str) -> str:
    from gyrolab import __version__

    return (
        f"gyrolab {__version__} export of {model_dir}: 3rd-order temperature polynomial "
        "per axis\n(the firmware form; metrics.json 'firmware_poly3' gives its residual)\n"
        + line
    )


def target(
    fmt: str,
    *,
    kind: str = "chosen",
    instance: int = 0,
    device_id: int | None = None,
    run: object | None = None,
    rostopic: str = "/imu0",
) -> dict[str, Any]:
    """What an export was made for, as given: the gyro instance, device id, model kind,
    kalibr's topic and run (the catalogue's ``target``; what was not given is left out)."""
    t = {
        "instance": instance,
        "device_id": device_id,
        "kind": kind if fmt in ("c", "json") else None,
        "rostopic": rostopic if fmt == "kalibr" else None,
        "run": None if fmt != "kalibr" or run is None else str(run),
    }
    return {k: v for k, v in t.items() if v is not None}


def provenance(model_hash: str, fmt: str, what: dict[str, Any]) -> str:
    """The line every export carries (a comment in the text formats): which model, by its
    hash, in which format, for which target — what ``gyrolab runs rebuild`` reads back
    (docs/export.md, "Provenance")."""
    return f"gyrolab export of model {model_hash} as {fmt} target " + json.dumps(
        what, sort_keys=True
    )


def kalibr_text(
    model_dir: str, run: str, rostopic: str = "/imu0", log_options: dict[str, Any] | None = None
) -> str:
    """``imu.yaml`` for ``model_dir`` applied to ``run`` (every axis)."""
    from gyrolab.compensation.apply import streaming_compensate
    from gyrolab.compensation.model_dir import ModelDir
    from gyrolab.export.kalibr import accel_axis_noise, axis_noise, imu_yaml
    from gyrolab.logs import read_log

    rec = read_log(run, **(log_options or {}))
    dirs = ModelDir(model_dir).axes()
    if rec.axes != len(dirs):
        raise InputError(run, f"has {rec.axes} axes, the model {len(dirs)}")
    pt_t, pt_c = rec.require_temperature()
    axes = {}
    try:
        for k, (name, d) in enumerate(dirs):
            s = rec.axis(k).require_rate()
            y = streaming_compensate(d.load(), s.t, s.values, pt_t, pt_c, "chosen")
            axes[name] = axis_noise(y, s.rate_hz)
    except InputError as e:
        raise InputError(run, e.problem) from None
    accel, why = None, "the run has no accelerometer"
    if rec.accel is not None:  # a user's log with an accelerometer (gyrolab.logs)
        acc = rec.accel
        try:
            accel = {"xyz"[j]: accel_axis_noise(acc.values[:, j], acc.rate_hz) for j in range(3)}
        except InputError as e:  # e.g. a constant (unlogged, zero-noise) accelerometer
            why = f"its accelerometer gives no noise terms ({e.problem})"
    rate_hz = rec.require_rate().rate_hz
    return imu_yaml(axes, rate_hz, rostopic, str(run), accel, no_accel_reason=why)


def export(
    model_dir: str | os.PathLike[str],
    fmt: str,
    out: str | os.PathLike[str],
    *,
    kind: str = "chosen",
    instance: int = 0,
    device_id: int | None = None,
    run: str | os.PathLike[str] | None = None,
    rostopic: str = "/imu0",
    log_options: dict[str, Any] | None = None,
    force: bool = False,
) -> list[Path]:
    """Write ``model_dir`` in format ``fmt`` to ``out`` (module docstring); returns the
    files written. ``device_id`` is required for ``px4``, ``run`` for ``kalibr``
    (:func:`check_request`)."""
    from gyrolab.compensation.model_dir import ModelDir
    from gyrolab.export.params import ardupilot_parm, px4_params

    check_request(fmt, device_id=device_id, run=run, instance=instance)
    model, out = str(model_dir), Path(out)
    outs = [out] + ([out.with_suffix(".h")] if fmt == "c" else [])
    inputs = (model, None if run is None else str(run))
    if fmt == "c":
        from gyrolab.export.c_code import check_header_name

        try:
            check_header_name(outs[1].name)
        except ValueError as e:
            raise InputError(out, str(e)) from None
    for o in outs:
        check_output(o, force, inputs=inputs, kind="file")
    what = target(
        fmt, kind=kind, instance=instance, device_id=device_id, run=run, rostopic=rostopic
    )
    md = ModelDir(model)
    md.axes()  # a model directory (one line, exit 2 otherwise) before it is hashed
    model_hash = md.digest()
    line = provenance(model_hash, fmt, what)
    if fmt == "px4":
        assert device_id is not None  # check_request
        texts = [px4_params(_polys(model), instance, device_id, header=_header(model, line))]
    elif fmt == "ardupilot":
        texts = [ardupilot_parm(_polys(model), instance, header=_header(model, line))]
    elif fmt in ("c", "json"):
        from gyrolab.export.model_json import export_spec

        spec = export_spec(model, kind)
        if fmt == "json":
            spec["model_sha256"] = model_hash  # the catalogue's link to the model
            spec["target"] = what
            texts = [json.dumps(spec, indent=2) + "\n"]
        else:
            from gyrolab.export.c_code import generate

            if out.suffix != ".c":
                raise InputError(out, "the C output must be NAME.c (NAME.h is written beside it)")
            try:
                header, source = generate(spec, outs[1].name)
            except ValueError as e:  # e.g. a non-finite constant, axes' windows that differ
                raise InputError(model, str(e)) from None
            texts = [f"/* {line} */\n" + source, f"/* {line} */\n" + header]
    else:  # kalibr (check_request knows every format)
        texts = [f"# {line}\n" + kalibr_text(model, str(run), rostopic, log_options)]
    for o, text in zip(outs, texts, strict=True):
        with atomic_file(o, force, inputs=inputs) as tmp:
            tmp.write_text(text, encoding="utf-8")
    return outs
