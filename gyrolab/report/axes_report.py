"""The report of a multi-axis unit: the single-axis report of every axis, one after the
other in one document (the layout of :mod:`.build` is reused, not copied).

Sections and blocks get the axis in their key and title (``x-run``, "Axis x — Run: …");
``metrics.json`` is ``{"axes": {"x": {...}, "y": {...}, "z": {...}}, "outcome", "timing_s"}``
with each axis's metrics as a single-axis report writes them (a spec's verdict per axis)
and the run's outcome, the same for every axis, once more at the top.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from gyrolab.record.format import AXIS_NAMES
from gyrolab.record.reader import Recording
from gyrolab.report.causal_section import hysteresis_axes_section
from gyrolab.report.document import Document


def n_axes(
    run: str | Path, model: str | Path | None, log_options: dict | None = None
) -> tuple[int, Recording | None]:
    """Axes of the report: those of the model directory, else those of the run (then the
    recording, read to count them, is returned too, so that it is read once)."""
    if model is not None:
        from gyrolab.compensation.model_dir import ModelDir

        return len(ModelDir(model).axes()), None
    from gyrolab.report.data import read_run

    rec = read_run(run, log_options)
    return rec.axes, rec


def build_axes_report(
    run: str | Path,
    model: str | Path | None,
    n: int,
    step: Any,
    log_options: dict | None = None,
    rec: Recording | None = None,
    **kw: Any,
) -> tuple[Document, dict[str, Any]]:
    """One document with every axis's report (module docstring); ``rec``: the recording
    already read; ``kw`` go to every :func:`~gyrolab.report.build.build_report` (spec,
    operator, serial)."""
    from gyrolab.compensation.model_dir import ModelDir
    from gyrolab.report.build import build_report
    from gyrolab.report.data import read_run

    t0 = time.perf_counter()
    if rec is None:  # read once: every axis's report uses it
        rec = read_run(run, log_options)
    have = rec.axes
    if have != n:
        raise_mismatch(run, have, n)
    dirs = [d.path for _a, d in ModelDir(model).axes()] if model is not None else [None] * n
    doc: Document | None = None
    metrics: dict[str, Any] = {"axes": {}}
    for k in range(n):
        name = AXIS_NAMES[k]
        d, m = build_report(run, dirs[k], step, axis=k, log_options=log_options, rec=rec, **kw)
        metrics["axes"][name] = m
        for sec in d.sections:
            sec.key = f"{name}-{sec.key}"
            sec.title = f"Axis {name} — {sec.title}"
            for b in sec.blocks:
                if hasattr(b, "key"):
                    b.key = f"{name}-{b.key}"
        if doc is None:
            doc = d
            doc.subtitle += f" ({n} axes: {', '.join(AXIS_NAMES[:n])})"
        else:
            doc.sections.extend(d.sections)
    assert doc is not None
    hyst = hysteresis_axes_section(metrics["axes"])
    if hyst is not None:  # after the run section, before the axes' own sections
        doc.sections.insert(1, hyst)
    # one recording: how the run ended is the same for every axis
    metrics["outcome"] = metrics["axes"]["x"].get("outcome", {})
    metrics["timing_s"] = time.perf_counter() - t0
    return doc, metrics


def raise_mismatch(run: str | Path, have: int, want: int) -> None:
    from gyrolab.errors import InputError

    raise InputError(run, f"has {have} gyro axes, the model {want}")
