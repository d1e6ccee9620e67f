"""The run engine's per-read path for N units, in one thread, without the bench's timing:
the ``gyroadc`` driver reading frames from real pseudo-terminals, each unit's
``RateRecorder`` turning the read into recorded blocks, and the recorder's flush every
simulated second — once with reads of one simulated second (a 1 s bench tick each, what
the readers did at 300x before ``READ_MIN_INTERVAL_S``) and once with reads of K seconds
(at 300x a read every 10 ms of wall time holds ~3), the ratio printed.

    python benchmarks/bench_read_path.py [--units 8] [--seconds 600] [--ticks 3]

CPU is this process's (``time.process_time``), split into the driver's read and the
recording; the cores that path needs at 300x are printed beside it. The engine's threads,
queue, pollers and GIL hand-overs are not in it (``bench_acquire.py speed`` measures the
whole process).
"""

from __future__ import annotations

import argparse
import io
import os
import pty
import time
import tty

import numpy as np
from machine import stamp

from gyrolab.acquisition.streams import RateRecorder
from gyrolab.framing import encode_frame
from gyrolab.instruments.drivers.gyroadc import GyroAdcConfig, GyroAdcReader
from gyrolab.record.writer import RecordingWriter

FRAMES_PER_S = 10  # the simulated ADC: 100 Hz, 10 samples a frame


def run(units: int, seconds: int, ticks: int) -> tuple[float, float, int]:
    """CPU seconds (read, record) for ``seconds`` simulated seconds read ``ticks`` at a
    time, and the samples recorded."""
    rng = np.random.default_rng(0)
    frames = [
        encode_frame(k, int(k * 1e5), rng.integers(-1000, 1000, 10))
        for k in range(FRAMES_PER_S * (seconds + ticks))
    ]
    w = RecordingWriter(
        io.BytesIO(),
        start_time_ns=0,
        flush_every_s=1.0,
        units=[f"U{u}" for u in range(units)],
    )
    ports, recs, fds = [], [], []
    for u in range(units):
        master, slave = pty.openpty()
        tty.setraw(master)
        tty.setraw(slave)
        fds += [master, slave]
        reader = GyroAdcReader(os.ttyname(slave), samples_per_frame=10, rate_hz=100.0)
        reader.name = f"unit/U{u}"
        reader.counters = lambda: {"frames_bad": 0}  # what RateRecorder asks of a stream
        reader.read(0.01)  # opens the port (which drops what was waiting in it)
        ports.append((master, reader))
        recs.append(RateRecorder(reader, GyroAdcConfig(), w, lambda *a, **k: None, unit=f"U{u}"))
    cpu_read = cpu_record = 0.0
    try:
        for s0 in range(0, seconds, ticks):
            data = b"".join(frames[FRAMES_PER_S * s0 : FRAMES_PER_S * (s0 + ticks)])
            for master, _ in ports:
                os.write(master, data)
            time.sleep(0.001)  # the pty hands the bytes over
            for (_, reader), rec in zip(ports, recs, strict=True):
                c0 = time.process_time()
                got = reader.read(0.05)
                c1 = time.process_time()
                rec.on_read(got, float(s0 + ticks), lambda: None)
                cpu_record += time.process_time() - c1
                cpu_read += c1 - c0
            c1 = time.process_time()
            w.maybe_flush(float(s0 + ticks))
            cpu_record += time.process_time() - c1
        time.sleep(0.01)
        for (_, reader), rec in zip(ports, recs, strict=True):  # what the pty still held
            rec.on_read(reader.read(0.05), float(seconds + ticks), lambda: None)
            rec.emit_block()
        w.close()
    finally:
        for _, reader in ports:
            reader.close()
        for fd in fds:
            os.close(fd)
    return cpu_read, cpu_record, sum(r.samples for r in recs)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--units", type=int, default=8)
    ap.add_argument("--seconds", type=int, default=600)
    ap.add_argument("--ticks", type=int, default=3)
    a = ap.parse_args(argv)
    print(stamp())
    total = {}
    for k in (1, a.ticks):
        cpu_read, cpu_record, samples = run(a.units, a.seconds, k)
        per_s = (cpu_read + cpu_record) / a.seconds
        total[k] = per_s
        print(
            f"reads of {k} s: read {cpu_read / a.seconds * 1e6:5.0f} µs + record "
            f"{cpu_record / a.seconds * 1e6:5.0f} µs CPU per simulated second of {a.units} "
            f"units = {per_s * 300:.3f} of a core at 300x ({samples} samples)"
        )
    print(f"ratio (1 s reads / {a.ticks} s reads): {total[1] / total[a.ticks]:.2f}x")
    print(f"# load after {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
