"""Resume after an interruption (``gyrolab acquire --resume``; gyrolab/acquisition/resume.py,
docs/recording-format.md "Segments"): a ``kill -9`` mid-profile, then the continuation;
the run reads as one, its gap marked and never filled in, and the report says so."""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from gyrolab.cli import main
from gyrolab.record.reader import read_metadata, read_recording, segments

PROFILE = """name = "resume"
[[step]]
setpoint_c = 25
duration_s = 60
[[step]]
setpoint_c = 35
duration_s = 120
[[step]]
setpoint_c = 30
duration_s = 60
"""


def _killed_mid_step_2(tmp_path: Path, extra: tuple[str, ...] = ()) -> Path:
    """``acquire --bench sim`` (and ``extra`` arguments) killed with SIGKILL once its
    samples reach 100 s of run time (step 2 runs from 60 to 180 s), told by the run itself
    (GYROLAB_TRACE_FD)."""
    prof = tmp_path / "p.toml"
    prof.write_text(PROFILE, encoding="utf-8")
    out = tmp_path / "run.mcap"
    r, w = os.pipe()
    cmd = [sys.executable, "-m", "gyrolab", "acquire", "--bench", "sim", "--profile", str(prof)]
    env = {**os.environ, "GYROLAB_NO_PROGRESS": "1", "GYROLAB_TRACE_FD": str(w)}
    p = subprocess.Popen(
        [*cmd, "--speed", "40", "--seed", "4", *extra, "--out", str(out)],
        env=env,
        pass_fds=(w,),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    os.close(w)
    got, deadline = b"", time.monotonic() + 120.0
    try:
        while time.monotonic() < deadline:
            if select.select([r], [], [], 1.0)[0]:
                chunk = os.read(r, 65536)
                if not chunk:
                    break
                got += chunk
                lines = got.split(b"\n")
                if len(lines) > 1 and float(lines[-2]) >= 100.0:
                    p.send_signal(signal.SIGKILL)
                    break
    finally:
        os.close(r)
        p.kill()
        p.wait()
    assert p.returncode == -signal.SIGKILL
    return out


def test_kill_9_then_resume_completes_the_profile_as_one_run_with_one_gap(
    tmp_path: Path, capsys
) -> None:
    out = _killed_mid_step_2(tmp_path)
    assert main(["acquire", "--resume", str(out), "--speed", "40"]) == 0
    err = capsys.readouterr().err
    assert "was cut short" in err and "segment 2 of run" in err
    cont = tmp_path / "run.seg2.mcap"
    recovered = tmp_path / "run.recovered.mcap"
    assert segments(cont) == [recovered, cont]  # the cut file is kept, untouched
    # The catalogue knows the run as one run of its two segments (docs/catalogue.md).
    assert main(["runs", "list", "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    runs = listed["runs"] if isinstance(listed, dict) else listed
    (run,) = [r for r in runs if len(r.get("segments", [])) == 2]
    assert [s["number"] for s in run["segments"]] == [1, 2]
    rec = read_recording(cont)
    # One run: the first segment's identity, its two segments, one interruption.
    ((after, at),) = rec.interruptions
    assert 100.0 - 2.0 <= after < 180.0 and at > after + 1.0  # ≤ 2 s lost to the kill
    meta = read_metadata(cont)["run"]
    assert [s["segment"] for s in meta["segments"]] == [1, 2]
    assert meta["segments"][0]["recovery"]["source"] == "run.mcap"
    # The steps before the interruption are not repeated: step 1 ran once, step 2 (the
    # one running) started again at the resumption (a re-soak), step 3 followed.
    starts = [(e["step"], e["t"], e["detail"]) for e in rec.events if e["event"] == "step_started"]
    assert [s[0] for s in starts] == [0, 1, 1, 2]
    assert starts[2][1] == pytest.approx(at, abs=1e-6) and starts[2][2].endswith("(re-soak)")
    assert rec.events[-2]["event"] == "run_ended" and rec.events[-1]["event"] == "safe_state"
    assert [e["event"] for e in rec.events].count("run_resumed") == 1
    # One gap in the data, marked, not filled: the sample index jumps over it and /log says so.
    rate = rec.require_rate()
    ((t_gap, n_missing),) = rate.gaps()
    # the last sample before it: within the crash-loss window of the last message
    assert after - 3.0 <= t_gap <= after
    assert n_missing == pytest.approx((at - t_gap) * 100, abs=60)
    assert not ((rate.t > t_gap + 0.5) & (rate.t < at - 1e-3)).any()
    (gap_log,) = [m for m in rec.logs if m.get("data", {}).get("cause") == "run interrupted"]
    assert gap_log["data"]["n_missing"] == n_missing
    assert np.all(np.diff(rate.t) > 0)
    # The report: one run, its interruption and resumption stated, the gap counted once.
    assert main(["report", str(cont), "--out", str(tmp_path / "rep")]) == 0
    html = (tmp_path / "rep" / "index.html").read_text(encoding="utf-8")
    assert "interrupted after" in html and "resumed at" in html
    metrics = json.loads((tmp_path / "rep" / "metrics.json").read_text())
    assert metrics.get("outcome", {}).get("status", "complete") == "complete"


def _one_gap_and_the_step_re_soaked(cont: Path, unit: str | None = None) -> np.ndarray:
    """The continuation ``cont`` read as one run (of ``unit``): one interruption, one
    marked gap in the samples over it, steps 1 and 3 once and step 2 re-soaked, the
    profile complete; returns its rates."""
    rec = read_recording(cont, unit=unit)
    ((after, at),) = rec.interruptions
    assert 100.0 - 2.0 <= after < 180.0 and at > after + 1.0
    starts = [e["step"] for e in rec.events if e["event"] == "step_started"]
    assert starts == [0, 1, 1, 2] and rec.events[-2]["event"] == "run_ended"
    rate = rec.require_rate()
    ((t_gap, _n),) = rate.gaps()
    assert after - 3.0 <= t_gap <= after
    assert not ((rate.t > t_gap + 0.5) & (rate.t < at - 1e-3)).any()
    return rate.values


def test_a_three_axis_run_resumes_the_same_way(tmp_path: Path, capsys) -> None:
    """A simulated 3-axis unit (``--axis-model`` twice): the continuation rebuilds the
    same three axes from the run's own record (``sim_provenance_axes``), nothing given."""
    from gyrolab.record.reader import read_metadata
    from gyrolab.sim.model import nominal_model

    base = nominal_model().to_toml()
    y, z = tmp_path / "y.toml", tmp_path / "z.toml"
    y.write_text(base.replace("c1 = 0.000384", "c1 = -0.0005"))
    z.write_text(base.replace("c0 = 0.02", "c0 = -0.05"))
    out = _killed_mid_step_2(tmp_path, ("--axis-model", str(y), "--axis-model", str(z)))
    # the run fixed its axes: they cannot be given again
    assert main(["acquire", "--resume", str(out), "--axis-model", str(y)]) == 2
    assert main(["acquire", "--resume", str(out), "--speed", "40"]) == 0
    cont = tmp_path / "run.seg2.mcap"
    values = _one_gap_and_the_step_re_soaked(cont)
    assert values.ndim == 2 and values.shape[1] == 3
    assert read_recording(cont).run["axes"] == 3
    axes = [read_metadata(f)["sim_provenance_axes"] for f in segments(cont)]
    assert axes[0] == axes[1] and axes[0]["models_toml"][1] == z.read_text()
    # the z axis (bias -0.05 °/s) is still the z axis after the resumption
    assert values[-1000:, 2].mean() < values[-1000:, 0].mean() - 0.03
    capsys.readouterr()


def test_a_multi_unit_run_resumes_every_unit(tmp_path: Path, capsys) -> None:
    """Two units in one chamber (``--units 2``): one continuation, every unit's stream
    with its one marked gap."""
    out = _killed_mid_step_2(tmp_path, ("--units", "2"))
    assert main(["acquire", "--resume", str(out), "--speed", "40"]) == 0
    cont = tmp_path / "run.seg2.mcap"
    for unit in ("SIM4-01", "SIM4-02"):
        _one_gap_and_the_step_re_soaked(cont, unit)
    capsys.readouterr()
