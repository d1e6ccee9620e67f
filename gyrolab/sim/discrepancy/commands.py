"""What ``gyrolab discrepancy RUN.mcap [--model SIM_MODEL.toml] --out DIR`` does:
:func:`discrepancy` (called by :mod:`gyrolab.app.discrepancy` and by ``gyrolab batch``).

Writes ``DIR/discrepancy.json`` (``effects_found``, ``ambiguous``, ``gap_before``,
``gap_after``, ``steps``), ``DIR/model.toml`` (the updated simulator model, accepted by
``gyrolab simulate --model``) and ``DIR/index.html``, atomically. Reads only the bench
channels of the recording, never its metadata (where a simulator keeps its provenance).

On a multi-axis recording (issue 15's layout) each axis is analysed with the thermal fits
shared (:mod:`gyrolab.sim.discrepancy.axes_workflow`) and ``DIR`` holds ``discrepancy.json``
(``effects_shared`` once, ``effects_by_axis`` and one full single-axis document per axis
under ``axes``), ``model_axis{K}.toml`` and ``index_axis{K}.html`` per axis, and an
``index.html`` that links them (docs/discrepancy.md, "Several axes").
"""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Callable
from dataclasses import replace
from html import escape
from typing import Any

from gyrolab.outputs import atomic_dir, check_output
from gyrolab.sim.discrepancy.axes_workflow import run_discrepancy_axes
from gyrolab.sim.discrepancy.data import load_recording_axes
from gyrolab.sim.discrepancy.report import json_default, render
from gyrolab.sim.discrepancy.workflow import Result, run_discrepancy
from gyrolab.sim.model import load_sim_model, nominal_model

#: What :func:`discrepancy` reports to its ``on_stage`` as each is done (batch's progress).
STAGES = ("read", "analyse", "write")


def discrepancy(
    run: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    model: str | os.PathLike[str] | None = None,
    unit: str | None = None,
    force: bool = False,
    log: Callable[[str], None] | None = None,
    on_stage: Callable[[str], None] | None = None,
) -> str:
    """Analyse ``run`` from ``model`` (default nominal), write ``out`` (module docstring);
    returns the one-line summary the command prints. ``log``: progress lines (default:
    ``discrepancy: ...`` on stderr); ``on_stage(name)`` is told each of :data:`STAGES` as
    it is done."""
    stage = on_stage or (lambda _name: None)
    inputs = (run, model)
    check_output(out, force, inputs=inputs, kind="dir")
    sim_model = load_sim_model(model) if model else nominal_model()
    from gyrolab.record.reader import select_unit

    axes = load_recording_axes(run, unit=select_unit(run, unit))
    stage("read")

    def stderr_log(msg: str) -> None:
        print(f"discrepancy: {msg}", file=sys.stderr)

    log = log or stderr_log
    if len(axes) > 1:
        line = _discrepancy_axes(run, out, force, axes, sim_model, inputs, log, stage)
        stage("write")
        return line
    data = replace(axes[0], source=str(run))
    res = run_discrepancy(data, sim_model, log=log)
    stage("analyse")
    with atomic_dir(out, force, command="discrepancy", inputs=inputs) as tmp:
        (tmp / "discrepancy.json").write_text(
            json.dumps(res.to_json(), indent=1, default=json_default), encoding="utf-8"
        )
        (tmp / "model.toml").write_text(res.model.to_toml(), encoding="utf-8")
        (tmp / "index.html").write_text(render(res, str(run)), encoding="utf-8")
        _write_proposals(tmp, res)
    stage("write")
    found = ", ".join(res.effects_found) or "nothing"
    amb = "; ".join("{" + ", ".join(s) + "}" for s in res.ambiguous)
    nxt = [
        a.proposal.file + ("" if a.proposal.expected_to_separate else " (not expected to separate)")
        for a in res.ambiguity
        if a.proposal is not None
    ]
    cyc = "; ".join(
        f"a {c['period_s']:.0f} s cycle at {c['peak_to_local_median']:.0f}x the local median "
        "(present in the measurement: check the bench)"
        for c in res.periodic_content
    )
    return (
        f"wrote {out}: named {found}"
        + (f" (ambiguous: {amb})" if amb else "")
        + (f"; next experiment to separate them: {', '.join(nxt)}" if nxt else "")
        + (f"; {cyc}" if cyc else "")
        + "; "
        f"LF residual {res.gap_before['lf_residual_rms_dps']:.3g} -> "
        f"{res.gap_after['lf_residual_rms_dps']:.3g} deg/s, "
        f"Allan log distance {res.gap_before['allan_log_distance']:.3g} -> "
        f"{res.gap_after['allan_log_distance']:.3g}, "
        f"temperature {res.gap_before['temperature_rms_c']:.3g} -> "
        f"{res.gap_after['temperature_rms_c']:.3g} C ({res.elapsed_s:.0f} s)"
    )


def _write_proposals(tmp: Any, res: Result) -> None:
    """Each proposed separating profile as a PROFILE.toml beside discrepancy.json."""
    for a in res.ambiguity:
        if a.proposal is not None:
            (tmp / a.proposal.file).write_text(a.proposal.toml(), encoding="utf-8")


def _discrepancy_axes(
    run: str | os.PathLike[str],
    out: str | os.PathLike[str],
    force: bool,
    axes: list[Any],
    model: Any,
    inputs: tuple[Any, ...],
    log: Any,
    stage: Callable[[str], None],
) -> str:
    """The multi-axis layout (module docstring): shared effects once, one model per axis."""
    res = run_discrepancy_axes(axes, model, log=log)
    stage("analyse")
    n = len(res.axes)
    links = "".join(
        f'<li>axis {"xyz"[k]}: <a href="index_axis{k}.html">report</a>, '
        f'<a href="model_axis{k}.toml">model</a>; own effects: '
        f"{escape(', '.join(res.by_axis[k]) or 'none')}</li>"
        for k in range(n)
    )
    index = (
        "<!doctype html><meta charset=utf-8><title>discrepancy</title>"
        f"<h1>Discrepancy: {escape(str(run))} ({n} axes)</h1>"
        f"<p>Shared by every axis: {escape(', '.join(res.shared) or 'none')}</p><ul>{links}</ul>"
    )
    for k, r in enumerate(res.axes):  # each axis's proposals under its own name
        for a in r.ambiguity:
            if a.proposal is not None:
                a.proposal.file = f"axis{k}_{a.proposal.file}"
    with atomic_dir(out, force, command="discrepancy", inputs=inputs) as tmp:
        (tmp / "discrepancy.json").write_text(
            json.dumps(res.to_json(), indent=1, default=json_default), encoding="utf-8"
        )
        for k, r in enumerate(res.axes):
            _write_proposals(tmp, r)
            (tmp / f"model_axis{k}.toml").write_text(r.model.to_toml(), encoding="utf-8")
            (tmp / f"index_axis{k}.html").write_text(
                render(r, f"{run} (axis {'xyz'[k]})"), encoding="utf-8"
            )
        (tmp / "index.html").write_text(index, encoding="utf-8")
    own = "; ".join(
        f"axis {'xyz'[k]}: {', '.join(e) or 'nothing'}" for k, e in enumerate(res.by_axis)
    )
    return (
        f"wrote {out}: {n} axes; shared {', '.join(res.shared) or 'nothing'}; {own}; "
        + ", ".join(
            f"axis {'xyz'[k]} LF residual {r.gap_before['lf_residual_rms_dps']:.3g} -> "
            f"{r.gap_after['lf_residual_rms_dps']:.3g} deg/s"
            for k, r in enumerate(res.axes)
        )
    )
