"""Time to read ONE unit of a multi-unit recording, against the number of units in the file.

    python benchmarks/bench_unit_read.py FILE.mcap [FILE.mcap ...] [--repeat 3]

For each file (``gyrolab simulate --units N``), reads its first unit the way
``gyrolab compensate`` does (``prepare_file``: the PT100 readings with ``read_recording``,
then ``/gyro/rate`` streamed block by block), then the unit whole (``read_recording``: every
topic, as ``report`` and ``convert`` do), and prints the best of ``--repeat`` times of each,
wall and CPU (the process's own: steadier than wall time on a shared machine), the chunks
the file has and the chunks that hold the unit's rate channel (from the MCAP summary's chunk
indexes). With one unit per chunk the time does not grow with the number of units; with
interleaved chunks it grows linearly (docs/performance.md). Every read is checked
(docs/reliability.md "Checked reads"): run it on two trees to see what the checks cost.
"""

from __future__ import annotations

import argparse
import os
import time

from gyrolab.compensation.prepare import iter_rate_batches
from gyrolab.record.format import TOPIC_PT100, TOPIC_RATE, unit_topic
from gyrolab.record.reader import list_units, read_recording
from gyrolab.record.source import opened


def chunk_counts(path: str, unit: str | None) -> tuple[int, int]:
    """(chunks in the file, chunks holding ``unit``'s ``/gyro/rate`` channel)."""
    with opened(path) as src:
        summary = src.summary
    assert summary is not None
    rate = unit_topic(TOPIC_RATE, unit)
    ids = {cid for cid, ch in summary.channels.items() if ch.topic == rate}
    holding = sum(1 for ci in summary.chunk_indexes if ids & set(ci.message_index_offsets))
    return len(summary.chunk_indexes), holding


def read_one(path: str, unit: str | None) -> int:
    rec = read_recording(path, topics=[TOPIC_PT100], unit=unit)
    n = 0
    for _t, x, _p in iter_rate_batches(path, unit=unit):
        n += x.size
    return n + rec.pt100_c.size


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="+")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f}")
    print(
        f"{'units':>5} {'MB':>7} {'chunks':>6} {'unit chunks':>11} {'read 1 unit s':>13} "
        f"{'cpu s':>6} {'whole unit s':>12} {'cpu s':>6}"
    )
    for path in args.files:
        units = list_units(path)
        unit = units[0] if units else None
        best = [float("inf")] * 4
        for _ in range(args.repeat):
            w0, c0 = time.perf_counter(), time.process_time()
            read_one(path, unit)
            w1, c1 = time.perf_counter(), time.process_time()
            read_recording(path, unit=unit)
            w2, c2 = time.perf_counter(), time.process_time()
            times = (w1 - w0, c1 - c0, w2 - w1, c2 - c1)
            best = [min(b, x) for b, x in zip(best, times, strict=True)]
        total, holding = chunk_counts(path, unit)
        mb = os.path.getsize(path) / 1e6
        print(
            f"{max(1, len(units)):>5} {mb:>7.1f} {total:>6} {holding:>11} {best[0]:>13.3f} "
            f"{best[1]:>6.3f} {best[2]:>12.3f} {best[3]:>6.3f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
