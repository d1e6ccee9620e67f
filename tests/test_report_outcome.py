"""The report says how a run ended: complete, aborted, interrupted, recovered.

Each run is a real ``acquire --bench sim`` (drivers over pseudo-terminals), kept short:
a two-step profile at 50x. The watchdog run uses the in-process path of
tests/test_acquire.py (a tight PT100 limit); SIGINT and kill -9 go to a subprocess.
"""

from __future__ import annotations

import glob
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from test_acquire import _profile, _run_in_process

from gyrolab.acquisition.simdir import MARKER, PREFIX, SCRATCH_ENV, scratch_root, sweep_stale
from gyrolab.cli import main
from gyrolab.record.reader import read_recording
from gyrolab.report.build import build_report
from gyrolab.report.outcome import run_outcome
from gyrolab.report.record_sections import run_log_rows

ENV = {**os.environ, "GYROLAB_NO_PROGRESS": "1"}


@pytest.fixture(scope="module", autouse=True)
def own_scratch(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """The simulated bench's scratch directories go in this module's own directory (in
    process and in the subprocesses), not the machine's /tmp: another gyrolab run on the
    machine sweeps /tmp's dead ones, and would take the kill -9 run's from under the test."""
    root = tmp_path_factory.mktemp("scratch")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(SCRATCH_ENV, str(root))
        mp.setitem(ENV, SCRATCH_ENV, str(root))
        yield root


def _acquire_cmd(prof: Path, out: Path) -> list[str]:
    return [
        sys.executable, "-m", "gyrolab", "acquire", "--bench", "sim", "--profile", str(prof),
        "--speed", "50", "--out", str(out),
    ]  # fmt: skip


def _start_and_wait(prof: Path, out: Path) -> subprocess.Popen[str]:
    """Start an acquisition; return once it has flushed data (the file grows by chunks).
    No wall-clock limit: the run is long, so it either gets there or ends (asserted)."""
    p = subprocess.Popen(_acquire_cmd(prof, out), env=ENV, stderr=subprocess.PIPE, text=True)
    while not out.exists() or out.stat().st_size < 30_000:
        assert p.poll() is None, p.stderr.read() if p.stderr else ""
        time.sleep(0.05)
    return p


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("outcomes")
    out: dict[str, Path] = {}
    # complete: 25 °C then 27 °C, 40 s of run time
    prof = _profile(tmp, [(25, 20), (27, 20)])
    out["complete"] = tmp / "complete.mcap"
    assert main(_acquire_cmd(prof, out["complete"])[3:]) == 0
    # aborted: the PT100 watchdog (limit 26 °C) while heating to 60 °C
    from gyrolab.acquisition.bench_config import Limits
    from gyrolab.sim.bench import FaultPlan

    wd = tmp / "wd"
    wd.mkdir()
    res, _, _ = _run_in_process(
        wd, _profile(wd, [(25, 30), (60, 900)]), speed=50.0, faults=FaultPlan(),
        limits=Limits(pt100_max_c=26.0),
    )  # fmt: skip
    assert res.outcome == "fault"
    out["aborted"] = wd / "run.mcap"
    # interrupted (SIGINT) and killed (kill -9, then recovered): a long hot step
    long = _profile(tmp, [(25, 30), (60, 3600)])
    out["interrupted"] = tmp / "int.mcap"
    p = _start_and_wait(long, out["interrupted"])
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 130, err
    out["interrupted_pid"] = Path(str(p.pid))
    killed = tmp / "killed.mcap"
    p = _start_and_wait(long, killed)
    os.kill(p.pid, signal.SIGKILL)
    p.communicate(timeout=30)
    out["killed"] = killed
    out["killed_pid"] = Path(str(p.pid))
    out["recovered"] = tmp / "recovered.mcap"
    assert main(["recover", str(killed), "--out", str(out["recovered"])]) == 0
    return out


def _outcome_line(rec_path: Path, tmp_path: Path) -> tuple[str, dict, str]:
    rep = tmp_path / f"rep-{rec_path.stem}"
    assert main(["report", str(rec_path), "--out", str(rep)]) == 0
    m = json.loads((rep / "metrics.json").read_text())
    html = (rep / "index.html").read_text(encoding="utf-8")
    return m["outcome"]["line"], m, html


def test_complete_run(runs: dict[str, Path], tmp_path: Path) -> None:
    line, m, html = _outcome_line(runs["complete"], tmp_path)
    assert line == "complete — profile complete; oven in safe state (setpoint 25 °C verified)"
    assert m["outcome"]["status"] == "complete" and 'class="st st-complete"' in html
    # coverage: the profile 25…27 °C, the chamber and case ranges as recorded
    rec = read_recording(runs["complete"])
    cov = m["coverage"]
    assert cov["profile_c"] == [25.0, 27.0]
    assert cov["case_c"] == [pytest.approx(rec.pt100_c.min()), pytest.approx(rec.pt100_c.max())]
    assert cov["samples"] == rec.rate.t.size and cov["gaps"] == 0
    assert "temperatures reached" in html and "gyro case covered" in html
    # a clean run's safe state is a row of the log, neither a fault nor counted as one
    rows, counts = run_log_rows(rec)
    safe = [r for r in rows if r[3] == "safe_state"]
    assert len(safe) == 1 and safe[0][1] == "info" and "safe_state" not in counts
    assert not any(r[1] == "fault" for r in rows) and "fault" not in counts


def test_aborted_run(runs: dict[str, Path], tmp_path: Path) -> None:
    line, m, _ = _outcome_line(runs["aborted"], tmp_path)
    assert line.startswith("aborted — ") and "over-temperature" in line
    assert line.endswith("; oven in safe state (setpoint 25 °C verified)")
    rows, counts = run_log_rows(read_recording(runs["aborted"]))
    assert counts.get("abort") == 1 and counts.get("fault", 0) >= 1


def test_interrupted_run(runs: dict[str, Path], tmp_path: Path) -> None:
    line, m, html = _outcome_line(runs["interrupted"], tmp_path)
    safe = "oven in safe state (setpoint 25 °C verified)"
    assert line == f"interrupted — interrupted by SIGINT; {safe}"
    assert 'class="st st-interrupted"' in html


def test_recovered_run(runs: dict[str, Path], tmp_path: Path) -> None:
    line, m, html = _outcome_line(runs["recovered"], tmp_path)
    assert line.startswith("recovered (") and "s lost, safe state not confirmed)" in line
    assert "cut short" in line and m["outcome"]["status"] == "recovered"
    rec = read_recording(runs["recovered"])
    assert rec.metadata["recovery"]["source"] == "killed.mcap"
    assert rec.metadata["recovery"]["end_event"] == ""
    assert 'class="st st-recovered"' in html


def _scratch_dirs(pid: int) -> list[Path]:
    """The ``gyrolab-sim-*`` directories whose owner marker names ``pid``."""
    out = []
    for d in glob.glob(os.path.join(scratch_root(), PREFIX + "*")):
        try:
            if int((Path(d) / MARKER).read_text()) == pid:
                out.append(Path(d))
        except (OSError, ValueError):
            continue
    return out


def test_scratch_directories_are_removed_on_every_exit_path(runs: dict[str, Path]) -> None:
    # normal end (in process) and SIGINT (subprocess): removed by the process itself
    assert _scratch_dirs(os.getpid()) == []
    assert _scratch_dirs(int(str(runs["interrupted_pid"]))) == []
    # kill -9 runs no code: the directory stays until the next acquisition sweeps it
    (left,) = _scratch_dirs(int(str(runs["killed_pid"])))
    foreign = Path(tempfile.mkdtemp(prefix=PREFIX, dir=scratch_root()))  # no marker: kept
    try:
        assert left in sweep_stale() and not left.exists() and foreign.exists()
    finally:
        foreign.rmdir()


def test_sigterm_while_the_bench_starts_still_removes_the_scratch_directory(
    tmp_path: Path,
) -> None:
    prof = _profile(tmp_path, [(25, 30)])
    p = subprocess.Popen(
        _acquire_cmd(prof, tmp_path / "t.mcap"), env=ENV, stderr=subprocess.PIPE, text=True
    )
    while not _scratch_dirs(p.pid):  # it makes it, or ends without it (asserted)
        assert p.poll() is None, f"ended before its scratch directory: {p.communicate()[1]}"
        time.sleep(0.01)
    p.send_signal(signal.SIGTERM)
    p.communicate(timeout=60)
    assert p.returncode == 130 and _scratch_dirs(p.pid) == []


def test_sigterm_at_any_moment_of_an_acquisition_ends_with_exit_130(tmp_path: Path) -> None:
    """SIGTERM from the first moment of the bench's start-up to the run: exit 130 every time,
    the scratch directory removed, and a signal that lands in the run ends it the runner's
    way (safe state verified). Before the fix about 1 in 10 of these ended with exit status -2 (the
    signal's KeyboardInterrupt raised inside scipy's ``exec`` while numba was importing;
    gyrolab/acquisition/interrupts.py) or exit 0 (raised in an llvmlite ctypes callback,
    printed as "Exception ignored" and lost). Eight runs at once, each signalled at its own
    delay after its scratch directory appeared."""
    prof = _profile(tmp_path, [(25, 60)])  # 1.2 s of run at 50x: every delay lands in time
    delays = [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.8]
    procs = [
        subprocess.Popen(
            _acquire_cmd(prof, tmp_path / f"t{i}.mcap"),
            env=ENV,
            stderr=subprocess.PIPE,
            text=True,
        )
        for i in range(len(delays))
    ]
    t_dir: dict[int, float] = {}
    sent: set[int] = set()
    # No wall-clock limit on the start-ups (eight at once on two cores: a loaded machine
    # stretches them past any fixed one): each is signalled after its directory appeared,
    # or has ended (asserted).
    while len(sent) < len(procs):
        for i, p in enumerate(procs):
            if i in sent:
                continue
            assert p.poll() is None, f"run {i} ended before its signal: {p.communicate()[1]}"
            if i not in t_dir and _scratch_dirs(p.pid):
                t_dir[i] = time.monotonic()
            if i in t_dir and time.monotonic() - t_dir[i] >= delays[i]:
                p.send_signal(signal.SIGTERM)
                sent.add(i)
        time.sleep(0.005)
    for d, p in zip(delays, procs, strict=True):
        _, err = p.communicate(timeout=60)
        assert p.returncode == 130, f"delay {d} s: exit {p.returncode}: {err}"
        in_run = "interrupted (interrupted by SIGTERM)" in err
        assert "Exception ignored" not in err, f"delay {d} s: {err}"
        assert "gyrolab: interrupted" in err or (in_run and "safe state verified" in err), err
        assert _scratch_dirs(p.pid) == [], f"delay {d} s: scratch directory left"


def test_a_stop_signal_in_the_deferred_scope_is_acted_on_where_the_code_chooses() -> None:
    """The mechanism, deterministically: a SIGTERM that lands while ``exec`` runs (where
    the old handler's KeyboardInterrupt left CPython's "unhandled KeyboardInterrupt" flag
    set, so the process died by SIGINT after returning 130) is only noted, raised at the
    scope's end, and the process exits 130; a second signal raises at once."""
    code = """if True:
        import os, signal, sys
        from gyrolab.acquisition import interrupts
        try:
            with interrupts.deferred_stop_signals():
                os.kill(os.getpid(), signal.SIGTERM)
                exec("x = sum(range(1000))")
                assert interrupts.pending() == "SIGTERM"
                print("exec done", file=sys.stderr)
        except KeyboardInterrupt as e:
            print("interrupted by", e, file=sys.stderr)
        try:
            with interrupts.deferred_stop_signals():
                os.kill(os.getpid(), signal.SIGHUP)
                os.kill(os.getpid(), signal.SIGINT)
                exec("x = sum(range(1000))")
                print("not reached", file=sys.stderr)
        except KeyboardInterrupt as e:
            print("at once:", e, file=sys.stderr)
        assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
        sys.exit(130)
    """
    r = subprocess.run([sys.executable, "-c", code], env=ENV, capture_output=True, text=True)
    assert r.returncode == 130, r.stderr
    assert r.stderr.splitlines() == ["exec done", "interrupted by SIGTERM", "at once: SIGINT"]


def test_report_outcome_from_events_without_a_log(tmp_path: Path) -> None:
    """A recording with events but no /log end messages still gets its outcome."""
    from gyrolab.record.writer import RecordingWriter

    path = tmp_path / "x.mcap"
    with RecordingWriter(path, start_time_ns=0, run={"source": "acquire"}) as w:
        import numpy as np

        w.write_rate_block(0.0, 0.1, 0, np.zeros(200))
        w.write_event(10.0, "aborted", 1, 60.0, "lost communication with oven")
        w.write_event(11.0, "safe_state", -1, None, "FAILED: TimeoutError")
    rec = read_recording(path)
    o = run_outcome(rec)
    assert o.status == "aborted" and o.safe_state == "failed"
    assert o.line == (
        "aborted — lost communication with oven; oven safe state FAILED (TimeoutError)"
    )
    rows, counts = run_log_rows(rec)
    assert [r[3] for r in rows] == ["abort", "fault"] and counts["fault"] == 1
    doc, _ = build_report(path)
    assert dict(doc.summary)["run outcome"] == o.line


def test_a_stopped_stream_counts_as_a_gap_in_the_header(tmp_path: Path) -> None:
    """The acquisition logs a stream that stopped as a gap to the end of the run (no jump
    in the sample index shows it): the header's samples line counts it."""
    import numpy as np

    from gyrolab.record.writer import RecordingWriter
    from gyrolab.report.outcome import run_coverage

    path = tmp_path / "stopped.mcap"
    with RecordingWriter(path, start_time_ns=0, run={"source": "acquire"}) as w:
        w.write_rate_block(0.0, 0.1, 0, np.zeros(600))  # 60 s, then nothing until 120 s
        w.write_log(
            120.0, "warning", "adc", "ADC gap: stream stopped", "gap",
            {"first_missing_index": 600, "n_missing": 600, "t_first_missing": 60.0,
             "t_end": 120.0, "cause": "stream stopped"},
        )  # fmt: skip
        w.write_event(120.0, "aborted", 0, 25.0, "lost communication with adc")
    cov = run_coverage(read_recording(path))
    assert (cov.gaps, cov.samples_missing, cov.gap_s) == (1, 600, pytest.approx(60.0))
    assert "1 gap(s), 600 samples missing (60.0 s)" in cov.samples_line()
