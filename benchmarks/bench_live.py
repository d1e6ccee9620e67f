"""The live view's cost: ``gyrolab acquire --bench sim --speed 300`` with and without
``--live`` and a viewer subscribed to every channel.

    python benchmarks/bench_live.py [--profile short] [--speed 300] [--repeats 3]

Each run is a separate ``gyrolab acquire`` process; its CPU time (user + system, from
``wait4``) and wall time are measured, and the recording is checked for gaps. With
``--live`` a second process (a ``websockets`` client speaking the Foxglove WebSocket
protocol) connects, subscribes to every advertised channel — the 1 kHz ``/gyro/adc`` and
``/gyro/rate`` blocks included — and counts what it receives. Runs alternate (off, on, off,
on, ...) so that a change of machine load hits both sides. There is no peer to run beside
it: the figures to meet are "no gap" and a CPU cost small beside the run's own.
docs/live-view.md has the table.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from gyrolab.record.reader import read_recording

CLIENT = r"""
import json, struct, sys, time
from websockets.sync.client import connect
url, seconds = sys.argv[1], float(sys.argv[2])
deadline = time.monotonic() + 60
while True:
    try:
        ws = connect(url, subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"]).__enter__()
        break
    except OSError:
        if time.monotonic() > deadline:
            raise
        time.sleep(0.05)
n = nbytes = 0
subscribed = False
end = time.monotonic() + seconds
try:
    while time.monotonic() < end:
        try:
            m = ws.recv(timeout=0.2)
        except TimeoutError:
            continue
        if isinstance(m, str):
            j = json.loads(m)
            if j["op"] == "advertise":
                subs = [{"id": c["id"], "channelId": c["id"]} for c in j["channels"]]
                ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                subscribed = True
        elif m[0] == 1:
            n += 1
            nbytes += len(m)
except Exception:
    pass  # the server closes when the run ends
print(json.dumps({"messages": n, "bytes": nbytes, "subscribed": subscribed}))
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def one_run(out: Path, profile: str, speed: float, live: bool, seed: int = 0) -> dict:
    cmd = [sys.executable, "-m", "gyrolab", "acquire", "--bench", "sim", "--out", str(out)]
    cmd += ["--profile", profile, "--speed", str(speed), "--seed", str(seed), "--force"]
    env = {**os.environ, "GYROLAB_NO_PROGRESS": "1"}
    client = None
    if live:
        port = _free_port()
        cmd += ["--live", str(port)]
        client = subprocess.Popen(
            [sys.executable, "-c", CLIENT, f"ws://127.0.0.1:{port}", "3600"],
            stdout=subprocess.PIPE,
            text=True,
        )
    t0 = time.monotonic()
    p = subprocess.Popen(cmd, env=env, stderr=subprocess.PIPE, text=True)
    _pid, status, ru = os.wait4(p.pid, 0)
    wall = time.monotonic() - t0
    err = p.stderr.read() if p.stderr else ""
    if status != 0:
        raise SystemExit(f"acquire failed ({status}): {err[-2000:]}")
    res = {
        "live": live,
        "wall_s": wall,
        "cpu_s": ru.ru_utime + ru.ru_stime,
        "max_rss_mb": ru.ru_maxrss / 1024.0,
    }
    rec = read_recording(out, topics=["/gyro/rate"])
    assert rec.rate is not None
    res.update(samples=int(rec.rate.t.size), gaps=len(rec.rate.gaps()))
    for line in err.splitlines():
        if line.startswith("live view:") and "published" in line:
            res["server"] = line.removeprefix("live view: ").strip()
    if client is not None:
        try:
            cout, _ = client.communicate(timeout=5)
        except subprocess.TimeoutExpired:
            client.kill()
            cout, _ = client.communicate()
        res["client"] = json.loads(cout.strip().splitlines()[-1])
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--profile", default="short")
    ap.add_argument("--speed", type=float, default=300.0)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for k in range(args.repeats):
            for live in (False, True):
                r = one_run(Path(d) / f"r{k}{int(live)}.mcap", args.profile, args.speed, live)
                rows.append(r)
                print(json.dumps(r), flush=True)
    for live in (False, True):
        sel = [r for r in rows if r["live"] == live]
        cpu = [r["cpu_s"] for r in sel]
        print(
            f"live={live}: cpu {min(cpu):.2f}-{max(cpu):.2f} s (mean {sum(cpu) / len(cpu):.2f}), "
            f"wall {sum(r['wall_s'] for r in sel) / len(sel):.2f} s, "
            f"gaps {sum(r['gaps'] for r in sel)}"
        )
    print("load:", os.getloadavg())


if __name__ == "__main__":
    main()
