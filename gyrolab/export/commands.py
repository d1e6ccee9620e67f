"""``gyrolab export MODEL_DIR --format px4|ardupilot|c|json|kalibr --out FILE``.

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

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from gyrolab.errors import InputError
from gyrolab.outputs import atomic_file, check_output

FORMATS = ("px4", "ardupilot", "c", "json", "kalibr")


def _polys(model_dir: str) -> list[Any]:
    from gyrolab.compensation.axes import axis_dirs, load_poly3

    return [load_poly3(d) for _name, d in axis_dirs(model_dir)]


def _header(args: argparse.Namespace) -> str:
    from gyrolab import __version__

    return (
        f"gyrolab {__version__} export of {args.model}: 3rd-order temperature polynomial "
        "per axis\n(the firmware form; metrics.json 'firmware_poly3' gives its residual)"
    )


def kalibr_text(args: argparse.Namespace) -> str:
    """``imu.yaml`` for ``args.model`` applied to ``args.run`` (every axis)."""
    from gyrolab.compensation.apply import streaming_compensate
    from gyrolab.compensation.axes import axis_dirs
    from gyrolab.compensation.model_dir import load_model
    from gyrolab.export.kalibr import accel_axis_noise, axis_noise, imu_yaml
    from gyrolab.logs import log_options, read_log

    if not args.run:
        raise InputError("--run", "the kalibr format needs a run to analyse (--run RUN)")
    rec = read_log(args.run, **log_options(args))
    dirs = axis_dirs(args.model)
    if rec.axes != len(dirs):
        raise InputError(args.run, f"has {rec.axes} axes, the model {len(dirs)}")
    pt_t, pt_c = rec.require_temperature()
    axes = {}
    try:
        for k, (name, d) in enumerate(dirs):
            s = rec.axis(k).require_rate()
            y = streaming_compensate(load_model(str(d)), s.t, s.values, pt_t, pt_c)
            axes[name] = axis_noise(y, s.rate_hz)
    except InputError as e:
        raise InputError(args.run, e.problem) from None
    accel, why = None, "the run has no accelerometer"
    if rec.accel is not None:  # a user's log with an accelerometer (gyrolab.logs)
        acc = rec.accel
        try:
            accel = {"xyz"[j]: accel_axis_noise(acc.values[:, j], acc.rate_hz) for j in range(3)}
        except InputError as e:  # e.g. a constant (unlogged, zero-noise) accelerometer
            why = f"its accelerometer gives no noise terms ({e.problem})"
    rate_hz = rec.require_rate().rate_hz
    return imu_yaml(axes, rate_hz, args.rostopic, str(args.run), accel, no_accel_reason=why)


def check_instance(firmware: str, instance: int) -> None:
    """``--instance`` within the firmware's calibration slots (PX4 TC_G0..3, ArduPilot
    INS_TCAL1..3 as 0..2); InputError otherwise."""
    from gyrolab.autopilot import ardupilot, px4

    n = px4.TC_SLOTS if firmware == "px4" else ardupilot.IMUS
    if not 0 <= instance < n:
        raise InputError(
            "--instance", f"{firmware} has gyro calibration instances 0..{n - 1}, not {instance}"
        )


def export(args: argparse.Namespace) -> int:
    """The ``gyrolab export`` handler (module docstring)."""
    from gyrolab.export.params import ardupilot_parm, px4_params

    fmt = args.format
    out = Path(args.out)
    outs = [out] + ([out.with_suffix(".h")] if fmt == "c" else [])
    inputs = (args.model, args.run)
    for o in outs:
        check_output(o, args.force, inputs=inputs, kind="file")
    if fmt in ("px4", "ardupilot"):
        check_instance(fmt, args.instance)
    if fmt == "px4":
        if args.device_id is None:
            raise InputError("--device-id", "PX4 needs the gyro's device id (TC_Gi_ID)")
        texts = [
            px4_params(_polys(args.model), args.instance, args.device_id, header=_header(args))
        ]
    elif fmt == "ardupilot":
        texts = [ardupilot_parm(_polys(args.model), args.instance, header=_header(args))]
    elif fmt in ("c", "json"):
        from gyrolab.export.spec import export_spec

        spec = export_spec(args.model, args.kind)
        if fmt == "json":
            texts = [json.dumps(spec, indent=2) + "\n"]
        else:
            from gyrolab.export.c_code import generate

            if out.suffix != ".c":
                raise InputError(out, "the C output must be NAME.c (NAME.h is written beside it)")
            try:
                header, source = generate(spec, outs[1].name)
            except ValueError as e:
                raise InputError(args.model, str(e)) from None
            texts = [source, header]
    elif fmt == "kalibr":
        texts = [kalibr_text(args)]
    else:  # argparse restricts the choices
        raise InputError("--format", f"unknown format {fmt!r}")
    for o, text in zip(outs, texts, strict=True):
        with atomic_file(o, args.force, inputs=inputs) as tmp:
            tmp.write_text(text, encoding="utf-8")
    print(f"wrote {', '.join(str(o) for o in outs)}", file=sys.stderr)
    return 0
