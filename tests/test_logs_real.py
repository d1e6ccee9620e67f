"""Users' logs that real autopilots wrote (tests/data/README.md: pymavlink's tests/test.BIN,
pyulog's test/sample_log_small.ulg), read in the sensor frame, uncorrected: ArduPilot's
AHRS_ORIENTATION and gyro offsets undone from its PARM messages, the older IMU2 layout
read for --log-instance 1, PX4's sensor_gyro (before thermal compensation) with the TC
parameters the log stores; the active INS_TCAL correction undone on a log written with
the firmware's own arithmetic; damaged logs refused in one line."""

from __future__ import annotations

import csv
import hashlib
from pathlib import Path

import numpy as np
import pytest
from logwriters import write_dataflash

from gyrolab.autopilot import ardupilot as ap
from gyrolab.cli import main
from gyrolab.logs import read_log

DATA = Path(__file__).parent / "data"
BIN = DATA / "pymavlink_test.BIN"
ULG = DATA / "pyulog_sample_log_small.ulg"
SHA256 = {
    BIN: "a51f040b2ad7f55185c1da5705f226f51469b86562c4ff76d05c99e0e52c2bf4",
    ULG: "68d1020f688109f027dba08d2950247cc0ae34aaefdcf37e4a7d60838f3e1aa3",
}


def test_the_public_logs_are_the_published_bytes() -> None:
    for path, digest in SHA256.items():
        assert hashlib.sha256(path.read_bytes()).hexdigest() == digest, path.name


def _csv(path: Path) -> tuple[list[str], np.ndarray, list[str]]:
    comments = [ln for ln in path.read_text().splitlines() if ln.startswith("#")]
    rows = [r for r in csv.reader(ln for ln in path.read_text().splitlines() if ln[:1] != "#")]
    return rows[0], np.asarray(rows[1:], dtype=float), comments


def _logged(name: str) -> tuple[np.ndarray, dict[str, float]]:
    """pymavlink's own decoding of every ``name`` message (TimeUS, GyrX..Z, T) and the
    log's parameters."""
    from pymavlink import DFReader

    log = DFReader.DFReader_binary(str(BIN), zero_time_base=True)
    rows, params = [], {}
    while (m := log.recv_match(type=[name, "PARM"])) is not None:
        if m.get_type() == "PARM":
            params.setdefault(m.Name, m.Value)
        else:
            rows.append((m.TimeUS, m.GyrX, m.GyrY, m.GyrZ, m.T))
    return np.asarray(rows), params


@pytest.mark.parametrize(
    ("instance", "message", "offs"), [(0, "IMU", "INS_GYROFFS_"), (1, "IMU2", "INS_GYR2OFFS_")]
)
def test_dataflash_convert_is_the_sensor_frame(
    tmp_path: Path, instance: int, message: str, offs: str
) -> None:
    """test.BIN has AHRS_ORIENTATION = 8 (roll 180°): the body frame's Y and Z are the
    sensor's negated. convert undoes it and adds back the offsets ArduPilot subtracted."""
    out = tmp_path / f"imu{instance}.csv"
    assert main(["convert", str(BIN), "--to", "csv", "--out", str(out),
                 "--log-instance", str(instance)]) == 0  # fmt: skip
    names, table, comments = _csv(out)
    assert names == [
        "index", "t_s", "rate_x_dps", "rate_y_dps", "rate_z_dps",
        "accel_x_mps2", "accel_y_mps2", "accel_z_mps2", "internal_temperature_c",
    ]  # fmt: skip
    logged, p = _logged(message)
    assert p["AHRS_ORIENTATION"] == 8
    o = np.array([p[f"{offs}{a}"] for a in "XYZ"])
    sensor = logged[:, 1:4] * [1.0, -1.0, -1.0] + o  # roll 180° undone, offsets back
    assert table.shape[0] == logged.shape[0] == 45
    np.testing.assert_allclose(table[:, 2:5], np.degrees(sensor), rtol=0, atol=2e-5)
    # read in the body frame (as logged), Y and Z would be off by twice their size
    assert np.max(np.abs(table[:, 3:5] - np.degrees(logged[:, 2:4] + o[1:]))) > 0.1
    np.testing.assert_allclose(table[:, 8], logged[:, 4], atol=1e-5)  # the IMU's own T
    np.testing.assert_allclose(table[:, 1], (logged[:, 0] - logged[0, 0]) * 1e-6, atol=1e-9)
    meta = next(c for c in comments if c.startswith("# gyrolab_metadata"))
    assert '"AHRS_ORIENTATION": 8.0' in meta and f'"message": "{message}"' in meta


def test_dataflash_instance_that_is_not_there_is_one_line(tmp_path: Path, capsys) -> None:
    out = tmp_path / "x.csv"
    rc = main(["convert", str(BIN), "--to", "csv", "--out", str(out), "--log-instance", "2"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and not out.exists()
    assert err.count("\n") == 0 and "instances in the log: [0, 1]" in err


def _damaged(tmp_path: Path) -> dict[str, Path]:
    from pymavlink import DFReader

    d = BIN.read_bytes()
    log = DFReader.DFReader_binary(str(BIN))
    starts = sorted(o for offs in log.offsets for o in offs)
    a, b = (next(o for o in starts if o > x) for x in (12000, 30000))  # two message starts
    cases = {
        "inserted bytes": d[:20000] + b"garbage!" + d[20000:],
        "unknown message type": d[:b] + b"\xa3\x95\xfe" + d[b + 3 :],
        "overwritten header": d[:a] + b"\x00\x00\x00\x00" + d[a + 4 :],
    }
    out = {}
    for k, v in cases.items():
        p = tmp_path / (k.replace(" ", "_") + ".bin")
        p.write_bytes(v)
        out[k] = p
    u = ULG.read_bytes()
    p = tmp_path / "definitions.ulg"
    p.write_bytes(u[:100] + bytes(40) + u[140:])  # a ULog with its definitions damaged
    out["ulog definitions"] = p
    return out


def test_damaged_logs_are_one_line_exit_2_nothing_written(tmp_path: Path, capfd) -> None:
    for what, path in _damaged(tmp_path).items():
        out = tmp_path / f"{path.stem}.csv"
        rc = main(["convert", str(path), "--to", "csv", "--out", str(out)])
        cap = capfd.readouterr()
        err = cap.err.strip()
        assert rc == 2, what
        assert not out.exists(), what
        assert err.count("\n") == 0 and "damaged" in err and str(path) in err, (what, err)
        assert cap.out == "", what  # pymavlink's/pyulog's own chatter kept out


def test_a_log_cut_mid_message_reads_its_whole_messages(tmp_path: Path) -> None:
    """Logging stopped mid-write (power cut): the messages before the cut are read, the
    cut one is not."""
    p = tmp_path / "cut.bin"
    p.write_bytes(BIN.read_bytes()[:40007])
    rec = read_log(p)
    full = read_log(BIN)
    n = rec.rate.t.size
    assert 0 < n < full.rate.t.size
    np.testing.assert_array_equal(rec.rate.values, full.rate.values[:n])


def test_ulog_sensor_gyro_and_its_tc_parameters() -> None:
    """sensor_gyro is PX4's sensor frame before calibration and thermal compensation: read
    as logged (rad/s → °/s); the parameters that act on it downstream come with it."""
    from pyulog import ULog

    log = ULog(str(ULG), ["sensor_gyro"])
    for inst in (0, 1, 2):
        rec = read_log(ULG, instance=inst)
        d = next(x.data for x in log.data_list if x.multi_id == inst)
        g = np.column_stack([d["x"], d["y"], d["z"]]).astype(float)
        np.testing.assert_allclose(rec.rate.values, np.degrees(g), rtol=1e-12)
        np.testing.assert_allclose(rec.pt100_c, d["temperature"], rtol=1e-12)
        p = rec.run["parameters"]
        assert p["TC_G_ENABLE"] == 0 and p["SENS_BOARD_ROT"] == 4
        assert p[f"CAL_GYRO{inst}_ID"] == rec.run["device_id"] == int(d["device_id"][0])
        assert rec.accel is not None and rec.accel.values.shape == (6, 3)
        assert "before CAL_GYRO offsets and TC_G thermal compensation" in rec.run["frame"]


def test_ulog_convert_to_csv(tmp_path: Path) -> None:
    out = tmp_path / "u.csv"
    assert main(["convert", str(ULG), "--to", "csv", "--out", str(out), "--log-instance", "2"]) == 0
    names, table, _c = _csv(out)
    assert names[2:5] == ["rate_x_dps", "rate_y_dps", "rate_z_dps"] and table.shape == (6, 9)


def test_dataflash_active_tcal_orientation_and_a_change_mid_log(tmp_path: Path) -> None:
    """A log whose IMU values went through ArduPilot's own correction (the firmware's
    float32 arithmetic, gyrolab.autopilot.ardupilot.correct): INS_TCAL1 enabled, offsets,
    AHRS_ORIENTATION = 2 (yaw 90°), and the offsets and orientation changing half-way
    (logged as PARM then). The reader gets the sensor's own output back."""
    rng = np.random.default_rng(3)
    n = 400
    t_us = 5_000_000 + np.arange(n) * 10_000
    temp = np.linspace(10.0, 55.0, n)
    raw = np.column_stack([0.01 + 2e-4 * (temp - 30), -0.02 + 1e-6 * (temp - 20) ** 3,
                           0.004 * np.ones(n)]) + 1e-3 * rng.standard_normal((n, 3))  # fmt: skip
    p1 = {
        "INS_TCAL1_ENABLE": 1.0, "INS_TCAL1_TMIN": 15.0, "INS_TCAL1_TMAX": 50.0,
        **{f"INS_TCAL1_GYR{k}_{a}": float(v) for k, row in zip((1, 2, 3),
           [[180.0, -75.0, 5.0], [2.0, 3.0, -1.0], [0.05, -0.02, 0.01]], strict=True)
           for a, v in zip("XYZ", row, strict=True)},
        "INS_GYROFFS_X": 0.011, "INS_GYROFFS_Y": -0.019, "INS_GYROFFS_Z": 0.003,
        "INS_GYR1_CALTEMP": 31.5, "AHRS_ORIENTATION": 2.0,
    }  # fmt: skip
    p2 = {**p1, "INS_GYROFFS_X": 0.015, "AHRS_ORIENTATION": 4.0}
    half = n // 2
    body = np.vstack([ap.correct(raw[:half], temp[:half], p1, 0),
                      ap.correct(raw[half:], temp[half:], p2, 0)])  # fmt: skip
    params = [(int(t_us[0]) - 1000, k, v) for k, v in p1.items()]
    params += [(int(t_us[half]) - 5, k, v) for k, v in p2.items() if p1[k] != v]
    path = write_dataflash(tmp_path / "tcal.bin", t_us, body, temp, params=params)
    rec = read_log(path)
    np.testing.assert_allclose(np.radians(rec.rate.values), raw, atol=2e-7)
    assert rec.run["parameter_changes"] == 1
    # without the undo the log would be off by the correction: far more than the tolerance
    assert np.max(np.abs(body.astype(float) - raw)) > 1e-2
