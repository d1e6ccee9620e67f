"""gyrolab/record/: the typed metadata (old spellings still read), rewriting a recording,
and the one MCAP writer. Small files written in-process; no simulation."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from gyrolab.record.blocks import decode_block, encode_block
from gyrolab.record.format import TOPIC_PT100, TOPIC_RATE
from gyrolab.record.metadata import BenchMetadata, RunMetadata
from gyrolab.record.reader import iter_blocks, iter_messages, read_metadata, read_recording
from gyrolab.record.rewrite import Message, rewrite_recording
from gyrolab.record.writer import RecordingWriter
from gyrolab.report.outcome import profile_setpoints, run_outcome

REPO = Path(__file__).resolve().parents[1]
PROFILE = {
    "name": "two",
    "description": "",
    "ambient_c": 25.0,
    "step": [{"setpoint_c": 25.0, "duration_s": 10.0}, {"setpoint_c": 40.0, "duration_s": 10.0}],
}
# What `gyrolab simulate` wrote before the metadata had one owner (commit a7837da).
OLD_RUN = {
    "operator": "gyrolab simulate",
    "source": "simulation",
    "start_time": "2021-04-20T00:00:00Z",
    "profile": "two",
    "profile_definition": PROFILE,
    "seed": 3,
    "rate_hz": 100.0,
    "software_version": "0.1.0",
}
OLD_ADC = {"bits": 24, "vref_v": 2.5, "gain_v_per_dps": 0.01, "offset_v": 0.0, "rate_hz": 100.0}
OLD_BENCH = {
    "bench": "sim",
    "instruments": {"dmm": {"identity": "HEWLETT-PACKARD,34401A,SIM00001,11-5-2"}},
    "adc": OLD_ADC,
    "pt100": {"standard": "IEC 60751", "r0_ohm": 100.0, "wiring": "4-wire", "on": "case"},
}


def _write(path: Path, run: object, bench: object, units: list[str] | None = None) -> None:
    with RecordingWriter(path, start_time_ns=10**18, run=run, bench=bench, units=units) as w:
        for k in range(3):
            t = np.arange(100) * 0.01 + k
            for u in units or [None]:
                w.write_rate_block(float(k), 0.01, 100 * k, 1e-3 * np.sin(t), unit=u)
                w.write_pt100(float(k), 100.0 + k, 25.0 + k, unit=u)
        w.write_event(0.0, "step_started", 0, setpoint_c=25.0)
        w.write_event(3.0, "run_ended", -1)


def test_an_old_simulated_file_reads_normalised(tmp_path: Path) -> None:
    """A file with the old spellings (source "simulation", profile by name with the table
    beside it, bench.adc.rate_hz, bench.bench) reads in the documented shape."""
    path = tmp_path / "old.mcap"
    _write(path, OLD_RUN, OLD_BENCH)
    rec = read_recording(path)
    assert rec.run["source"] == "simulate" and rec.run["profile"] == PROFILE
    assert "profile_definition" not in rec.run
    assert rec.bench["name"] == "sim" and rec.bench["simulated"] is True
    assert rec.bench["adc"]["sample_rate_hz"] == 100.0 and "rate_hz" not in rec.bench["adc"]
    assert rec.run["rate_hz"] == 100.0 and rec.bench["pt100"]["r0_ohm"] == 100.0  # kept
    assert read_metadata(path)["run"] == rec.run  # every reader gets the same shape
    # what the report reads from it, with no workaround of its own
    assert profile_setpoints(rec) == [25.0, 40.0]
    assert run_outcome(rec).safe_state == "not applicable"  # a simulated run has no chamber
    run, bench = RunMetadata.from_dict(rec.run), BenchMetadata.from_dict(rec.bench)
    assert run.source == "simulate" and run.seed == 3 and run.extra == {"rate_hz": 100.0}
    assert bench.sample_rate_hz() == 100.0 and set(bench.extra) == {"instruments", "pt100"}


def test_an_old_multi_unit_file_reads_each_units_rate(tmp_path: Path) -> None:
    path = tmp_path / "old-units.mcap"
    units = {s: {"adc": {**OLD_ADC, "rate_hz": r}} for s, r in (("A1", 100.0), ("B2", 50.0))}
    _write(path, OLD_RUN, {**OLD_BENCH, "units": units}, units=["A1", "B2"])
    bench = BenchMetadata.from_dict(read_recording(path, unit="B2").bench)
    assert bench.sample_rate_hz("A1") == 100.0 and bench.sample_rate_hz("B2") == 50.0
    assert bench.units is not None and "rate_hz" not in bench.units["B2"]["adc"]


def test_the_rate_goes_to_a_callback_in_the_pass_that_reads_the_rest(tmp_path: Path) -> None:
    """``on_rate``: one unit's rate blocks, in order, to the caller (not kept), the PT100
    readings read in the same pass exactly as without it."""
    path = tmp_path / "units.mcap"
    _write(path, OLD_RUN, OLD_BENCH, units=["A1", "B2"])
    topics = [TOPIC_PT100, TOPIC_RATE]
    blocks: list[tuple[float, float, int, np.ndarray]] = []
    rec = read_recording(path, topics=topics, unit="B2", on_rate=blocks.append)
    whole = read_recording(path, topics=topics, unit="B2")
    assert rec.rate is None and rec.topic_counts == whole.topic_counts == {
        TOPIC_PT100: 3,
        TOPIC_RATE: 3,
    }
    for k in ("pt100_t", "pt100_ohm", "pt100_c"):
        np.testing.assert_array_equal(getattr(rec, k), getattr(whole, k))
    streamed = list(iter_blocks(path, TOPIC_RATE, unit="B2"))
    heads = [(k, 0.01, 100 * k) for k in (0, 1, 2)]  # (t0, period, first index)
    assert [b[:3] for b in blocks] == [b[:3] for b in streamed] == heads
    assert whole.rate is not None
    np.testing.assert_array_equal(np.concatenate([b[3] for b in blocks]), whole.rate.values)


def test_typed_metadata_round_trips_and_keeps_unknown_keys() -> None:
    run = RunMetadata(
        source="acquire",
        start_time="2026-01-01T00:00:00+00:00",
        profile=PROFILE,
        operator="A",
        axes=3,
        extra={"site": "lab 2"},
    )
    d = run.to_dict()
    assert d["axes"] == 3 and d["site"] == "lab 2" and d["seed"] is None and "units" not in d
    assert RunMetadata.from_dict(json.loads(json.dumps(d))) == run
    bench = BenchMetadata(name="b", simulated=False, adc={"sample_rate_hz": 200})
    assert BenchMetadata.from_dict(bench.to_dict()) == bench
    assert bench.sample_rate_hz() == 200.0 and BenchMetadata("x", False).sample_rate_hz() is None


def test_the_writer_writes_typed_metadata_with_the_layout(tmp_path: Path) -> None:
    path = tmp_path / "typed.mcap"
    run = RunMetadata(source="simulate", start_time="t", profile=PROFILE, seed=1, speed="max")
    _write(path, run, BenchMetadata(name="sim", simulated=True), units=["U1"])
    meta = read_metadata(path)
    # values read back JSON-decoded: the format version "1" comes back as 1
    assert meta["run"] == {**run.to_dict(), "units": ["U1"], "format_version": 1}
    assert meta["bench"]["limits"] is None and meta["bench"]["name"] == "sim"


def test_rewrite_transforms_adds_topics_and_keeps_times_and_sequences(tmp_path: Path) -> None:
    src, dst = tmp_path / "in.mcap", tmp_path / "out.mcap"
    _write(src, {"operator": "x"}, {"name": "b"})

    def double(m: Message) -> list[Message]:
        if m.topic != TOPIC_RATE:
            return [m]
        t0, period, first, v = decode_block(m.data, "rate")
        data = encode_block(t0, period, first, 2 * v, "rate")
        return [
            Message("/gyro/copy", m.log_time, m.publish_time, m.sequence, m.data),
            Message(m.topic, m.log_time, m.publish_time, m.sequence, data),
        ]

    tail = [
        Message("/gyro/extra", 10**18, 10**18, 0, encode_block(0.0, 1.0, 0, np.ones(2), "rate"))
    ]
    rewrite_recording(
        src,
        dst,
        transform=double,
        tail=tail,
        derived={"/gyro/copy": TOPIC_RATE, "/gyro/extra": TOPIC_RATE},
        metadata={"note": {"why": "test"}},
    )
    a, b = read_recording(src), read_recording(dst)
    assert np.array_equal(b.rate.values, 2 * a.rate.values.astype(np.float32))
    assert np.array_equal(b.pt100_c, a.pt100_c) and b.run == a.run and a.run["operator"] == "x"
    assert read_metadata(dst)["note"] == {"why": "test"}
    copied = [(ts, decode_block(d, "rate")[0]) for _, ts, d in iter_messages(dst, ["/gyro/copy"])]
    orig = [(ts, decode_block(d, "rate")[0]) for _, ts, d in iter_messages(src, [TOPIC_RATE])]
    assert copied == orig and len(list(iter_messages(dst, ["/gyro/extra"]))) == 1
    assert len(list(iter_messages(dst, [TOPIC_PT100]))) == 3


def test_one_module_writes_mcap() -> None:
    """Every MCAP file gyrolab writes goes through gyrolab/record/writer.py: its McapFile
    builds the records (no module uses the mcap library's writer, the reference of
    tests/test_mcap_file.py), and no other module packs an MCAP record."""
    sources = {str(p.relative_to(REPO)): p.read_text() for p in (REPO / "gyrolab").rglob("*.py")}
    assert [f for f, text in sorted(sources.items()) if re.search(r"\bmcap\.writer\b", text)] == []
    packers = [  # a record packed for writing (a reader packs the footer only for its CRC)
        f
        for f, text in sorted(sources.items())
        if any(
            re.search(r"(pack|_record)\(OP_", line) and "crc" not in line
            for line in text.splitlines()
        )
    ]
    assert packers == ["gyrolab/record/writer.py"]


def test_a_damaged_source_is_an_input_error(tmp_path: Path) -> None:
    from gyrolab.errors import InputError

    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap at all")
    with pytest.raises(InputError, match="not an MCAP"):
        rewrite_recording(bad, tmp_path / "out.mcap")
