"""Build the report of one run: read the recording (and the model), assemble the data once,
lay it out.

:func:`build_report` returns the :class:`~gyrolab.report.document.Document` and the
``metrics.json`` content; :mod:`gyrolab.report.commands` writes them. The stages:

1. inputs checked before anything heavy runs: the spec file, the model directory (its
   format version), then the recording's gyro topic;
2. :func:`gyrolab.report.data.assemble` — every number, once, into a
   :class:`~gyrolab.report.data.ReportData` (with a model: what ``gyrolab compensate``
   computed on this run, read from the model directory; :mod:`gyrolab.report.analysis`);
3. :func:`gyrolab.report.layout.document` — the sections, from the data only.

Without a model the report is the raw record of the run (temperature profile, raw output,
raw Allan deviation and metrics, run log, bench identity); with ``--model`` the model's
figures (GPSO, VMD/MPE, drift fit, compensated output, compensated Allan deviation,
baseline comparison) are added.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gyrolab.record.reader import Recording
from gyrolab.report.document import Document

Step = Callable[[str], None]


def _noop(_: str) -> None:
    return None


def build_report(
    run_path: str | Path,
    model_dir: str | Path | None = None,
    step: Step = _noop,
    spec: str | Path | None = None,
    operator: str | None = None,
    serial: str | None = None,
    axis: int | None = None,
    log_options: dict | None = None,
    unit: str | None = None,
    rec: Recording | None = None,
    label: str | None = None,
) -> tuple[Document, dict[str, Any]]:
    """The report document and ``metrics.json`` content of ``run_path`` (and the model).

    ``step(name)`` is called as each stage starts (progress display). ``spec`` (a spec
    TOML, :mod:`gyrolab.report.spec_limits`) adds the verdict; ``operator``/``serial`` override
    the recording's for the sign-off block; ``axis`` reports one axis of a multi-axis
    unit; ``rec`` is the recording already read (``run_path``'s, every axis); ``label``
    names the run in metrics.json (default: ``run_path`` as given).
    """
    from gyrolab.outputs import json_safe
    from gyrolab.report.data import assemble, read_run
    from gyrolab.report.layout import document
    from gyrolab.report.spec_limits import load_spec

    t_start = time.perf_counter()
    spec_obj = load_spec(spec) if spec is not None else None
    model = None
    if model_dir is not None:
        step("load model")
        from gyrolab.compensation.model_dir import load_model

        model = load_model(str(model_dir))
    step("read recording")
    if rec is None:
        rec = read_run(run_path, log_options, unit)  # unit: of a multi-unit recording
    if axis is not None:  # one axis of a multi-axis unit (gyrolab.report.axes_report)
        rec = rec.axis(axis)
    data = assemble(rec, model_dir, model, step, spec_obj, operator, serial, unit, label)
    step("figures")
    doc = document(data)
    metrics = data.metrics
    metrics["timing_s"] = time.perf_counter() - t_start
    return doc, json_safe(metrics)
