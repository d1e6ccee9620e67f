"""gyrolab's own MCAP records (gyrolab/record/writer.py ``McapFile``) against the ``mcap``
library: the same calls write the same file, byte for byte, and the library's readers read
ours back with every CRC checked, through the summary and indexes and without them."""

from __future__ import annotations

import io
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import NonSeekingReader, SeekingReader
from mcap.stream_reader import CRCValidationError

from gyrolab.record.writer import McapFile, RecordingWriter

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from mcap_peer import LibraryMcapFile as _Library  # noqa: E402


def _script(w, seed: int) -> list[tuple[int, int, bytes, int, int]]:
    """A seeded mix of every call a gyrolab writer makes; returns the messages written
    (channel, log time, data, publish time, sequence)."""
    rng = np.random.default_rng(seed)
    s1 = w.register_schema(
        "gyrolab.Block", "protobuf", bytes(rng.integers(0, 256, 300, dtype=np.uint8))
    )
    s2 = w.register_schema("Log", "jsonschema", b'{"type": "object"}')
    chans = [
        w.register_channel("/gyro/rate", "protobuf", s1, {"unit": "A1", "é": "ü"}),
        w.register_channel("/log", "json", s2),
        w.register_channel("/raw", "", 0),
    ]
    w.add_metadata("run", {"operator": "t", "nested": '{"a": 1}'})
    sent = []
    t = 1_700_000_000_000_000_000
    for k in range(400):
        chan = chans[int(rng.integers(0, len(chans)))]
        t += int(rng.integers(-5_000_000, 20_000_000))  # log times need not increase
        data = bytes(rng.integers(0, 256, int(rng.integers(0, 300)), dtype=np.uint8))
        pub = t + int(rng.integers(0, 3))
        w.add_message(chan, t, data, pub, k)
        sent.append((chan, t, data, pub, k))
        if k == 150:  # a channel registered mid-file goes into the next chunk
            chans.append(w.register_channel("/late", "json", s2, {"k": "v"}))
        if k % 97 == 0:
            w.flush()
        if k % 131 == 0:
            w.add_metadata(f"note{k}", {"k": str(k)})
    batch = [(chans[0], t + 1000 * i, bytes([i]) * i, i) for i in range(60)]
    w.add_messages(batch)  # the multi-unit path: one group's messages, one chunk
    w.close_chunk()
    sent += [(c, ts, d, ts, q) for c, ts, d, q in batch]
    w.add_metadata("bench", {})
    w.finish()
    return sent


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
@pytest.mark.parametrize("chunk_size", [700, 1 << 20])
def test_same_bytes_as_the_mcap_library(compression: str, chunk_size: int) -> None:
    files = []
    for cls in (McapFile, _Library):
        fh = io.BytesIO()
        w = cls(
            fh,
            profile="gyrolab",
            library="gyrolab test",
            chunk_size=chunk_size,
            compression=compression,
        )
        _script(w, seed=3)
        files.append(fh.getvalue())
    assert files[0] == files[1]


def test_an_empty_file_is_the_library_s() -> None:
    files = []
    for cls in (McapFile, _Library):
        fh = io.BytesIO()
        w = cls(fh, profile="p", library="l", chunk_size=1 << 20, compression="zstd")
        w.register_channel("/x", "json", w.register_schema("S", "jsonschema", b"{}"))
        w.add_metadata("run", {"a": "b"})
        w.finish()
        files.append(fh.getvalue())
    assert files[0] == files[1]


def test_the_library_reads_ours_back_with_its_checks() -> None:
    fh = io.BytesIO()
    w = McapFile(fh, profile="gyrolab", library="gyrolab test", chunk_size=700)
    sent = _script(w, seed=5)
    raw = fh.getvalue()
    want = sorted((c, ts, d, p, q) for c, ts, d, p, q in sent)
    # without the summary: every chunk's CRC and the data section's CRC checked
    plain = NonSeekingReader(io.BytesIO(raw), validate_crcs=True)
    got = [
        (m.channel_id, m.log_time, m.data, m.publish_time, m.sequence)
        for _, _, m in plain.iter_messages()
    ]
    assert sorted(got) == want
    # through the summary, the chunk indexes and the message indexes
    seek = SeekingReader(io.BytesIO(raw), validate_crcs=True)
    summary = seek.get_summary()
    assert summary is not None and summary.statistics is not None
    st = summary.statistics
    assert st.message_count == len(sent) and st.chunk_count == len(summary.chunk_indexes)
    assert st.message_start_time == min(m[1] for m in sent)
    assert st.message_end_time == max(m[1] for m in sent)
    assert st.channel_message_counts == {
        c: sum(1 for m in sent if m[0] == c) for c in set(m[0] for m in sent)
    }
    assert st.metadata_count == len(list(seek.iter_metadata()))
    assert [s.name for s in summary.schemas.values()] == ["gyrolab.Block", "Log"]
    assert summary.channels[1].metadata == {"unit": "A1", "é": "ü"}
    assert summary.channels[4].topic == "/late"
    indexed = [
        (m.channel_id, m.log_time, m.data, m.publish_time, m.sequence)
        for _, _, m in seek.iter_messages(log_time_order=True)
    ]
    assert sorted(indexed) == want
    assert [ts for _, ts, *_ in indexed] == sorted(ts for _, ts, *_ in indexed)
    late = [m for _, _, m in seek.iter_messages(topics=["/late"])]
    assert len(late) == sum(1 for m in sent if m[0] == 4) > 0
    meta = {r.name: r.metadata for r in seek.iter_metadata()}
    assert meta["run"] == {"operator": "t", "nested": '{"a": 1}'} and meta["bench"] == {}


def test_the_library_checks_our_crcs() -> None:
    """A flipped byte inside an (uncompressed) chunk fails its chunk CRC; one inside a
    metadata record, which no chunk covers, fails the data section's CRC."""
    fh = io.BytesIO()
    w = McapFile(fh, profile="gyrolab", library="gyrolab test", compression="none")
    cid = w.register_channel("/x", "json", w.register_schema("S", "jsonschema", b"{}"))
    w.add_metadata("run", {"operator": "MARKER-A"})
    w.add_message(cid, 10, b"MARKER-B", 10, 0)
    w.finish()
    raw = fh.getvalue()
    list(NonSeekingReader(io.BytesIO(raw), validate_crcs=True).iter_messages())  # clean
    for marker in (b"MARKER-A", b"MARKER-B"):
        bad = bytearray(raw)
        bad[raw.index(marker)] ^= 0x20
        with pytest.raises(CRCValidationError):
            list(NonSeekingReader(io.BytesIO(bytes(bad)), validate_crcs=True).iter_messages())


def test_a_multi_unit_recording_is_the_library_s(tmp_path: Path, monkeypatch) -> None:
    """A whole multi-unit recording, flushed every run second, written by the recorder on
    our records and on the library's: the same file."""
    import gyrolab.record.writer as writer_mod

    def run(path: Path) -> bytes:
        rng = np.random.default_rng(2)
        with RecordingWriter(
            path,
            start_time_ns=1_700_000_000_000_000_000,
            run={"operator": "t"},
            flush_every_s=1.0,
            units=["A1", "B2"],
        ) as w:
            w.write_event(0.0, "run_started")
            for k in range(20):
                for u in ("A1", "B2"):
                    c = rng.integers(-(2**23), 2**23, 50, dtype=np.int32)
                    w.write_adc_block(k * 0.5, 0.01, k * 50, c, unit=u)
                    w.write_rate_block(k * 0.5, 0.01, k * 50, c * 3e-5, unit=u)
                    w.write_pt100(k * 0.5, 100.0 + k, 0.5 * k, unit=u)
                w.write_oven(k * 0.5, 40.0, 39.0, "run")
                w.write_log(k * 0.5, "info", "test", f"tick {k}")
        return path.read_bytes()

    ours = run(tmp_path / "ours.mcap")
    monkeypatch.setattr(writer_mod, "McapFile", _Library)
    theirs = run(tmp_path / "theirs.mcap")
    assert ours == theirs
