"""Per-axis compensation of 1–3-axis units: one single-axis model per axis.

The single-axis model (:mod:`.fit`, :mod:`.apply`) is unchanged; a unit with several axes
is a loop over it, and its model directory holds one single-axis model directory per axis
(:class:`~gyrolab.compensation.model_dir.ModelDir`: ``axis_x/``, ``axis_y/``, ``axis_z/``
and a head naming them). :func:`load_runs` reads a run of any axis count as one prepared
run per axis.
"""

from __future__ import annotations

from typing import Any

from gyrolab.compensation.config import PipelineConfig
from gyrolab.compensation.prepare import PreparedRun, prepare_file, prepare_run


def load_runs(path: str, cfg: PipelineConfig, **log_options: Any) -> list[PreparedRun]:
    """One :class:`~.prepare.PreparedRun` per axis of the run at ``path``.

    A single-axis gyrolab MCAP is streamed from the file (:func:`.prepare.prepare_file`,
    bounded memory, exactly as before); a multi-axis recording or a foreign log (ROS 2
    MCAP, PX4 ULog, ArduPilot DataFlash: :func:`gyrolab.logs.read_log` with
    ``log_options``) is read into memory and prepared axis by axis
    (:func:`.prepare.prepare_run`)."""
    from gyrolab.logs import read_log, single_axis_gyrolab

    if single_axis_gyrolab(path):
        return [prepare_file(path, cfg)]
    rec = read_log(path, **log_options)
    return [prepare_run(rec.axis(k), cfg) for k in range(rec.axes)]
