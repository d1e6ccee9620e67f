"""Multi-unit recordings put one unit's messages per chunk (docs/recording-format.md).

Reading one unit then decompresses only that unit's chunks. The layout must read back the
same as the interleaved one (time-ordered chunks mixing every unit, as older files have),
survive ``recover`` and keep the crash-loss policy: a flush writes every unit's buffer.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from gyrolab.record.format import TOPIC_ADC, TOPIC_PT100, TOPIC_RATE, UNIT_PREFIX
from gyrolab.record.reader import iter_blocks, iter_messages, read_recording
from gyrolab.record.recover import recover_recording
from gyrolab.record.source import chunks_in_file_order
from gyrolab.record.writer import RecordingWriter

START_NS = 1_700_000_000_000_000_000
UNITS = ["A1", "B2", "C3"]
BLOCK = 50
RATE = 100.0


def _write(
    path: Path,
    seconds: float = 30.0,
    flush_every_s: float | None = None,
    stop_at: float | None = None,
) -> tuple[RecordingWriter, list[tuple[str, int, bytes]]]:
    """A small 3-unit run (small chunks, so each unit spans several); returns the writer
    (closed unless ``stop_at``: then flushed at that run time and left open) and what its
    tap saw."""
    rng = np.random.default_rng(11)
    w = RecordingWriter(
        path,
        start_time_ns=START_NS,
        run={"operator": "t"},
        chunk_size=4096,
        flush_every_s=flush_every_s,
        units=UNITS,
    )
    seen: list[tuple[str, int, bytes]] = []
    w.tap = lambda topic, ts, data: seen.append((topic, ts, data))
    w.write_event(0.0, "run_started")
    for k in range(int(seconds * RATE / BLOCK)):
        t0 = k * BLOCK / RATE
        if stop_at is not None and t0 >= stop_at:
            w.flush()
            return w, seen
        for j, u in enumerate(UNITS):
            counts = rng.integers(-(2**23), 2**23, BLOCK, dtype=np.int32)
            w.write_adc_block(t0, 1 / RATE, k * BLOCK, counts, unit=u)
            w.write_rate_block(t0, 1 / RATE, k * BLOCK, counts * 3e-5, unit=u)
            w.write_pt100(t0, 100.0 + k * 1e-3 + j, k * 2.5e-3 + j, unit=u)
        w.write_oven(t0, 40.0, 39.9, "run")
        if k % 10 == 0:
            w.write_log(t0, "info", "test", f"block {k}")
    w.write_event(seconds, "run_ended")
    w.close()
    return w, seen


def _interleaved_copy(src: Path, dst: Path) -> None:
    """The same schemas, channels, metadata and messages, written the way older gyrolab
    did: in log-time order into shared chunks that mix every unit."""
    with open(src, "rb") as fh, open(dst, "wb") as out:
        r = make_reader(fh)
        s = r.get_summary()
        assert s is not None
        w = Writer(out, chunk_size=4096, compression=CompressionType.ZSTD)
        w.start(profile="gyrolab", library="test")
        for sid in sorted(s.schemas):
            assert (
                w.register_schema(s.schemas[sid].name, s.schemas[sid].encoding, s.schemas[sid].data)
                == sid
            )
        for cid in sorted(s.channels):
            c = s.channels[cid]
            assert w.register_channel(c.topic, c.message_encoding, c.schema_id) == cid
        for m in r.iter_metadata():
            w.add_metadata(m.name, m.metadata)
        for _sch, _ch, m in r.iter_messages():
            w.add_message(m.channel_id, m.log_time, m.data, m.publish_time, m.sequence)
        w.finish()


def _shuffled_copy(src: Path, dst: Path, chunk_size: int) -> None:
    """The same channels and messages written out of log-time order (a fixed permutation),
    log times cut to whole seconds so that a topic has many messages at one time."""
    with open(src, "rb") as fh, open(dst, "wb") as out:
        r = make_reader(fh)
        s = r.get_summary()
        assert s is not None
        w = Writer(out, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        w.start(profile="gyrolab", library="test")
        for sid in sorted(s.schemas):
            w.register_schema(s.schemas[sid].name, s.schemas[sid].encoding, s.schemas[sid].data)
        for cid in sorted(s.channels):
            c = s.channels[cid]
            w.register_channel(c.topic, c.message_encoding, c.schema_id)
        for m in r.iter_metadata():
            w.add_metadata(m.name, m.metadata)
        msgs = [m for _s, _c, m in r.iter_messages()]
        for i in np.random.default_rng(5).permutation(len(msgs)):
            m = msgs[i]
            t = m.log_time - m.log_time % 10**9
            w.add_message(m.channel_id, t, m.data, t, m.sequence)
        w.finish()


def _chunk_groups(path: Path) -> list[set[str]]:
    """Per chunk, the groups (unit serial or 'shared') whose channels it holds."""
    with open(path, "rb") as fh:
        s = make_reader(fh).get_summary()
    assert s is not None
    out = []
    for ci in s.chunk_indexes:
        topics = [s.channels[c].topic for c in ci.message_index_offsets]
        out.append(
            {
                t[len(UNIT_PREFIX) :].split("/", 1)[0] if t.startswith(UNIT_PREFIX) else "shared"
                for t in topics
            }
        )
    return out


def _by_topic(messages: list[tuple[str, int, bytes]]) -> dict[str, list[tuple[int, bytes]]]:
    out: dict[str, list[tuple[int, bytes]]] = {}
    for topic, ts, data in messages:
        out.setdefault(topic, []).append((ts, data))
    return out


def _same_recordings(a: Path, b: Path) -> None:
    assert _by_topic(list(iter_messages(a))) == _by_topic(list(iter_messages(b)))
    for u in UNITS:
        ra, rb = read_recording(a, unit=u), read_recording(b, unit=u)
        for name in ("t", "values", "index"):
            np.testing.assert_array_equal(getattr(ra.rate, name), getattr(rb.rate, name))
            np.testing.assert_array_equal(getattr(ra.adc, name), getattr(rb.adc, name))
        np.testing.assert_array_equal(ra.pt100_c, rb.pt100_c)
        np.testing.assert_array_equal(ra.oven_t, rb.oven_t)
        assert ra.events == rb.events and ra.logs == rb.logs and ra.run == rb.run
        assert ra.topic_counts == rb.topic_counts
        for topic in (TOPIC_RATE, TOPIC_ADC):
            for x, y in zip(
                iter_blocks(a, topic, unit=u), iter_blocks(b, topic, unit=u), strict=True
            ):
                assert x[:3] == y[:3] and np.array_equal(x[3], y[3])


def test_each_chunk_holds_one_unit_and_reads_like_the_interleaved_layout(
    tmp_path: Path,
) -> None:
    path, old = tmp_path / "units.mcap", tmp_path / "interleaved.mcap"
    _w, seen = _write(path)
    groups = _chunk_groups(path)
    assert all(len(g) == 1 for g in groups)
    for g in [*UNITS, "shared"]:  # every unit spans several chunks of its own
        assert sum(1 for x in groups if x == {g}) >= (1 if g == "shared" else 3)
    # sequences are per topic and in put order, whatever chunk a message landed in
    with open(path, "rb") as fh:
        seqs: dict[str, list[int]] = {}
        for _s, ch, m in make_reader(fh).iter_messages(log_time_order=False):
            seqs.setdefault(ch.topic, []).append(m.sequence)
    assert all(v == list(range(len(v))) for v in seqs.values())
    # the tap saw every message when it was put, in put order
    assert len(seen) == sum(len(v) for v in seqs.values())
    assert seen[0][0] == "/profile/event" and seen[1][0] == f"/unit/{UNITS[0]}{TOPIC_ADC}"
    # an interleaved file of the same messages (older writers) reads back the same
    _interleaved_copy(path, old)
    assert any(len(g) > 1 for g in _chunk_groups(old))
    _same_recordings(path, old)
    rec = read_recording(path, topics=[TOPIC_PT100], unit="B2")
    assert rec.pt100_c.size == 60 and rec.pt100_c[0] == 1.0


def test_same_bytes_for_the_same_messages(tmp_path: Path) -> None:
    _write(tmp_path / "a.mcap")
    _write(tmp_path / "b.mcap")
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()


def test_recover_keeps_every_unit(tmp_path: Path) -> None:
    path = tmp_path / "units.mcap"
    _write(path)
    rep = recover_recording(path, tmp_path / "fixed.mcap")
    assert rep.complete and rep.chunks_damaged == 0
    _same_recordings(path, tmp_path / "fixed.mcap")


def test_a_flush_writes_every_units_buffer(tmp_path: Path) -> None:
    """Crash-loss policy: after a flush every message put so far, of every unit and of the
    shared topics, is in a closed chunk: an unfinished file cut there recovers all of it."""
    path = tmp_path / "open.mcap"
    w, seen = _write(path, flush_every_s=1.0, stop_at=12.0)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes())  # what a kill -9 right now would leave
    rep = recover_recording(cut, tmp_path / "fixed.mcap")
    assert not rep.complete and rep.truncated_tail_bytes == 0 and rep.chunks_damaged == 0
    got = list(iter_messages(tmp_path / "fixed.mcap"))
    assert _by_topic(got) == _by_topic(sorted(seen, key=lambda m: m[1]))
    assert {t for t, _ts, _d in got} >= {f"/unit/{u}{TOPIC_RATE}" for u in UNITS}
    w.close()


def test_reading_in_file_order_gives_each_topic_in_log_time_order(tmp_path: Path) -> None:
    """``order="topic"`` (and a single topic in log-time order) read chunks in file order:
    each topic's messages come back exactly as the mcap library's log-time merge gives them,
    on the one-unit-per-chunk layout, on the interleaved one, and on files written out of
    order (within one chunk: sorted per chunk; across overlapping chunks: the merge)."""
    path = tmp_path / "units.mcap"
    _write(path, seconds=10.0)
    files = {"units": path, "interleaved": tmp_path / "old.mcap"}
    _interleaved_copy(path, files["interleaved"])
    for name, size in (("shuffled", 4096), ("shuffled-one-chunk", 1 << 24)):
        files[name] = tmp_path / f"{name}.mcap"
        _shuffled_copy(path, files[name], size)
    fast = {}
    for name, f in files.items():
        with open(f, "rb") as fh:
            r = make_reader(fh)
            fast[name] = chunks_in_file_order(r.get_summary(), None) is not None
            merged = [(c.topic, m.log_time, m.data) for _s, c, m in r.iter_messages()]
        assert _by_topic(list(iter_messages(f, order="topic"))) == _by_topic(merged), name
        assert _by_topic(list(iter_messages(f))) == _by_topic(merged), name
        assert list(iter_messages(f)) == merged  # all topics: the whole log-time order
        for topic in (TOPIC_RATE, TOPIC_PT100):  # one unit, one topic: the whole order
            full = f"{UNIT_PREFIX}B2{topic}"
            want = [(topic, ts, d) for ts, d in _by_topic(merged)[full]]
            assert list(iter_messages(f, [topic], unit="B2")) == want, (name, topic)
        u = "C3"
        by_unit = _by_topic(list(iter_messages(f, unit=u, order="topic")))
        assert by_unit[TOPIC_RATE] == _by_topic(merged)[f"{UNIT_PREFIX}{u}{TOPIC_RATE}"]
    # the file-order path is taken where it is exact, the merge where chunks overlap in time
    assert fast == {
        "units": True,
        "interleaved": True,  # log-time order into shared chunks: they follow in time
        "shuffled": False,
        "shuffled-one-chunk": True,
    }
    assert len(_by_topic(merged)[f"{UNIT_PREFIX}A1{TOPIC_RATE}"]) == 20
