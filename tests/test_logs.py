"""Reading the logs users have (gyrolab.logs): ROS 2 MCAP (sensor_msgs/Imu + Temperature),
PX4 ULog (sensor_gyro) and ArduPilot DataFlash (IMU), each written by the test through
its own library or byte by byte from its specification and read back — units converted,
gaps kept — then through compensate, report (Allan) and the kalibr export."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from logwriters import write_dataflash, write_ros2, write_ulog
from test_pipeline import SMALL

from gyrolab.cli import main
from gyrolab.compensation.prepare import causal_temperature
from gyrolab.errors import InputError
from gyrolab.logs import detect_format, read_log
from gyrolab.profiles.profile import load_profile
from gyrolab.record.reader import read_recording
from gyrolab.sim.model import nominal_model
from gyrolab.sim.simulate import simulate_run

torch.set_num_threads(1)
DROP = slice(5000, 5037)  # 37 samples lost: a gap every reader must keep


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    d = tmp_path_factory.mktemp("logs")
    m = nominal_model()
    others = [m.with_effect("bias_poly", c0=-0.01, c1=-2e-4), m.with_effect("bias_poly", c0=0.0)]
    simulate_run(
        d / "sim.mcap",
        load_profile("short"),
        m,
        rate_hz=10.0,
        seed=7,
        axis_models=others,
        show_progress=False,
    )
    rec = read_recording(d / "sim.mcap")
    keep = np.ones(rec.rate.t.size, bool)
    keep[DROP] = False
    t = rec.rate.t[keep]
    g = np.radians(rec.rate.values[keep])  # the logs carry rad/s
    T = causal_temperature(t, rec.pt100_t, rec.pt100_c)  # IMU temperature per sample
    t_us = (3_000_000 + np.rint(t * 1e6)).astype(np.int64)
    return {
        "dir": d,
        "t": t,
        "dps": rec.rate.values[keep],
        "temp": T,
        "ros2": write_ros2(d / "imu.mcap", t, g, rec.pt100_t, rec.pt100_c, 1.7e9),
        "ulog": write_ulog(d / "imu.ulg", t_us, g, T, 2490378),
        "dataflash": write_dataflash(d / "imu.bin", t_us, g, T),
    }


@pytest.mark.parametrize("fmt", ["ros2", "ulog", "dataflash"])
def test_reader_units_gaps_and_temperature(logs: dict, fmt: str) -> None:
    path = logs[fmt]
    assert detect_format(path) == fmt
    rec = read_log(path)
    s = rec.rate
    assert rec.axes == 3 and s.values.shape == logs["dps"].shape
    tol = 0.0 if fmt == "ros2" else 1e-6  # ULog/DataFlash store float32 rad/s
    np.testing.assert_allclose(s.values, logs["dps"], rtol=tol, atol=1e-9)
    np.testing.assert_allclose(s.t, logs["t"] - logs["t"][0], atol=2e-6)
    assert s.period == pytest.approx(0.1, rel=1e-5)
    assert s.gaps() == [(pytest.approx(logs["t"][DROP.start - 1] - logs["t"][0], abs=2e-6), 37)]
    if fmt == "ros2":
        assert rec.pt100_t.size == 2880 and rec.run["temperature_topic"] == "/imu/temperature"
    else:
        np.testing.assert_allclose(rec.pt100_c, logs["temp"], rtol=1e-6)


def test_reader_bad_input_is_one_line(logs: dict, tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no topic '/nope'"):
        read_log(logs["ros2"], temperature_topic="/nope")
    with pytest.raises(InputError, match="is sensor_msgs/msg/Imu"):
        read_log(logs["ros2"], temperature_topic="/imu/data")
    with pytest.raises(InputError, match="no sensor_gyro instance 1"):
        read_log(logs["ulog"], instance=1)
    with pytest.raises(InputError, match="no IMU messages of instance 2"):
        read_log(logs["dataflash"], instance=2)
    nan = tmp_path / "nan.ulg"
    t_us = np.arange(100, dtype=np.int64) * 10_000 + 1_000_000
    write_ulog(nan, t_us, np.zeros((100, 3)), np.full(100, np.nan), 1)
    with pytest.raises(InputError, match="no finite temperature readings"):
        read_log(nan)
    junk = tmp_path / "junk.bin"
    junk.write_bytes(b"hello world")
    with pytest.raises(InputError, match="not an MCAP file"):
        read_log(junk)


def test_ros2_imu_fast_path_equals_the_library(tmp_path: Path) -> None:
    """The fixed-offset Imu read (gyrolab.logs.ros2.imu_fast) against mcap-ros2-support's
    decoder, message by message, with frame ids of every length mod 8 (CDR alignment)."""
    from logwriters import IMU_MSGDEF
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from mcap_ros2.writer import Writer

    from gyrolab.logs.ros2 import imu_fast

    p = tmp_path / "ids.mcap"
    rng = np.random.default_rng(1)
    with open(p, "wb") as fh:
        w = Writer(fh)
        s = w.register_msgdef("sensor_msgs/msg/Imu", IMU_MSGDEF)
        for k in range(24):
            v = rng.normal(size=3)
            msg = {
                "header": {"stamp": {"sec": 1000 + k, "nanosec": 7 * k}, "frame_id": "f" * k},
                "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
                "orientation_covariance": [0.5] * 9,
                "angular_velocity": {"x": v[0], "y": v[1], "z": v[2]},
                "angular_velocity_covariance": [0.0] * 9,
                "linear_acceleration": {"x": 0.1 * k, "y": -0.2, "z": 9.81},
                "linear_acceleration_covariance": [0.0] * 9,
            }
            w.write_message("/imu", s, msg, log_time=k, publish_time=k)
        w.finish()
    with open(p, "rb") as fh:
        n = 0
        for _s, _c, m, msg in make_reader(
            fh, decoder_factories=[DecoderFactory()]
        ).iter_decoded_messages():
            a, f = msg.angular_velocity, msg.linear_acceleration
            st = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            assert imu_fast(m.data) == (st, a.x, a.y, a.z, f.x, f.y, f.z)
            n += 1
    assert n == 24


def test_unstamped_ros2_bag_uses_log_time(tmp_path: Path) -> None:
    t = np.arange(200) / 50.0
    g = np.zeros((200, 3))
    g[:, 2] = 0.01
    p = write_ros2(tmp_path / "u.mcap", t, g, t[::50], 20.0 + t[::50], 1.7e9, stamp=False)
    rec = read_log(p)
    assert rec.run["time"].startswith("MCAP log_time")
    np.testing.assert_allclose(rec.rate.t, t, atol=1e-6)
    np.testing.assert_allclose(rec.rate.values[:, 2], np.degrees(0.01))
    assert rec.pt100_c.tolist() == pytest.approx((20.0 + t[::50]).tolist())


def test_compensate_a_ros2_bag_per_axis(logs: dict, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("gyrolab.compensation.commands.DEFAULT_CONFIG", SMALL)
    out = logs["dir"] / "model_ros2"
    assert (
        main(
            [
                "compensate",
                str(logs["ros2"]),
                "--temperature-topic",
                "/imu/temperature",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    m = json.loads((out / "metrics.json").read_text())
    assert set(m["axes"]) == {"x", "y", "z"}
    for a in "xyz":
        assert m["axes"][a]["run"] == str(logs["ros2"])
        assert m["axes"][a]["compensated_streaming"]["rms_deg_per_s"] > 0
    # the same model scores the same samples read from the other two formats alike
    for fmt in ("ulog", "dataflash"):
        k = main(
            [
                "export",
                str(out),
                "--format",
                "kalibr",
                "--run",
                str(logs[fmt]),
                "--out",
                str(logs["dir"] / f"imu_{fmt}.yaml"),
            ]
        )
        assert k == 0


def test_log_options_from_the_command_line(logs: dict, tmp_path: Path) -> None:
    rec = read_recording(logs["dir"] / "sim.mcap")
    t, n = rec.rate.t, 600
    p = write_ros2(
        tmp_path / "two.mcap",
        t[:n],
        np.zeros((n, 3)),
        rec.pt100_t[:60],
        rec.pt100_c[:60],
        1.7e9,
        second_temperature="/board/temperature",
    )
    # two Temperature topics: the bag does not say which one is the IMU's
    with pytest.raises(InputError, match="several sensor_msgs/msg/Temperature topics"):
        read_log(p)
    r = read_log(p, temperature_topic="/board/temperature")
    assert r.run["temperature_topic"] == "/board/temperature"
    np.testing.assert_allclose(r.pt100_c, rec.pt100_c[:60] + 10.0)
    out = tmp_path / "rep"
    assert main(["report", str(p), "--out", str(out)]) == 2
    assert main(["report", str(p), "--temperature-topic", "/nope", "--out", str(out)]) == 2
    assert main(["report", str(logs["ulog"]), "--log-instance", "3", "--out", str(out)]) == 2
    assert not out.exists()


def test_report_allan_of_a_dataflash_log(logs: dict) -> None:
    from gyrolab.report.axes_report import build_axes_report

    doc, metrics = build_axes_report(logs["dataflash"], None, 3, lambda _s: None)
    assert set(metrics["axes"]) == {"x", "y", "z"}
    for a in "xyz":
        raw = metrics["axes"][a]["raw"]
        # the simulated ARW (0.0523 deg/sqrt(h)) read back through DataFlash
        assert raw["arw_deg_per_sqrt_h"] == pytest.approx(0.0523, rel=0.5)
    assert any(s.title.startswith("Axis z — Performance") for s in doc.sections)


def test_dataflash_fast_path_equals_pymavlink(logs: dict) -> None:
    """The numpy gather at pymavlink's index (gyrolab.logs.dataflash.imu_rows) against
    pymavlink's own message-by-message decoding of the same file."""
    from pymavlink import DFReader

    from gyrolab.logs.dataflash import COLUMNS, imu_rows

    log = DFReader.DFReader_binary(str(logs["dataflash"]), zero_time_base=True)
    fast = imu_rows(log, 0)
    slow = []
    while (m := log.recv_match(type="IMU")) is not None:
        slow.append([m.TimeUS * 1e-6] + [getattr(m, c) for c in COLUMNS[1:]])
    assert fast.shape == (len(slow), len(COLUMNS))
    np.testing.assert_array_equal(fast, np.asarray(slow))
    assert imu_rows(log, 1).shape == (0, len(COLUMNS))
