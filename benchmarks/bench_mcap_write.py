"""The recorder's MCAP writing: gyrolab's own records (``McapFile``) against the ``mcap``
library's ``Writer``, on the same messages, in one process.

    python benchmarks/bench_mcap_write.py [--units 8] [--seconds 600] [--repeat 3]

What a multi-unit ``acquire --bench sim`` records every simulated second at ≥ 100× (one
bench tick): per unit a 100-sample ``/gyro/adc`` block, its ``/gyro/rate`` block and the
rate summary, a PT100 reading every 2 s, the oven every 2 s, then the crash-loss flush
(``flush_every_s`` = 1 run s) that closes one chunk per unit and one for the shared topics.
The same ``RecordingWriter`` calls run twice, once on each writer (the library behind
``McapFile``'s methods, as ``tests/test_mcap_file.py`` does), and the CPU time per
simulated second, the ratio, the cores needed at 300× and whether the two files are the
same bytes are printed.
"""

from __future__ import annotations

import argparse
import io
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from machine import stamp  # noqa: E402
from mcap_peer import LibraryMcapFile  # noqa: E402

import gyrolab.record.writer as writer_mod  # noqa: E402
from gyrolab.record.writer import RecordingWriter  # noqa: E402


def record(units: int, seconds: int, seed: int = 0) -> tuple[float, bytes]:
    """CPU seconds of writing ``seconds`` simulated seconds of ``units`` units, and the file."""
    rng = np.random.default_rng(seed)
    serials = [f"U{k:02d}" for k in range(units)]
    blocks = [rng.integers(-(2**23), 2**23, (seconds, 100), dtype=np.int32) for _ in serials]
    fh = io.BytesIO()
    t0 = time.process_time()
    w = RecordingWriter(
        fh,
        start_time_ns=1_700_000_000_000_000_000,
        run={"operator": "bench"},
        flush_every_s=1.0,
        units=serials,
    )
    w.write_event(0.0, "run_started")
    for s in range(seconds):
        for j, u in enumerate(serials):
            counts = blocks[j][s]
            w.write_adc_block(float(s), 0.01, 100 * s, counts, unit=u)
            w.write_rate_block(float(s), 0.01, 100 * s, counts * 3.0e-5, unit=u)
            if s % 2 == 0:
                w.write_pt100(s + 0.5, 100.0 + 0.01 * s, 25.0 + 0.03 * s, unit=u)
        if s % 2 == 0:
            w.write_oven(s + 0.7, 40.0, 39.5, "run")
        w.maybe_flush(s + 1.0)
    w.close()
    return time.process_time() - t0, fh.getvalue()


class _Calls:
    """An ``McapFile`` stand-in that only records the calls a ``RecordingWriter`` makes."""

    def __init__(self, fh: io.BytesIO, **kw: object) -> None:
        self.calls: list[tuple[str, tuple]] = [("__init__", (kw,))]
        _Calls.last = self
        self._ids = {"register_schema": 0, "register_channel": 0}

    def __getattr__(self, name: str):
        def call(*args: object) -> int:
            self.calls.append((name, args))
            if name in self._ids:
                self._ids[name] += 1
                return self._ids[name]
            return 0

        return call


def replay(cls: type, calls: list[tuple[str, tuple]]) -> tuple[float, bytes]:
    """CPU seconds of making ``calls`` on a ``cls`` writer alone (no recorder around it)."""
    fh = io.BytesIO()
    t0 = time.process_time()
    w = cls(fh, **calls[0][1][0])
    for name, args in calls[1:]:
        if name == "add_messages":  # a group's messages: the list as it was then
            args = (list(args[0]),)
        getattr(w, name)(*args)
    return time.process_time() - t0, fh.getvalue()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--units", type=int, default=8)
    ap.add_argument("--seconds", type=int, default=600)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args(argv)
    print(stamp())
    ours_cls = writer_mod.McapFile
    best: dict[str, float] = {}
    files: dict[str, bytes] = {}
    for _ in range(a.repeat):
        for name, cls in (("ours", ours_cls), ("mcap library", LibraryMcapFile)):
            writer_mod.McapFile = cls  # RecordingWriter looks it up at each construction
            try:
                cpu, files[name] = record(a.units, a.seconds)
            finally:
                writer_mod.McapFile = ours_cls
            best[name] = min(cpu, best.get(name, cpu))
    for name, cpu in best.items():
        per_s = cpu / a.seconds
        print(
            f"{name:>13}: {per_s * 1e6:7.0f} µs CPU per simulated second of {a.units} units "
            f"(best of {a.repeat}), {per_s * 300:.3f} of a core at 300x"
        )
    both = best["mcap library"] / best["ours"]
    print(f"ratio (library / ours), the recorder and its writer: {both:.2f}x")
    # the writer alone: the same McapFile calls, replayed on each
    writer_mod.McapFile = _Calls
    try:
        record(a.units, a.seconds)
    finally:
        writer_mod.McapFile = ours_cls
    calls = _Calls.last.calls
    alone: dict[str, float] = {}
    for _ in range(a.repeat):
        for name, cls in (("ours", ours_cls), ("mcap library", LibraryMcapFile)):
            cpu, data = replay(cls, calls)
            alone[name] = min(cpu, alone.get(name, cpu))
            assert data == files[name], "the replay wrote another file"
    for name, cpu in alone.items():
        print(f"{name:>13}, the writer alone: {cpu / a.seconds * 1e6:7.0f} µs per simulated second")
    print(f"ratio (library / ours), the writer alone: {alone['mcap library'] / alone['ours']:.2f}x")
    print(f"same bytes: {files['ours'] == files['mcap library']} ({len(files['ours'])} bytes)")
    print(f"# load after {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
