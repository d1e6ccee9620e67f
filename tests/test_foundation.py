"""The package foundation: CLI contract, profiles, recording round trip, atomic outputs."""

from __future__ import annotations

import numpy as np
import pytest

from gyrolab.cli import HANDLERS, main
from gyrolab.errors import InputError
from gyrolab.outputs import atomic_file
from gyrolab.profiles.profile import load_profile
from gyrolab.record.blocks import decode_block, encode_block
from gyrolab.record.format import TOPIC_RATE
from gyrolab.record.reader import read_recording
from gyrolab.record.writer import RecordingWriter


def test_cli_lists_every_design_subcommand() -> None:
    assert set(HANDLERS) == {
        "simulate",
        "acquire",
        "compensate",
        "apply",
        "report",
        "discrepancy",
        "recover",
        "demo",
        "convert",  # issue 16
        "export",  # issue 15: firmware and tool formats
        "batch",
        "fleet",
        "runs",  # issue 29: the catalogue
        "profile",  # issue 30: profile design
    }


def test_cli_bad_arguments_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--out" in err[0]


def test_paper_profile_shape() -> None:
    p = load_profile("paper")
    assert p.duration_s == 13 * 3600
    sps = [s.setpoint_c for s in p.steps]
    assert sps[0] == 25 and sps[1] == 60 and sps[-1] == -40
    assert np.all(np.diff(sps[1:]) == -10)
    assert p.setpoint_at(3600.5) == 60.0


def test_profile_errors_name_the_file(tmp_path) -> None:
    with pytest.raises(InputError, match="unknown profile"):
        load_profile("nope")
    bad = tmp_path / "bad.toml"
    bad.write_text("[[step]]\nsetpoint_c = 20\n")
    with pytest.raises(InputError, match="bad.toml"):
        load_profile(bad)
    good = tmp_path / "good.toml"
    good.write_text('name = "g"\n[[step]]\nsetpoint_c = 20\nduration_s = 60\n')
    assert load_profile(good).steps[0].setpoint_c == 20


def test_block_codec_round_trip() -> None:
    counts = np.array([-(2**23), -1, 0, 1, 2**23 - 1], dtype=np.int32)
    t0, period, first, arr = decode_block(encode_block(1.5, 0.01, 123456789, counts, "adc"), "adc")
    assert (t0, period, first) == (1.5, 0.01, 123456789)
    np.testing.assert_array_equal(arr, counts)


def test_recording_round_trip_and_gaps(tmp_path) -> None:
    path = tmp_path / "r.mcap"
    with RecordingWriter(path, start_time_ns=10**18, run={"operator": "t"}) as w:
        w.write_rate_block(0.0, 0.01, 0, np.ones(100))
        w.write_rate_block(2.0, 0.01, 200, np.full(100, 2.0))  # 100 samples lost
        w.write_pt100(0.0, 100.0, 0.0)
        w.write_event(0.0, "run_started")
    rec = read_recording(path)
    assert rec.run["operator"] == "t"
    assert rec.topic_counts[TOPIC_RATE] == 2
    assert rec.rate is not None and rec.rate.gaps() == [(pytest.approx(0.99), 100)]
    assert rec.rate.rate_hz == pytest.approx(100.0)


def test_reader_rejects_foreign_file(tmp_path) -> None:
    p = tmp_path / "x.mcap"
    p.write_bytes(b"hello world")
    with pytest.raises(InputError, match="not an MCAP file"):
        read_recording(p)


def test_atomic_file_leaves_nothing_on_error(tmp_path) -> None:
    target = tmp_path / "out.bin"
    with pytest.raises(RuntimeError), atomic_file(target) as tmp:
        tmp.write_bytes(b"half")
        raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []
    with atomic_file(target) as tmp:
        tmp.write_bytes(b"whole")
    assert target.read_bytes() == b"whole"
    with pytest.raises(InputError, match="already exists"), atomic_file(target):
        pass
