"""ADC frame decoding throughput: gyrolab's FrameDecoder vs a straightforward reference.

Three measurements, all in one process:

1. ``decoder``: :class:`gyrolab.framing.FrameDecoder` fed a pre-encoded stream in 4 KiB
   chunks (what a serial read returns), clean and with 1 % corrupted / 0.1 % dropped
   bytes, for 1, 10 and 100 samples per frame.
2. ``reference``: the decoder one usually writes first — a byte-at-a-time state machine
   with a bitwise CRC-16/CCITT — on the same streams; its output is checked identical.
3. ``pty``: :class:`gyrolab.instruments.drivers.gyroadc.GyroAdcReader` reading a real pseudo-
   terminal that a writer thread fills as fast as the kernel takes it (decode + port I/O).

The need is 1 kHz (1000 samples/s); the target is ≥ 20× that. Usage::

    python benchmarks/bench_adc_frames.py [--seconds S] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import struct
import threading
import time

import numpy as np

from gyrolab.framing import FrameDecoder, encode_frames
from gyrolab.instruments.drivers.gyroadc import GyroAdcReader
from gyrolab.sim.bench.faults import ByteFaults
from gyrolab.sim.bench.serial_pty import PortClosed, PtyPort

RATE_HZ = 1000.0


def make_stream(frames: int, n: int, corrupt: float = 0.0, drop: float = 0.0) -> bytes:
    rng = np.random.default_rng(0)
    counts = rng.integers(-(1 << 23), 1 << 23, size=(frames, n))
    ts = (np.arange(frames) * n * 1e6 / RATE_HZ).astype(np.int64)
    wire = encode_frames(0, ts, counts)
    if corrupt or drop:
        f = ByteFaults(corrupt_prob=corrupt, drop_prob=drop, seed=1)
        wire = [f.apply(w)[0] for w in wire]
    return b"".join(wire)


def run_decoder(stream: bytes, n: int) -> tuple[float, int, np.ndarray]:
    dec = FrameDecoder(n, RATE_HZ)
    t0 = time.perf_counter()
    out = []
    for i in range(0, len(stream), 4096):
        b = dec.feed(stream[i : i + 4096])
        out.append(b.seq)
    dt = time.perf_counter() - t0
    seq = np.concatenate(out)
    return dt, seq.size, seq


def _crc_bitwise(data: bytes) -> int:
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def run_reference(stream: bytes, n: int) -> tuple[float, int, np.ndarray]:
    """Byte-at-a-time state machine; on a bad frame, rescan from the byte after its sync."""
    length = 12 + 3 * n
    size = length + 6
    t0 = time.perf_counter()
    seqs: list[int] = []
    samples: list[int] = []
    i, end = 0, len(stream)
    last = -1
    while i + size <= end:
        if stream[i] != 0xA5 or stream[i + 1] != 0x5A:
            i += 1
            continue
        if stream[i + 2] | stream[i + 3] << 8 != length:
            i += 1
            continue
        body = stream[i + 2 : i + 4 + length]
        if _crc_bitwise(body) != (stream[i + size - 2] << 8 | stream[i + size - 1]):
            i += 1
            continue
        seq, _ts = struct.unpack_from("<IQ", stream, i + 4)
        if seq > last:
            for k in range(n):
                o = i + 16 + 3 * k
                v = stream[o] | stream[o + 1] << 8 | stream[o + 2] << 16
                samples.append(v - (1 << 24) if v & 0x800000 else v)
            seqs.append(seq)
            last = seq
        i += size
    dt = time.perf_counter() - t0
    return dt, len(seqs), np.asarray(seqs)


def run_pty(seconds: float, n: int) -> tuple[float, int]:
    frames = 20000
    stream = make_stream(frames, n)
    port = PtyPort()
    port.connect()
    reader = GyroAdcReader(port.path, samples_per_frame=n, rate_hz=RATE_HZ)
    reader.open()
    stop = threading.Event()

    def pump() -> None:
        # The same frames again and again would be dropped as stale: renumber per lap.
        lap = 0
        while not stop.is_set():
            data = stream if lap == 0 else make_lap(stream, n, lap * frames)
            try:
                port.write(data, timeout_s=0.2)
            except PortClosed:
                return
            lap += 1

    laps: dict[int, bytes] = {}

    def make_lap(_s: bytes, n_: int, seq0: int) -> bytes:
        if seq0 not in laps:
            rng = np.random.default_rng(seq0)
            counts = rng.integers(-(1 << 23), 1 << 23, size=(frames, n_))
            ts = ((seq0 + np.arange(frames)) * n_ * 1e6 / RATE_HZ).astype(np.int64)
            laps.clear()
            laps[seq0] = b"".join(encode_frames(seq0, ts, counts))
        return laps[seq0]

    th = threading.Thread(target=pump, daemon=True)
    th.start()
    got = 0
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        got += reader.read(0.05).samples
    dt = time.perf_counter() - t0
    stop.set()
    th.join(2.0)
    reader.close()
    port.disconnect()
    return dt, got


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0, help="duration of the pty run")
    ap.add_argument("--json", help="write the figures here")
    args = ap.parse_args()
    rows = []
    print(
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, Python "
        f"{platform.python_version()}"
    )
    print("frames/s and samples/s: input processed per second; delivered: intact share")
    print(
        f"{'case':26s} {'ours frames/s':>14s} {'samples/s':>12s} {'delivered':>9s} "
        f"{'ref frames/s':>13s} {'ratio':>6s} {'x need':>7s}"
    )
    for n in (1, 10, 100):
        frames = 200_000 // n if n > 1 else 100_000
        for label, corrupt, drop in (("clean", 0.0, 0.0), ("1%/0.1% faults", 0.01, 0.001)):
            stream = make_stream(frames, n, corrupt, drop)
            dt, got, seq = run_decoder(stream, n)
            ref_frames = min(frames, 20_000 // max(1, n // 10))
            ref_stream = make_stream(ref_frames, n, corrupt, drop)
            rdt, rgot, rseq = run_reference(ref_stream, n)
            _, _, oseq = run_decoder(ref_stream, n)
            assert np.array_equal(oseq, rseq), "ours and the reference disagree"
            # Throughput = frames of input processed per second (delivered or rejected).
            fps, rfps = frames / dt, ref_frames / rdt
            row = {
                "case": f"n={n} {label}",
                "frames_per_s": fps,
                "samples_per_s": fps * n,
                "reference_frames_per_s": rfps,
                "speedup": fps / rfps,
                "times_1khz_need": fps * n / RATE_HZ,
                "frames_delivered": got,
                "delivered_fraction": got / frames,
            }
            rows.append(row)
            print(
                f"{row['case']:26s} {fps:14,.0f} {fps * n:12,.0f} {got / frames:9.1%} "
                f"{rfps:13,.0f} {fps / rfps:6.1f} {fps * n / RATE_HZ:7.0f}"
            )
    dt, got = run_pty(args.seconds, 10)
    row = {
        "case": "pty GyroAdcReader n=10",
        "samples_per_s": got / dt,
        "frames_per_s": got / dt / 10,
        "times_1khz_need": got / dt / RATE_HZ,
    }
    rows.append(row)
    print(
        f"{row['case']:26s} {row['frames_per_s']:14,.0f} {row['samples_per_s']:12,.0f} "
        f"{'100%':>9s} {'':>13s} {'':>6s} {row['times_1khz_need']:7.0f}"
    )
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
