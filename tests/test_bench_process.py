"""The simulated bench in a process of its own (``acquire --bench sim --units N``;
gyrolab/sim/bench/process.py): its clock seen from the run engine's process, and every way
the run engine can end — SIGTERM, ``kill -9`` — leaves neither the bench's process nor its
pseudo-terminals behind."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from test_acquire import _profile

from gyrolab.acquisition.simdir import MARKER, PREFIX, sweep_stale
from gyrolab.sim.bench.clock import SharedTime, SimClock

ENV = {**os.environ, "GYROLAB_NO_PROGRESS": "1"}


def test_shared_time_follows_the_bench_s_clock_from_another_reader(tmp_path: Path) -> None:
    writer = SharedTime(tmp_path / "clock", create=True)
    reader = SharedTime(tmp_path / "clock")
    clock = SimClock(200.0)
    clock.on_change = writer.publish
    clock.speed = 200.0

    def tick() -> None:
        t = 0.0
        while t < 4.0:
            t += 0.1
            clock.advance_to(t)
        clock.stop()

    th = threading.Thread(target=tick)
    th.start()
    assert reader.sleep(1.0, timeout_wall_s=5.0) and reader.now() >= 1.0
    th.join()
    t, speed, stopped = reader.read()
    assert t == clock.now() and speed == 200.0 and stopped
    assert not reader.sleep(1.0, timeout_wall_s=5.0)  # a stopped clock wakes the sleeper


def _children(pid: int) -> list[int]:
    text = Path(f"/proc/{pid}/task/{pid}/children").read_text()
    return [int(c) for c in text.split()]


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return Path(f"/proc/{pid}").exists() and "Z" not in Path(f"/proc/{pid}/stat").read_text()


def _start(tmp_path: Path, name: str) -> tuple[subprocess.Popen[str], int, Path]:
    """A two-unit acquisition on a long hot step, once it records (its file grows): the
    process, its bench's process and its scratch directory."""
    prof = _profile(tmp_path, [(25, 20), (50, 3600)])
    out = tmp_path / f"{name}.mcap"
    cmd = [sys.executable, "-m", "gyrolab", "acquire", "--bench", "sim", "--units", "2"]
    p = subprocess.Popen(
        [*cmd, "--profile", str(prof), "--speed", "50", "--out", str(out)],
        env=ENV,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline and (not out.exists() or out.stat().st_size < 30_000):
        assert p.poll() is None, p.stderr.read() if p.stderr else ""
        time.sleep(0.05)
    (bench,) = _children(p.pid)
    (work,) = [
        d
        for d in Path(tempfile.gettempdir()).glob(PREFIX + "*")
        if (d / MARKER).read_text().strip() == str(p.pid)
    ]
    assert (work / "adc1").is_symlink() and _alive(bench)
    return p, bench, work


def test_sigterm_and_kill_9_leave_no_bench_process_and_no_ports(tmp_path: Path) -> None:
    # SIGTERM: the run ends its way (safe state verified while the bench still answers),
    # then the bench's process is stopped and the scratch directory removed.
    p, bench, work = _start(tmp_path, "term")
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 130 and "safe state verified" in err, err
    assert not _alive(bench) and not work.exists()
    # kill -9: no code runs in the run engine; the bench's process sees its stdin close,
    # unplugs its ports and exits; the next acquisition sweeps the directory.
    p, bench, work = _start(tmp_path, "kill")
    os.kill(p.pid, signal.SIGKILL)
    p.communicate(timeout=30)
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and _alive(bench):
        time.sleep(0.1)
    assert not _alive(bench)
    assert not (work / "adc1").exists() and not (work / "oven").exists()
    assert work in sweep_stale() and not work.exists()
