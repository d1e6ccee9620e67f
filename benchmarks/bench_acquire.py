"""Acquisition through the wire-level simulated bench: speed, and crash loss under kill -9.

    python benchmarks/bench_acquire.py speed [--profile paper] [--speed 300] [--units 8]
    python benchmarks/bench_acquire.py kill [--trials 20] [--profile short] [--speed 100]

``speed`` runs ``gyrolab acquire --bench sim`` (the real drivers over real pseudo-
terminals, the simulated 34401A, Watlow F4 and gyro ADC behind them) as a separate
process and reports the wall time, the speed-up over real time and what the recording
holds (samples, gaps, PT100 and oven cadence). There is no reference peer to run beside
it: the figure to meet is ≥ 250× real time (the 13-h ``paper`` profile in ≤ 3 min).
With ``--units N`` it runs ``--bench sim --units N`` (N units, one ADC pty each, the
simulated 34970A scanner) and reports, per unit, the sample-index gaps, and the acquire
process's CPU time per unit and run hour.

``kill`` starts the same run, lets it record for a random time, sends it SIGKILL, runs
``gyrolab recover`` on what is left, and measures the data lost: the run time up to which
the process had *received* ADC samples (streamed unbuffered to a pipe as they arrived,
``GYROLAB_TRACE_FD``) minus the end of the last sample in the recovered file.
docs/reliability.md has the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import select
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from gyrolab.record.format import TOPIC_EVENT, TOPIC_LOG, TOPIC_OVEN, TOPIC_PT100, TOPIC_RATE
from gyrolab.record.reader import list_units, read_recording
from gyrolab.record.recover import recover_recording


def _acquire_cmd(out: Path, profile: str, speed: float | None, seed: int) -> list[str]:
    cmd = [sys.executable, "-m", "gyrolab", "acquire", "--bench", "sim", "--out", str(out)]
    cmd += ["--profile", profile, "--seed", str(seed)]
    if speed is not None:
        cmd += ["--speed", str(speed)]
    return cmd


def speed_run(out: Path, profile: str = "paper", speed: float | None = 300.0, seed: int = 0):
    """One acquisition; returns its figures."""
    env = {**os.environ, "GYROLAB_NO_PROGRESS": "1"}
    t0 = time.monotonic()
    p = subprocess.run(
        _acquire_cmd(out, profile, speed, seed), env=env, capture_output=True, text=True
    )
    wall = time.monotonic() - t0
    if p.returncode != 0:
        raise RuntimeError(f"acquire failed ({p.returncode}): {p.stderr[-2000:]}")
    rec = read_recording(out)
    run_s = float(rec.events[-1]["t"])
    dpt = np.diff(rec.pt100_t)
    dov = np.diff(rec.oven_t)
    return {
        "profile": profile,
        "speed_asked": speed if speed is not None else "max",
        "wall_s": round(wall, 1),
        "run_s": round(run_s, 1),
        "speedup": round(run_s / wall, 1),
        "samples": int(rec.adc.index.size),
        "gaps": len(rec.adc.gaps()),
        "pt100_readings": int(rec.pt100_t.size),
        "pt100_interval_s_median_p99_max": [
            round(float(x), 1) for x in np.percentile(dpt, [50, 99, 100])
        ],
        "oven_interval_s_median_p99_max": [
            round(float(x), 1) for x in np.percentile(dov, [50, 99, 100])
        ],
        "pt100_range_c": [round(float(rec.pt100_c.min()), 2), round(float(rec.pt100_c.max()), 2)],
        "file_mb": round(out.stat().st_size / 1e6, 1),
        "faults_logged": sum(1 for m in rec.logs if m.get("kind") == "fault"),
        "stderr_tail": p.stderr.strip().splitlines()[-1:],
    }


def _cpu_s(pid: int) -> float | None:
    """User + system CPU seconds of process ``pid`` so far (None: it is gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _children(pid: int) -> list[int]:
    try:
        return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


def _pace(received: list[tuple[float, float]]) -> dict[str, float]:
    """Run seconds per wall second from the first received sample to the last, and the
    slowest pace over any 10 % of the run (a stall the clock never makes up)."""
    if len(received) < 2:
        return {}
    wall = np.array([w for w, _ in received])
    run = np.array([t for _, t in received])
    k = max(1, len(run) // 10)
    paces = (run[k:] - run[:-k]) / np.maximum(wall[k:] - wall[:-k], 1e-9)
    return {
        "run_s": round(float(run[-1] - run[0]), 1),
        "wall_s": round(float(wall[-1] - wall[0]), 1),
        "speedup": round(float((run[-1] - run[0]) / (wall[-1] - wall[0])), 1),
        "slowest_tenth_speedup": round(float(paces.min()), 1),
    }


def units_run(
    out: Path, units: int = 8, profile: str = "paper", speed: float | None = 300.0, seed: int = 0
) -> dict[str, Any]:
    """``gyrolab acquire --bench sim --units N``: wall time, the process's CPU time per unit
    and run hour (``RUSAGE_CHILDREN``: the whole acquire process, simulated instruments
    included), and every unit's stream checked for gaps by its sample indices."""
    cmd = _acquire_cmd(out, profile, speed, seed) + ["--units", str(units)]
    # the first unit's samples, as the run engine receives them (GYROLAB_TRACE_FD): the
    # pace kept in the run itself, apart from the bench's start, the connect phase (at
    # the bench's connect speed) and the shutdown, which the overall figure includes
    r, w = os.pipe()
    env = {**os.environ, "GYROLAB_NO_PROGRESS": "1", "GYROLAB_TRACE_FD": str(w)}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    load_before = os.getloadavg()[0]
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, env=env, stderr=subprocess.PIPE, text=True, pass_fds=(w,))
    os.close(w)
    received: list[tuple[float, float]] = []  # (wall s, run s received to)

    def trace() -> None:
        with os.fdopen(r) as f:
            for line in f:
                received.append((time.monotonic(), float(line)))

    tracer = threading.Thread(target=trace, daemon=True)
    tracer.start()
    # The run engine's and the simulated bench's process (its child, when it has one):
    # each one's CPU seconds, sampled from /proc until they end (the last sample counts).
    per_process: dict[str, float] = {}
    err: list[str] = []
    at_end: dict[str, float] = {}  # the run engine's CPU when its run ended (before it registers)

    def drain() -> None:
        for line in proc.stderr:
            err.append(line)
            if line.startswith("gyrolab acquire: ") and " recorded in " in line:
                at_end["run engine"] = _cpu_s(proc.pid) or 0.0

    drainer = threading.Thread(target=drain, daemon=True)
    drainer.start()
    while proc.poll() is None:
        per_process["run engine"] = _cpu_s(proc.pid) or per_process.get("run engine", 0.0)
        for child in _children(proc.pid):
            per_process["simulated bench"] = _cpu_s(child) or per_process.get(
                "simulated bench", 0.0
            )
        time.sleep(0.5)
    drainer.join()
    tracer.join()
    wall = time.monotonic() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    stderr = "".join(err)
    if proc.returncode != 0:
        raise RuntimeError(f"acquire failed ({proc.returncode}): {stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    serials = list_units(out)
    shared = read_recording(out, topics=[TOPIC_EVENT, TOPIC_LOG, TOPIC_OVEN], unit=serials[0])
    run_s = float(shared.events[-1]["t"])
    per_unit = []
    for s in serials:
        rec = read_recording(out, topics=[TOPIC_RATE, TOPIC_PT100], unit=s)
        rate = rec.require_rate()
        dpt = np.diff(rec.pt100_t)
        per_unit.append(
            {
                "unit": s,
                "samples": int(rate.index.size),
                "index_gaps": len(rate.gaps()),
                "samples_missing": int(sum(n for _, n in rate.gaps())),
                "pt100_interval_s_median_p99_max": [
                    round(float(x), 1) for x in np.percentile(dpt, [50, 99, 100])
                ],
            }
        )
    return {
        "profile": profile,
        "units": len(serials),
        "speed_asked": speed if speed is not None else "max",
        "wall_s": round(wall, 1),
        "run_s": round(run_s, 1),
        "speedup": round(run_s / wall, 1),
        "in_run": _pace(received),
        "cpu_s": round(cpu, 1),
        # each process's CPU against the wall time the asked speed allows: below 1, the
        # process needs less than a core to keep up
        "cpu_s_per_process": {k: round(v, 1) for k, v in per_process.items()},
        "cores_needed_at_asked_speed": {
            k: round(v / (run_s / speed), 2) for k, v in per_process.items() if speed
        },
        "cpu_s_per_unit_per_run_hour": round(cpu / len(serials) / (run_s / 3600.0), 2),
        # the load-independent figure: each process's CPU seconds per unit and simulated hour
        "cpu_s_per_unit_per_run_hour_per_process": {
            k: round(v / len(serials) / (run_s / 3600.0), 2) for k, v in per_process.items()
        },
        # the run engine's CPU up to the end of its run, and after (the catalogue entry)
        "run_engine_cpu_s_run_and_after": [
            round(at_end.get("run engine", 0.0), 1),
            round(per_process.get("run engine", 0.0) - at_end.get("run engine", 0.0), 1),
        ],
        "suspensions": sum(1 for e in shared.events if e["event"] == "suspended"),
        "faults_logged": sum(1 for m in shared.logs if m.get("kind") == "fault"),
        "outcome": shared.events[-2]["event"] if len(shared.events) > 1 else "?",
        "load_before_after": [round(load_before, 2), round(os.getloadavg()[0], 2)],
        "gaps_total": sum(u["index_gaps"] for u in per_unit),
        "gap_logs": sum(1 for m in shared.logs if m.get("kind") == "gap"),
        "units_dropped": [
            m["data"]["unit"] for m in shared.logs if m.get("kind") == "unit_dropped"
        ],
        "file_mb": round(out.stat().st_size / 1e6, 1),
        "per_unit": per_unit,
        "stderr_tail": stderr.strip().splitlines()[-1:],
    }


def kill_trial(
    work: Path,
    name: str,
    *,
    kill_after_s: float,
    profile: str = "short",
    speed: float = 100.0,
    seed: int = 0,
) -> dict[str, Any]:
    """Start an acquisition, SIGKILL it ``kill_after_s`` wall seconds after its first
    received sample, recover the file and measure the loss (run seconds of ADC data)."""
    out = work / f"{name}.mcap"
    fixed = work / f"{name}-recovered.mcap"
    r, w = os.pipe()
    env = {**os.environ, "GYROLAB_NO_PROGRESS": "1", "GYROLAB_TRACE_FD": str(w)}
    p = subprocess.Popen(
        _acquire_cmd(out, profile, speed, seed),
        env=env,
        pass_fds=(w,),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    os.close(w)
    buf = b""
    deadline = time.monotonic() + 60.0
    # Wait for the first received samples (the run is recording), then the random delay.
    while b"\n" not in buf:
        if time.monotonic() > deadline or p.poll() is not None:
            p.kill()
            raise RuntimeError(f"acquire did not start: {p.stderr.read().decode()[-2000:]}")
        ready, _, _ = select.select([r], [], [], 0.1)
        if ready:
            buf += os.read(r, 65536)
    time.sleep(kill_after_s)
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    p.stderr.close()
    while True:  # the rest of the trace: everything the process wrote before dying
        chunk = os.read(r, 65536)
        if not chunk:
            break
        buf += chunk
    os.close(r)
    received_to = float(buf.split()[-1])
    size = out.stat().st_size
    rep = recover_recording(out, fixed)
    rec = read_recording(fixed)
    kept_to = float(rec.adc.t[-1] + rec.adc.period) if rec.adc.t.size else 0.0
    idx = rec.adc.index
    return {
        "kill_after_s": round(kill_after_s, 3),
        "file_bytes": size,
        "received_to_s": round(received_to, 3),
        "recovered_to_s": round(kept_to, 3),
        "lost_s": round(received_to - kept_to, 3),
        "messages": rep.message_count,
        "truncated_tail_bytes": rep.truncated_tail_bytes,
        "chunks_damaged": rep.chunks_damaged,
        # the recovered stream is whole: consecutive, never repeated sample indices
        "contiguous": bool(idx.size == 0 or np.array_equal(idx, np.arange(idx[0], idx[-1] + 1))),
    }


def kill_campaign(
    trials: int,
    *,
    profile: str = "short",
    speed: float = 100.0,
    seed: int = 0,
    max_delay_s: float = 6.0,
    work: Path | None = None,
) -> list[dict[str, Any]]:
    rng = np.random.default_rng(seed)
    with tempfile.TemporaryDirectory(prefix="gyrolab-kill-") as tmp:
        base = work or Path(tmp)
        return [
            kill_trial(
                base,
                f"kill{k}",
                kill_after_s=float(rng.uniform(0.05, max_delay_s)),
                profile=profile,
                speed=speed,
                seed=k,
            )
            for k in range(trials)
        ]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("speed")
    s.add_argument("--profile", default="paper")
    s.add_argument("--speed", type=float, default=300.0, help="0 = as fast as it goes")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--units", type=int, default=0, help="N > 0: --bench sim --units N")
    k = sub.add_parser("kill")
    k.add_argument("--trials", type=int, default=20)
    k.add_argument("--profile", default="short")
    k.add_argument("--speed", type=float, default=100.0)
    k.add_argument("--seed", type=int, default=0)
    k.add_argument("--max-delay", type=float, default=6.0)
    a = ap.parse_args(argv)
    from machine import stamp  # here: tests load this file by path, without benchmarks/ on sys.path

    print(stamp())
    if a.cmd == "speed":
        with tempfile.TemporaryDirectory() as tmp:
            if a.units:
                res = units_run(Path(tmp) / "run.mcap", a.units, a.profile, a.speed or None, a.seed)
            else:
                res = speed_run(Path(tmp) / "run.mcap", a.profile, a.speed or None, a.seed)
        print(json.dumps(res, indent=1))
    else:
        rows = kill_campaign(
            a.trials, profile=a.profile, speed=a.speed, seed=a.seed, max_delay_s=a.max_delay
        )
        for row in rows:
            print(json.dumps(row))
        lost = np.array([row["lost_s"] for row in rows])
        print(
            f"# {len(rows)} kills: all recovered; loss s: max {lost.max():.3f}, "
            f"median {np.median(lost):.3f}, mean {lost.mean():.3f}; "
            f"all contiguous: {all(row['contiguous'] for row in rows)}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
