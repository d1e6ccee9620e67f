"""What ``gyrolab report RUN.mcap [--model MODEL_DIR] --out REPORT_DIR`` writes (docs/cli.md
contract): :func:`write_report`, which :mod:`gyrolab.app.report` calls.

Writes, atomically (a temporary sibling directory renamed into place):

* ``index.html`` — the self-contained report (figures embedded, opens offline);
* ``metrics.json`` — docs/cli.md keys (``raw``; with a model also ``compensated``,
  ``baselines.<name>``, ``vmd``, ``imf_classes``, ``held_out``) and ``timing_s``;
* ``report.pdf`` — the same content as the HTML page.

Bad input (missing or foreign recording, no gyro topic, a model of another format
version) is one line and exit 2, and nothing is written.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gyrolab.outputs import atomic_dir, check_output
from gyrolab.progress import progress

STAGES = [
    "load model",
    "read recording",
    "apply model",
    "metrics",
    "figures",
    "allan",
    "plateau noise",
    "write",
]


def report_stages(has_model: bool) -> list[str]:
    """The stages a report goes through (the model's two only with a model)."""
    return [s for s in STAGES if has_model or s not in ("load model", "apply model")]


def write_report(
    run: str | Path,
    out: str | Path,
    model: str | Path | None = None,
    force: bool = False,
    show_progress: bool = True,
    spec: str | Path | None = None,
    operator: str | None = None,
    serial: str | None = None,
    log_options: dict | None = None,
    unit: str | None = None,
    label: str | None = None,
    on_stage: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Build and write the report of ``run`` into ``out``; returns the metrics.

    ``spec`` (SPEC.toml, :mod:`gyrolab.report.spec_limits`) adds per-limit pass/fail and the
    verdict; ``operator``/``serial`` fill the sign-off block instead of the recording's;
    ``label``: how metrics.json names the run (default: ``run`` as given; the demo passes
    a path relative to its output directory); ``on_stage(name)``: told each stage of
    :func:`report_stages` as it is reached.
    """
    from gyrolab.report.build import build_report
    from gyrolab.report.html import render
    from gyrolab.report.pdf import write_pdf

    check_output(out, force, inputs=(run, model, spec), kind="dir")
    stages = report_stages(model is not None)
    bar = progress(total=len(stages), desc="report", unit="stage")
    if not show_progress:
        bar.disable = True

    def step(name: str) -> None:
        if on_stage is not None:
            on_stage(name)
        bar.set_postfix_str(name)
        if bar.n < len(stages) - 1:
            bar.update(1)

    t0 = time.perf_counter()
    try:
        from gyrolab.report.axes_report import build_axes_report, n_axes

        n, rec = (1, None) if unit is not None else n_axes(run, model, log_options)
        kw = {
            "spec": spec,
            "operator": operator,
            "serial": serial,
            "log_options": log_options,
            "label": label,
        }
        if n > 1:
            doc, metrics = build_axes_report(run, model, n, step, rec=rec, **kw)
        else:
            doc, metrics = build_report(run, model, step=step, unit=unit, rec=rec, **kw)
        metrics["timing_s"] = time.perf_counter() - t0  # the recording's read included
        step("write")
        with atomic_dir(out, force, command="report", inputs=(run, model, spec)) as tmp:
            (tmp / "index.html").write_text(render(doc), encoding="utf-8")
            (tmp / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
            write_pdf(doc, tmp / "report.pdf")
        bar.update(len(stages) - bar.n)
    finally:
        bar.close()
    return metrics
