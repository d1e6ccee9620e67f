"""The axis count: ADC frames and /gyro/rate, /gyro/adc blocks of 1–3 axes. Single-axis
bytes are exactly those of the format before axis counts; multi-axis blocks decode with
the protobuf library from the FileDescriptorSet stored in the file; the simulator makes a
3-axis unit whose axis x is the single-axis unit of the same seed."""

from __future__ import annotations

import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

from gyrolab.cli import main
from gyrolab.framing import FrameDecoder, encode_frame, frame_size
from gyrolab.record.blocks import decode_block, encode_block
from gyrolab.record.format import file_descriptor_set
from gyrolab.record.reader import read_recording
from gyrolab.record.writer import RecordingWriter


def _proto(name: str):
    fds = descriptor_pb2.FileDescriptorSet.FromString(file_descriptor_set())
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(name))


def test_single_axis_block_bytes_unchanged() -> None:
    v = np.array([1.5, -2.25, 3.0], dtype=np.float32)
    b = encode_block(1.0, 0.01, 7, v, "rate")
    assert b"\x28" not in b[-4:] and len(b) == 1 + 8 + 1 + 8 + 1 + 1 + 1 + 1 + 12
    t0, period, first, arr = decode_block(b, "rate")
    assert (t0, period, first) == (1.0, 0.01, 7) and arr.ndim == 1
    np.testing.assert_array_equal(arr, v)


@pytest.mark.parametrize("axes", [2, 3])
def test_multi_axis_blocks_round_trip_and_protobuf(axes: int) -> None:
    v = np.arange(4 * axes, dtype=np.float32).reshape(4, axes) - 3.5
    b = encode_block(2.0, 0.1, 40, v, "rate")
    _t0, _p, first, arr = decode_block(b, "rate")
    assert first == 40 and arr.shape == (4, axes)
    np.testing.assert_array_equal(arr, v)
    msg = _proto("gyrolab.GyroRateBlock").FromString(b)  # the stored schema decodes it
    assert msg.axes == axes and list(msg.rate_dps) == v.ravel().tolist()
    c = (np.arange(3 * axes, dtype=np.int32).reshape(3, axes) - 4) * 1000
    m = _proto("gyrolab.GyroAdcBlock").FromString(encode_block(0.0, 0.1, 0, c, "adc"))
    assert m.axes == axes and list(m.counts) == c.ravel().tolist()
    with pytest.raises(ValueError):
        encode_block(0.0, 0.1, 0, np.zeros((2, 4)), "rate")


def test_recording_reads_axes(tmp_path) -> None:
    p = tmp_path / "r.mcap"
    v = np.random.default_rng(0).normal(size=(30, 3)).astype(np.float32)
    with RecordingWriter(p, start_time_ns=0) as w:
        w.write_rate_block(0.0, 0.1, 0, v[:10])
        w.write_rate_block(2.0, 0.1, 20, v[20:])  # 10 samples lost
    rec = read_recording(p)
    assert rec.axes == 3 and rec.rate.values.shape == (20, 3)
    assert rec.rate.gaps() == [(pytest.approx(0.9), 10)]
    np.testing.assert_array_equal(rec.axis(2).rate.values, np.r_[v[:10, 2], v[20:, 2]])
    bad = tmp_path / "mixed.mcap"
    with RecordingWriter(bad, start_time_ns=0) as w:
        w.write_rate_block(0.0, 0.1, 0, v[:10])
        w.write_rate_block(1.0, 0.1, 10, v[10:20, 0])
    assert main(["report", str(bad), "--out", str(tmp_path / "rep")]) == 2
    # the viewer summary keeps axis x in its own fields and lists every axis
    import json

    from gyrolab.record.format import TOPIC_RATE_SUMMARY
    from gyrolab.record.reader import iter_messages

    s = [json.loads(d) for _t, _ts, d in iter_messages(p, [TOPIC_RATE_SUMMARY])]
    assert [m["n"] for m in s] == [10, 10]
    assert s[0]["mean_dps"] == pytest.approx(float(v[:10, 0].astype(float).mean()))
    assert s[1]["axes_max_dps"] == pytest.approx(v[20:].astype(float).max(axis=0).tolist())
    # convert writes one rate column per axis (rate_x_dps, …); the gap stays a jump in index
    out = tmp_path / "r.csv"
    assert main(["convert", str(p), "--to", "csv", "--out", str(out)]) == 0
    lines = [ln for ln in out.read_text().splitlines() if not ln.startswith("#")]
    t = np.genfromtxt(lines, delimiter=",", names=True)
    assert t.dtype.names == ("index", "t_s", "rate_x_dps", "rate_y_dps", "rate_z_dps",
                             "pt100_c", "setpoint_c")  # fmt: skip
    np.testing.assert_array_equal(t["index"], np.r_[0:10, 20:30])
    for j, a in enumerate("xyz"):
        np.testing.assert_array_equal(t[f"rate_{a}_dps"].astype(np.float32), rec.rate.values[:, j])
    assert main(["convert", str(bad), "--to", "csv", "--out", str(tmp_path / "m.csv")]) == 2
    assert not (tmp_path / "m.csv").exists()


def test_adc_frame_with_three_axes() -> None:
    counts = np.arange(-15, 15, dtype=np.int32).reshape(10, 3) * 1000
    f = encode_frame(5, 1_000_000, counts)
    assert len(f) == frame_size(10, 3) == 18 + 90
    assert int.from_bytes(f[2:4], "little") == 12 + 3 * 10 * 3
    dec = FrameDecoder(10, rate_hz=100.0, axes=3)
    got = dec.feed(f + encode_frame(6, 1_100_000, counts + 1))
    assert got.counts.shape == (2, 30)
    np.testing.assert_array_equal(got.counts[0].reshape(10, 3), counts)
    # a single-axis decoder rejects 3-axis frames by their length, and vice versa
    assert len(FrameDecoder(10).feed(f)) == 0
    assert len(dec.feed(encode_frame(7, 1_200_000, counts[:, 0]))) == 0


def test_simulate_cli_three_axes(tmp_path) -> None:
    base = tmp_path / "x.toml"
    base.write_text(
        'format = "gyrolab-sim-model/1"\n[[effect]]\nname = "bias_poly"\n[[effect]]\nname = "arw"\n'
    )
    y = tmp_path / "y.toml"
    y.write_text(
        'format = "gyrolab-sim-model/1"\n[[effect]]\nname = "bias_poly"\nc1 = -2e-4\n'
        '[[effect]]\nname = "arw"\n'
    )
    prof = tmp_path / "p.toml"
    prof.write_text('name = "tiny"\n[[step]]\nsetpoint_c = 30.0\nduration_s = 20.0\n')
    one, three = tmp_path / "one.mcap", tmp_path / "three.mcap"
    args = ["simulate", "--profile", str(prof), "--model", str(base), "--rate", "20"]
    assert main([*args, "--out", str(one)]) == 0
    assert main([*args, "--axis-model", str(y), "--axis-model", str(y), "--out", str(three)]) == 0
    r1, r3 = read_recording(one), read_recording(three)
    assert r3.rate.values.shape == (r1.rate.t.size, 3)
    np.testing.assert_array_equal(r3.rate.values[:, 0], r1.rate.values)
    assert not np.array_equal(r3.rate.values[:, 1], r3.rate.values[:, 2])  # own noise
    other = tmp_path / "hot.toml"
    other.write_text('format = "gyrolab-sim-model/1"\n[thermal]\nair_tau_s = 10.0\n')
    assert main([*args, "--axis-model", str(other), "--out", str(tmp_path / "no.mcap")]) == 2
    assert not (tmp_path / "no.mcap").exists()
