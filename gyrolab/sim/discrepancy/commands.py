"""``gyrolab discrepancy RUN.mcap [--model SIM_MODEL.toml] --out DIR``.

Writes ``DIR/discrepancy.json`` (``effects_found``, ``ambiguous``, ``gap_before``,
``gap_after``, ``steps``), ``DIR/model.toml`` (the updated simulator model, accepted by
``gyrolab simulate --model``) and ``DIR/index.html``, atomically. Reads only the bench
channels of the recording, never its metadata (where a simulator keeps its provenance).
"""

from __future__ import annotations

import argparse
import json
import sys

from gyrolab.outputs import atomic_dir, check_output
from gyrolab.sim.discrepancy.data import load_recording
from gyrolab.sim.discrepancy.report import _json_default, render
from gyrolab.sim.discrepancy.workflow import run_discrepancy
from gyrolab.sim.model import load_model, nominal_model


def discrepancy(args: argparse.Namespace) -> int:
    """CLI handler (see module docstring)."""
    inputs = (args.run, args.model)
    check_output(args.out, args.force, inputs=inputs, kind="dir")
    model = load_model(args.model) if args.model else nominal_model()
    from gyrolab.recording import select_unit

    data = load_recording(args.run, unit=select_unit(args.run, getattr(args, "unit", None)))

    def log(msg: str) -> None:
        print(f"discrepancy: {msg}", file=sys.stderr)

    res = run_discrepancy(data, model, log=log)
    with atomic_dir(args.out, args.force, command="discrepancy", inputs=inputs) as tmp:
        (tmp / "discrepancy.json").write_text(
            json.dumps(res.to_json(), indent=1, default=_json_default), encoding="utf-8"
        )
        (tmp / "model.toml").write_text(res.model.to_toml(), encoding="utf-8")
        (tmp / "index.html").write_text(render(res, str(args.run)), encoding="utf-8")
    found = ", ".join(res.effects_found) or "nothing"
    amb = "; ".join("{" + ", ".join(s) + "}" for s in res.ambiguous)
    print(
        f"wrote {args.out}: named {found}" + (f" (ambiguous: {amb})" if amb else "") + f"; "
        f"LF residual {res.gap_before['lf_residual_rms_dps']:.3g} -> "
        f"{res.gap_after['lf_residual_rms_dps']:.3g} deg/s, "
        f"Allan log distance {res.gap_before['allan_log_distance']:.3g} -> "
        f"{res.gap_after['allan_log_distance']:.3g}, "
        f"temperature {res.gap_before['temperature_rms_c']:.3g} -> "
        f"{res.gap_after['temperature_rms_c']:.3g} C ({res.elapsed_s:.0f} s)"
    )
    return 0
