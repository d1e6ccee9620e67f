"""Every read is checked (gyrolab/record/integrity.py; docs/reliability.md "Checked reads").

A flipped bit anywhere in a recording, or a cut, is refused by every path that reads it —
exit 2, one line naming the file (and, for a chunk, its byte offset and time span) with the
``gyrolab recover`` hint — never silently wrong data. Files written before the data
section's CRC existed (DataEnd CRC 0) read as before, their chunks checked by their CRCs.
The fast in-process fuzz at the end is the suite's version of benchmarks/fuzz_reads.py.
"""

from __future__ import annotations

import importlib.util
import os
import random
import struct
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from gyrolab.errors import InputError
from gyrolab.logs import read_log
from gyrolab.record.reader import (
    iter_blocks,
    iter_messages,
    list_units,
    read_metadata,
    read_recording,
)
from gyrolab.record.rewrite import rewrite_recording
from gyrolab.record.writer import RecordingWriter

REPO = Path(__file__).resolve().parents[1]
START_NS = 1_700_000_000 * 10**9


def _fuzz_module() -> Any:
    spec = importlib.util.spec_from_file_location(
        "fuzz_reads", REPO / "benchmarks" / "fuzz_reads.py"
    )
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules["fuzz_reads"] = mod
    spec.loader.exec_module(mod)
    return mod


FZ = _fuzz_module()


def write_run(path: Path, seconds: int = 240, chunk_size: int = 4096) -> Path:
    """A recording of every topic, in several small chunks: 10 Hz rate and ADC blocks of
    1 s, PT100 and oven at 1 Hz, events and log messages."""
    rng = np.random.default_rng(1)
    with RecordingWriter(
        path, start_time_ns=START_NS, run={"operator": "t", "unit_serial": "SN1"},
        chunk_size=chunk_size,
    ) as w:  # fmt: skip
        w.write_event(0.0, "run_started")
        for s in range(seconds):
            temp = 25.0 + 0.1 * s
            w.write_rate_block(float(s), 0.1, 10 * s, rng.normal(0.01, 0.001, 10).astype("f4"))
            w.write_adc_block(float(s), 0.1, 10 * s, rng.integers(-999, 999, 10, dtype="i4"))
            w.write_pt100(float(s), 109.7, temp)
            w.write_oven(float(s), 60.0, temp + 1.0, "run")
            if s % 60 == 0:
                w.write_log(float(s), "info", "test", f"minute {s // 60}", kind="note")
        w.write_event(float(seconds), "run_ended", detail="profile complete")
    return path


def old_style(data: bytes) -> bytes:
    """The same file as gyrolab wrote it before the data section's CRC (DataEnd CRC 0)."""
    return FZ.without_data_crc(data)


def flipped(data: bytes, offset: int, bit: int = 2) -> bytes:
    d = bytearray(data)
    d[offset] ^= 1 << bit
    return bytes(d)


def regions(data: bytes, name: str) -> list[tuple[int, int]]:
    return [(a, b) for a, b, n in FZ.regions(data) if n == name]


READERS = {
    "read_recording": lambda p: read_recording(p),
    "read_log": lambda p: read_log(p),
    "iter_messages": lambda p: list(iter_messages(p)),
    "iter_messages topic order": lambda p: list(iter_messages(p, order="topic")),
    "iter_blocks": lambda p: list(iter_blocks(p)),
    "rewrite (apply)": lambda p: rewrite_recording(p, p.with_suffix(".copy")),
}


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_run(tmp_path_factory.mktemp("checked") / "run.mcap")


@pytest.mark.parametrize("style", ["current", "before the data CRC"])
def test_a_damaged_chunk_is_refused_by_every_reader_with_its_offset_and_span(
    run: Path, tmp_path: Path, style: str
) -> None:
    """The issue's probe: one flipped bit inside a chunk gave convert and report wrong
    numbers with exit 0. Every reading path now refuses the file, naming the chunk."""
    data = run.read_bytes() if style == "current" else old_style(run.read_bytes())
    chunks = regions(data, "chunk")
    assert len(chunks) >= 4
    a, b = chunks[2]
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(flipped(data, (a + b) // 2))
    for name, read in READERS.items():
        with pytest.raises(InputError) as e:
            read(bad)
        msg = str(e.value)
        assert msg.startswith(f"{bad}: damaged "), (name, msg)
        assert "gyrolab recover" in msg and "\n" not in msg, (name, msg)
        # caught by the data section's CRC (current) or the chunk's own (before): either
        # way the message says which chunk, and which messages it held
        assert f"damaged chunk at byte {a} (messages at t=" in msg, (name, msg)


def test_the_message_names_the_chunk_and_its_time_span(run: Path, tmp_path: Path) -> None:
    data = run.read_bytes()
    a, b = regions(data, "chunk")[3]
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(flipped(data, b - 10))
    with pytest.raises(InputError, match=rf"damaged chunk at byte {a} \(messages at t=") as e:
        read_recording(bad)
    lo, hi = (float(x) for x in str(e.value).split("t=")[1].split(" s)")[0].split("–"))
    rec = read_recording(run)  # the span is the chunk's, seconds after the first message
    assert 0 < lo < hi <= rec.rate.t[-1] + 1


@pytest.mark.parametrize(
    "where", ["magic", "header", "metadata", "message index", "data end", "chunk index",
              "statistics", "footer", "trailing magic"],
)  # fmt: skip
def test_bytes_outside_the_chunks_are_checked_too(run: Path, tmp_path: Path, where: str) -> None:
    """Metadata records have no CRC of their own: the data section's covers them (and the
    header and message indexes); the summary's covers the indexes; the file's end is its
    footer and magic. Every bit is checked: each flip here is refused."""
    data = run.read_bytes()
    if where == "trailing magic":
        a, b = len(data) - 8, len(data)
    else:
        a, b = (regions(data, where) or [(None, None)])[0]
    assert a is not None, where
    rng = random.Random(where)
    bad = tmp_path / "bad.mcap"
    for _ in range(5):
        bad.write_bytes(flipped(data, rng.randrange(a, b), rng.randrange(8)))
        with pytest.raises(InputError, match=r"damaged|truncated|not an MCAP") as e:
            read_recording(bad)
        assert str(e.value).startswith(f"{bad}: ")


def test_a_cut_file_is_refused_and_recover_is_named(run: Path, tmp_path: Path) -> None:
    data = run.read_bytes()
    bad = tmp_path / "cut.mcap"
    for n in (len(data) - 1, len(data) // 2, 100, 9):
        bad.write_bytes(data[:n])
        with pytest.raises(InputError, match="truncated|not an MCAP") as e:
            read_metadata(bad)
        assert "gyrolab recover" in str(e.value) or n < 16


def test_files_without_the_data_crc_read_as_before(run: Path, tmp_path: Path) -> None:
    """Recordings written before the data section's CRC keep reading (their DataEnd CRC is
    0: not computed); a flip in what no reader uses (a message index) changes nothing."""
    old = tmp_path / "old.mcap"
    old.write_bytes(old_style(run.read_bytes()))
    want = read_recording(run)
    got = read_recording(old)
    np.testing.assert_array_equal(got.rate.values, want.rate.values)
    assert got.metadata == want.metadata and got.events == want.events
    a, b = regions(old.read_bytes(), "message index")[0]
    old.write_bytes(flipped(old.read_bytes(), (a + b) // 2))
    np.testing.assert_array_equal(read_recording(old).rate.values, want.rate.values)
    assert list(iter_messages(old)) == list(iter_messages(run))
    assert list_units(old) == []


def test_the_writer_records_every_crc(run: Path) -> None:
    data = run.read_bytes()
    footer = len(data) - 8 - 29
    _op, _ln, summary_start, _sos, summary_crc = struct.unpack_from("<BQQQI", data, footer)
    (data_crc,) = struct.unpack_from("<I", data, summary_start - 4)
    assert summary_crc and data_crc


def test_fuzz_in_process(tmp_path: Path) -> None:
    """The suite's version of benchmarks/fuzz_reads.py: random bit flips and cuts of a
    recording through report, convert, compensate, apply and discrepancy in this process.
    In the current format every bit is covered by a CRC, so every case is a refusal: exit 2,
    one line naming the damaged file, nothing left where the output would go."""
    fz = FZ.Fuzz(tmp_path)
    fz.intact.parent.mkdir(parents=True)
    write_run(fz.intact, seconds=120)
    fz.model.mkdir(parents=True)  # apply checks the run before it reads the model
    (fz.model / "model.json").write_text("{}")
    intact = fz.intact.read_bytes()
    regs = FZ.regions(intact)
    rng = random.Random(25)
    for _ in range(40):
        off = rng.randrange(len(intact))
        fz.case("flip", off, flipped(intact, off, rng.randrange(8)), regs)
    for _ in range(10):
        off = rng.randrange(len(intact))
        fz.case("cut", off, intact[:off], regs)
    bad = [o for o in fz.outcomes if o.verdict != "refused"]
    assert not bad, bad[:5]
    assert len(fz.outcomes) == 50 * len(FZ.COMMANDS)


def test_no_code_reads_mcap_around_the_checks() -> None:
    """Only gyrolab/record/source.py opens MCAP files for reading (the mcap library's
    readers and record parsers), writer.py writes them; anything else goes through
    ``source.opened`` and its checks. (mcap-ros2-support's CDR decoder is a decoder of
    message bytes the source has already checked.)"""
    allowed = {"record/source.py", "record/writer.py"}
    offenders = []
    for f in sorted((REPO / "gyrolab").rglob("*.py")):
        rel = str(f.relative_to(REPO / "gyrolab"))
        for n, line in enumerate(f.read_text(encoding="utf-8").splitlines(), 1):
            code = line.split("#")[0]
            if ("from mcap" in code or "import mcap" in code) and "mcap_ros2.decoder" not in code:
                if rel not in allowed:
                    offenders.append(f"{rel}:{n}: {line.strip()}")
    assert not offenders, offenders


@pytest.mark.parametrize(
    "topic, data",
    [
        ("/temperature/pt100", b'{"t": 1.0}'),
        ("/temperature/pt100", b"\xff\xfe not json"),
        ("/gyro/rate", b"\x22\xff\xff\xff\xff\x0f"),
    ],
    ids=["a field missing", "not text", "a block that runs past its message"],
)
def test_a_message_its_writer_got_wrong_is_one_line(
    tmp_path: Path, topic: str, data: bytes
) -> None:
    """Its CRC is right (the writer wrote what it meant), its content is not: read_recording
    says which message, instead of a KeyError or UnicodeDecodeError traceback."""
    path = tmp_path / "odd.mcap"
    with RecordingWriter(path, start_time_ns=START_NS, run={}) as w:
        w.write_rate_block(0.0, 0.1, 0, np.zeros(10, "f4"))
        w._put(topic, 1.0, data)
    with pytest.raises(InputError, match=rf"a {topic} message \(log time \d+ ns\) does not decode"):
        read_recording(path)


def test_a_file_is_checked_once_per_process_until_it_changes(
    run: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A command opens its recording several times; the data section's CRC is summed on the
    first open only, and again as soon as the file's stamps show any change."""
    import gyrolab.record.source as source

    f = tmp_path / "run.mcap"
    f.write_bytes(run.read_bytes())
    sums = []
    real = source.check_data_section
    monkeypatch.setattr(source, "check_data_section", lambda *a: sums.append(1) or real(*a))
    now = source.time.time_ns
    monkeypatch.setattr(source.time, "time_ns", lambda: now() + 10**10)  # as if it settled
    read_metadata(f)
    list(iter_blocks(f))
    assert len(sums) == 1
    st = f.stat()
    f.write_bytes(flipped(f.read_bytes(), len(f.read_bytes()) // 2))
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # a stamp that surely differs
    with pytest.raises(InputError, match="damaged"):
        read_metadata(f)
    assert len(sums) == 2


def test_a_damaged_simulation_record_in_an_older_file_is_one_line(tmp_path: Path) -> None:
    """An older file's metadata records are under no CRC; the oracle's model (the
    ``sim_provenance`` record's TOML) that no longer decodes is one line naming the file
    (benchmarks/fuzz_reads.py --older-format found compensate's TOMLDecodeError traceback)."""
    from gyrolab.cli import main
    from gyrolab.compensation.oracle import oracle_rate

    prof = tmp_path / "p.toml"
    prof.write_text("[[step]]\nsetpoint_c = 25\nduration_s = 20\n")
    run = tmp_path / "run.mcap"
    assert main(["simulate", "--profile", str(prof), "--rate", "10", "--out", str(run)]) == 0
    data = old_style(run.read_bytes())
    at = data.index(b"[thermal]")
    old = tmp_path / "old.mcap"
    old.write_bytes(data[:at] + b"[thermal" + b"\x00" + data[at + 9 :])  # same length
    with pytest.raises(InputError, match="sim_provenance model does not decode") as e:
        oracle_rate(read_recording(old))
    assert e.value.path == str(old)


def test_a_summary_is_parsed_once_and_reused_only_for_the_same_bytes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Opening a recording again reuses its parsed summary (registration opens a fresh
    recording five times), but only while the summary's bytes are the ones parsed: a file
    written anew at the same path, at once, is parsed again and read as it now is."""
    from mcap.reader import SeekingReader

    from gyrolab.record.source import opened

    parses: list[int] = []
    real = SeekingReader.get_summary

    def counting(self: Any) -> Any:
        parses.append(1)
        return real(self)

    monkeypatch.setattr(SeekingReader, "get_summary", counting)

    def write(path: Path, n: int) -> None:
        with RecordingWriter(path, start_time_ns=0, run={}, bench={}) as w:
            for k in range(n):
                w.write_pt100(float(k), 109.7, 25.0)

    f = tmp_path / "r.mcap"
    write(f, 3)
    for _ in range(3):
        with opened(f) as src:
            assert src.summary.statistics.message_count == 3
    assert len(parses) == 1
    write(f, 5)  # the same path, written again within the same second
    with opened(f) as src:
        assert src.summary.statistics.message_count == 5
    assert len(parses) == 2
