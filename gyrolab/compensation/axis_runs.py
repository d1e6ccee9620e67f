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
