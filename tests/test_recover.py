"""`gyrolab recover` and the recorder's crash-loss window, on files cut at every kind of place."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from gyrolab.cli import main
from gyrolab.errors import InputError
from gyrolab.record.format import TOPIC_PT100
from gyrolab.record.reader import iter_messages, read_recording
from gyrolab.record.recover import recover_recording, scan
from gyrolab.record.writer import RecordingWriter

START_NS = 1_618_876_800_000_000_000
RATE = 100.0
BLOCK = 50  # 0.5 s blocks, as the runner writes them


def _write_run(path: Path, seconds: float, flush_every_s: float = 1.0, close: bool = True):
    """A small deterministic recording; returns (writer, all messages as written)."""
    rng = np.random.default_rng(7)
    w = RecordingWriter(
        path, start_time_ns=START_NS, run={"operator": "t"}, flush_every_s=flush_every_s
    )
    n_blocks = int(seconds * RATE / BLOCK)
    for k in range(n_blocks):
        t0 = k * BLOCK / RATE
        counts = rng.integers(-(2**23), 2**23, BLOCK, dtype=np.int32)
        w.write_adc_block(t0, 1 / RATE, k * BLOCK, counts)
        w.write_rate_block(t0, 1 / RATE, k * BLOCK, counts * 3e-5)
        if k % 2 == 0:
            w.write_pt100(t0, 100.0 + k * 1e-3, k * 2.5e-3)
    if close:
        w.close()
    else:
        w._fh.flush()  # what a kill -9 leaves: everything written, nothing finished
    return w


def _messages(path: Path) -> list[tuple[str, int, bytes]]:
    return list(iter_messages(path))


def test_complete_file_recovers_to_the_same_messages(tmp_path: Path) -> None:
    src = tmp_path / "ok.mcap"
    _write_run(src, 20.0)
    rep = recover_recording(src, tmp_path / "fixed.mcap")
    assert rep.complete and rep.truncated_tail_bytes == 0 and rep.chunks_damaged == 0
    assert _messages(tmp_path / "fixed.mcap") == _messages(src)
    fixed = read_recording(tmp_path / "fixed.mcap")
    assert fixed.run["operator"] == "t" and fixed.adc.index.size == 2000


def _chunk_ends(data: bytes) -> list[int]:
    """File offsets where each chunk record ends (walking the length prefixes)."""
    ends, i = [], 8
    while i + 9 <= len(data):
        ln = int.from_bytes(data[i + 1 : i + 9], "little")
        if data[i] == 0x06:
            ends.append(i + 9 + ln)
        i += 9 + ln
    return ends


def test_blocks_behind_a_later_stamped_flush_still_flush_within_flush_every_s(
    tmp_path: Path,
) -> None:
    """A flush stamped on arrival (the runner's loop, an oven reading) is later than the
    ADC blocks that follow it, which are stamped with their start: the stamp rule alone
    left three 1 s blocks unflushed (CI: 3 s lost to a kill -9). Each block topic's own
    account keeps what is not yet handed to the OS within flush_every_s."""
    path = tmp_path / "late.mcap"
    w = RecordingWriter(path, start_time_ns=START_NS, run={"operator": "t"}, flush_every_s=1.0)
    rng = np.random.default_rng(3)
    on_disk = []
    for k in range(30):
        counts = rng.integers(-(2**23), 2**23, 100, dtype=np.int32)  # 1 s ticks, as at 100×
        w.write_adc_block(float(k), 1 / RATE, k * 100, counts)
        w.write_rate_block(float(k), 1 / RATE, k * 100, counts * 3e-5)
        # what a kill -9 right now would leave: the bytes the OS has, recovered
        cut = tmp_path / "now.mcap"
        cut.write_bytes(path.read_bytes())
        fixed = tmp_path / "now-fixed.mcap"
        try:
            recover_recording(cut, fixed, force=True)
        except InputError:  # nothing flushed yet, not even the header
            on_disk.append(0.0)
        else:
            adc = read_recording(fixed).adc
            on_disk.append(float(adc.t[-1] + adc.period) if adc.t.size else 0.0)
        if k % 3 == 2:
            # The loop's turn after a burst of three ticks (a stalled process): its clock
            # is 0.9 s past the data, so its flush is stamped later than the next blocks.
            w.maybe_flush(k + 1.9)
    # written up to k + 1; on disk at most 1 s behind, for both streams
    lag = np.array([k + 1 - d for k, d in enumerate(on_disk)])
    assert lag.max() <= 1.0 + 1e-9 and lag.min() >= 0.0, lag
    assert w.flush_count <= 31  # not a flush per block and topic: one per tick at most
    w.close()


def test_every_cut_point_recovers_exactly_the_complete_chunks(tmp_path: Path) -> None:
    """Cut an unfinished file at many byte offsets: the recovered messages are exactly
    those of the chunks that were complete before the cut — no more, no fewer, unaltered."""
    src = tmp_path / "unfinished.mcap"
    w = _write_run(src, 30.0, close=False)
    assert w.flush_count >= 29
    data = src.read_bytes()
    full = tmp_path / "full.mcap"
    recover_recording(src, full)
    ref = _messages(full)
    ends = _chunk_ends(data)
    # Messages per chunk, in file order: count them chunk by chunk via recovery itself
    # at each chunk end (the count must grow by that chunk's messages only).
    per_chunk_total = []
    for e in ends:
        rep, _ = scan_bytes(tmp_path, data[:e])
        per_chunk_total.append(rep.message_count)
    assert per_chunk_total == sorted(per_chunk_total) and per_chunk_total[-1] == len(ref)
    rng = np.random.default_rng(1)
    cuts = sorted(
        set(rng.integers(ends[0] - 50, len(data), 80).tolist()) | {ends[0] - 1, len(data) - 1}
    )
    for cut in cuts:
        broken = tmp_path / "cut.mcap"
        broken.write_bytes(data[:cut])
        out = tmp_path / "cut-fixed.mcap"
        if cut < ends[0]:
            # Killed before the first flush: the metadata survive, as an empty recording.
            rep = recover_recording(broken, out, force=True)
            assert rep.message_count == 0 and "run" in rep.metadata
            assert read_recording(out).run["operator"] == "t"
            continue
        rep = recover_recording(broken, out, force=True)
        complete = sum(1 for e in ends if e <= cut)
        got = _messages(out)
        assert len(got) == per_chunk_total[complete - 1], f"cut at {cut}"
        assert got == ref[: len(got)], f"cut at {cut}: not the original messages"
        assert rep.salvaged_bytes + rep.truncated_tail_bytes == cut


def scan_bytes(tmp_path: Path, data: bytes):
    f = tmp_path / "scan.mcap"
    f.write_bytes(data)
    return scan(f)


def test_truncated_chunk_header_tells_the_lost_time_span(tmp_path: Path) -> None:
    src = tmp_path / "u.mcap"
    _write_run(src, 10.0, close=False)
    data = src.read_bytes()
    broken = tmp_path / "b.mcap"
    rep_all, _ = scan(src)
    # Find a cut that lands inside a chunk: the report gives the span it carried.
    for cut in range(len(data) - 1, 1000, -7):
        broken.write_bytes(data[:cut])
        rep, _ = scan(broken)
        if rep.lost_spans_ns:
            a, b = rep.lost_spans_ns[0]
            assert START_NS <= a <= b <= START_NS + 10 * 10**9
            assert 0 < rep.lost_seconds() <= 1.5
            assert "incomplete last record" in rep.summary() and "messages from t=" in rep.summary()
            break
    else:
        pytest.fail("no cut landed inside a chunk")
    assert rep_all.message_count > rep.message_count


def test_damaged_chunk_is_skipped_and_reported_later_ones_kept(tmp_path: Path) -> None:
    src = tmp_path / "d.mcap"
    _write_run(src, 20.0)
    data = bytearray(src.read_bytes())
    full_rep, _ = scan(src)
    # Flip a byte inside the compressed data of the middle chunk (from the chunk index).
    from mcap.reader import make_reader

    with open(src, "rb") as fh:
        chunks = make_reader(fh).get_summary().chunk_indexes
    ci = chunks[len(chunks) // 2]
    mid = ci.chunk_start_offset + ci.chunk_length // 2
    data[mid] ^= 0xFF
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    rep = recover_recording(bad, tmp_path / "fixed.mcap")
    assert rep.chunks_damaged + len(rep.problems) >= 1
    assert rep.chunks_ok >= full_rep.chunks_ok - 1
    fixed = read_recording(tmp_path / "fixed.mcap")
    orig = read_recording(src)
    # Whatever was kept is bit-identical to the original; nothing was altered.
    keep = np.isin(orig.adc.index, fixed.adc.index)
    assert np.array_equal(orig.adc.values[keep], fixed.adc.values)
    assert fixed.adc.index.size >= orig.adc.index.size - 200
    assert len(fixed.adc.gaps()) <= 1


def test_recover_gives_one_consistent_account_of_a_damaged_file(tmp_path: Path) -> None:
    """A closed file with one damaged chunk: 'complete, but damaged', and the samples and
    seconds lost per topic are exactly those missing from the recovered file."""
    src = tmp_path / "d.mcap"
    _write_run(src, 20.0)
    data = bytearray(src.read_bytes())
    ends = _chunk_ends(bytes(data))
    data[ends[7] - 40] ^= 0xFF  # inside the 8th chunk's compressed data
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    rep = recover_recording(bad, tmp_path / "fixed.mcap")
    assert rep.complete and rep.chunks_damaged == 1
    text = rep.summary()
    assert "the file was complete (it had its footer), but 1 chunk(s) in it were damaged" in text
    assert "already complete" not in text
    orig, fixed = read_recording(src), read_recording(tmp_path / "fixed.mcap")
    for topic, series in (("/gyro/adc", "adc"), ("/gyro/rate", "rate")):
        missing = getattr(orig, series).index.size - getattr(fixed, series).index.size
        assert missing > 0 and rep.lost[topic]["samples"] == missing
        assert rep.lost[topic]["seconds"] == pytest.approx(missing / RATE)
    assert rep.lost_seconds() == pytest.approx(rep.lost["/gyro/rate"]["seconds"])
    (a, b), = rep.lost["/gyro/rate"]["spans_s"]
    assert b - a == pytest.approx(rep.lost["/gyro/rate"]["seconds"])
    # What recover found is written into the recovered file for the report.
    meta = fixed.metadata["recovery"]
    assert meta["chunks_damaged"] == 1 and meta["complete"] is True
    assert meta["lost_seconds"] == pytest.approx(rep.lost_seconds())
    assert meta["safe_state"] == "not recorded" and meta["account"].startswith("recovered (")
    assert "oven safe state: never confirmed" in text


def test_recover_cli_reports_and_refuses_to_clobber(tmp_path: Path, capsys) -> None:
    src = tmp_path / "u.mcap"
    _write_run(src, 5.0, close=False)
    with pytest.raises(InputError):
        read_recording(src)  # the unfinished file is not readable as is
    out = tmp_path / "f.mcap"
    assert main(["recover", str(src), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "recovered" in text and TOPIC_PT100 in text
    assert read_recording(out).adc.index.size > 0
    assert main(["recover", str(src), "--out", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"hello world, not mcap")
    assert main(["recover", str(junk), "--out", str(tmp_path / "j.mcap")]) == 2
    assert "not an MCAP file" in capsys.readouterr().err
    assert main(["recover", str(src), "--out", str(src)]) == 2


_WRITER_SCRIPT = textwrap.dedent(
    """
    import sys, time
    import numpy as np
    from gyrolab.record.writer import RecordingWriter
    path, speed = sys.argv[1], float(sys.argv[2])
    w = RecordingWriter(path, start_time_ns=0, flush_every_s=1.0)
    t0 = time.monotonic()
    k = 0
    while True:
        # Run time advances at `speed` x wall; a 0.5 s block as soon as it is due.
        t = k * 0.5
        while (time.monotonic() - t0) * speed < t + 0.5:
            time.sleep(0.001)
        w.write_adc_block(t, 0.01, k * 50, np.arange(50, dtype=np.int32))
        sys.stdout.write(f"{t + 0.5}\\n"); sys.stdout.flush()
        k += 1
    """
)


def test_kill_9_of_a_writing_process_loses_at_most_the_flush_window(tmp_path: Path) -> None:
    """The recorder alone under kill -9 (the full acquisition is tests/test_acquire_kill)."""
    rng = np.random.default_rng(3)
    for i in range(5):
        path = tmp_path / f"k{i}.mcap"
        p = subprocess.Popen(
            [sys.executable, "-c", _WRITER_SCRIPT, str(path), "20"],
            stdout=subprocess.PIPE,
            text=True,
        )
        # Start the clock at the first block handed to the writer: on a loaded machine the
        # interpreter's start-up alone can take longer than the delay below.
        first = p.stdout.readline() if p.stdout else ""
        time.sleep(0.6 + rng.random() * 0.8)
        os.kill(p.pid, signal.SIGKILL)
        out, _ = p.communicate()
        out = first + out
        produced = float(out.split()[-1])  # end of the last block handed to the writer
        rep = recover_recording(path, tmp_path / f"k{i}-fixed.mcap")
        rec = read_recording(tmp_path / f"k{i}-fixed.mcap")
        kept = rec.adc.t[-1] + 0.01
        assert rep.message_count > 0
        assert produced - kept <= 1.5 + 1e-6, (produced, kept)
