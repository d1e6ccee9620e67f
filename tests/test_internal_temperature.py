"""A unit's internal temperature sensor as its temperature channel (docs/bench-config.md,
"Several units"; docs/instruments.md, "Internal temperature"): the frame's temperature word,
the simulated die sensor behind it, BENCH.toml's ``temperature = "internal"``, the recording
and reading it back."""

from __future__ import annotations

import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from simruns import run_on_sim, three_step_profile

from gyrolab.acquisition.bench_config import bench_from_dict, load_bench
from gyrolab.errors import InputError
from gyrolab.framing import FrameDecoder, crc16_ccitt, encode_frame, frame_size
from gyrolab.instruments.drivers.gyroadc import GyroAdcConfig, GyroAdcReader
from gyrolab.record.format import TOPIC_PT100, TOPIC_TEMPERATURE_INTERNAL
from gyrolab.record.reader import iter_messages, read_recording

# ------------------------------------------------------------------ the frame, byte by byte


def test_temperature_word_sits_before_the_crc_and_old_frames_are_unchanged() -> None:
    samples = np.array([1, -1])
    f = encode_frame(0x01020304, 0x1122334455, samples, temperature_code=4310)
    assert len(f) == frame_size(2, temperature=True) == 18 + 6 + 2
    assert f[:4] == b"\xa5\x5a\x14\x00"  # sync, L = 14 + 3·n·a = 20
    assert f[4:16] == bytes.fromhex("040302015544332211000000")  # seq, timestamp (LE)
    assert f[16:22] == b"\x01\x00\x00\xff\xff\xff"  # +1, -1 (24-bit LE)
    assert f[22:24] == b"\xd6\x10"  # 4310 = 0x10D6, int16 LE
    assert int.from_bytes(f[-2:], "big") == crc16_ccitt(f[2:-2])  # the CRC covers the word
    assert encode_frame(7, 0, samples, temperature_code=-6897)[22:24] == b"\x0f\xe5"  # 0xE50F
    # Without the option: the frame of before, byte for byte.
    plain = encode_frame(0x01020304, 0x1122334455, samples)
    assert len(plain) == frame_size(2) and plain[2:4] == b"\x12\x00"
    assert plain[:22] == f[:2] + b"\x12\x00" + f[4:22]
    with pytest.raises(ValueError, match="int16"):
        encode_frame(0, 0, samples, temperature_code=1 << 15)


def test_decoder_reads_the_word_and_refuses_the_other_layout() -> None:
    ts = np.arange(3) * 2000
    words = [4310, -6897, 18103]
    frames = b"".join(
        encode_frame(k, int(ts[k]), np.array([k, -k]), temperature_code=w)
        for k, w in enumerate(words)
    )
    got = FrameDecoder(2, 1000.0, temperature=True).feed(frames)
    assert got.seq.tolist() == [0, 1, 2] and got.temperature_code.tolist() == words
    assert got.counts.tolist() == [[0, 0], [1, -1], [2, -2]]
    plain = FrameDecoder(2, 1000.0)  # a decoder without the word: no frame passes
    assert len(plain.feed(frames)) == 0 and plain.stats.length_errors >= 3
    assert (
        FrameDecoder(2, 1000.0).feed(encode_frame(0, 0, np.array([1, 2]))).temperature_code is None
    )


def test_register_scale_is_the_data_sheets() -> None:
    # ADIS16135 data sheet, Table 13 (TEMP_OUT, two's complement, 0.0058 °C/LSB, 0 °C = 0):
    # +105 °C = +18 103 (0x46B7), −40 °C = −6897 (0xE50F), 0 °C = 0.
    c = GyroAdcConfig()
    assert c.to_celsius(np.array([18103, 0, -6897])) == pytest.approx([105.0, 0.0, -40.0], abs=3e-3)
    with pytest.raises(ValueError, match="temperature_c_per_lsb"):
        replace(c, temperature_c_per_lsb=0.0).check("setpoint")


# ------------------------------------------------------------------ the simulated die sensor


def test_simulated_unit_streams_its_die_temperature_on_its_pty() -> None:
    from gyrolab.sim.bench import SimBench

    bench = SimBench(speed=50.0, tcp=False, unit_internal_temperature=[True])
    reader = GyroAdcReader(
        bench.adc_port, samples_per_frame=10, rate_hz=100.0, temperature=(0.0, 0.0058)
    )
    blocks = []
    with bench:
        reader.open()
        deadline = time.monotonic() + 20.0
        while bench.clock.now() < 20.0 and time.monotonic() < deadline:
            blocks += reader.read(0.05).blocks
    reader.close()
    temps = np.concatenate([b.temperature_c for b in blocks])
    assert all(
        b.samples_per_reading == 10 and len(b.temperature_c) * 10 == b.counts.size for b in blocks
    )
    assert temps.size >= 100  # one reading per frame: 10 Hz
    p = bench.physics
    # the die at room temperature, seen through the unit's own offset, noise and 0.0058 °C LSB
    assert np.mean(temps) - p.die_sensor_offset_c == pytest.approx(25.0, abs=0.05)
    assert 0.005 < np.std(temps) < 0.05 and p.die_sensor_offset_c != 0.0
    assert np.allclose(np.round(temps / 0.0058), temps / 0.0058, atol=1e-6)  # quantised


# ------------------------------------------------------------------ BENCH.toml

MIXED = {
    "chamber": {"port": "/dev/ttyUSB1"},
    "scanner": {"resource": "TCPIP::10.0.0.9::5025::SOCKET"},
    "unit": [
        {"serial": "G-1", "port": "/dev/ttyUSB3", "temperature": "internal"},
        {"serial": "G-2", "port": "/dev/ttyUSB4", "temperature_channel": 102},
    ],
}


def test_units_may_mix_internal_sensors_and_pt100s() -> None:
    cfg = bench_from_dict(MIXED, "b.toml")
    a, b = cfg.units
    assert (a.temperature, a.temperature_channel, a.rate_stream.internal_temperature) == (
        "internal",
        None,
        True,
    )
    assert (b.temperature, b.temperature_channel, b.rate_stream.internal_temperature) == (
        "pt100",
        102,
        False,
    )
    assert cfg.scanner.channels == (102,)  # the scanner reads the PT100s only
    again = bench_from_dict(cfg.to_dict(), "again")
    assert again.units == cfg.units and again.scanner == cfg.scanner


def test_every_unit_internal_needs_no_scanner(tmp_path: Path) -> None:
    f = tmp_path / "b.toml"
    f.write_text(
        '[chamber]\nport = "/dev/ttyUSB1"\n'
        '[[unit]]\nserial = "G-1"\nport = "/dev/ttyUSB3"\ntemperature = "internal"\n'
        '[[unit]]\nserial = "G-2"\nport = "/dev/ttyUSB4"\ntemperature = "internal"\n'
        "rate_stream = { temperature_c_per_lsb = 0.0106 }\n"
    )
    cfg = load_bench(f)
    assert cfg.scanner is None and all(u.internal for u in cfg.units)
    assert cfg.units[1].rate_stream.temperature_c_per_lsb == 0.0106
    assert bench_from_dict(cfg.to_dict(), "again").units == cfg.units


@pytest.mark.parametrize(
    ("unit", "scanner", "match"),
    [
        (
            {"temperature": "internal", "temperature_channel": 101},
            True,
            r'b.toml: \[\[unit\]\] G-1: temperature = "internal" and temperature_channel = 101',
        ),
        ({"temperature": "die"}, True, r"b.toml: \[\[unit\]\] G-1: temperature = 'die'"),
        ({}, True, r"b.toml: \[\[unit\]\] G-1: temperature_channel = None"),
        ({"temperature": "internal"}, True, r"b.toml: \[scanner\]: every \[\[unit\]\] has"),
        ({"temperature_channel": 101}, False, r"b.toml: \[\[unit\]\] needs \[scanner\]"),
        (
            {"temperature": "internal", "rate_stream": {"temperature_c_per_lsb": -1.0}},
            False,
            r"b.toml: \[\[unit\]\] G-1 rate_stream gyroadc: temperature_c_per_lsb",
        ),
    ],
)
def test_bad_temperature_keys_are_one_line_naming_file_and_key(
    unit: dict, scanner: bool, match: str
) -> None:
    d = {"chamber": {"port": "/dev/ttyUSB1"}, "unit": [{"serial": "G-1", **unit}]}
    if scanner:
        d["scanner"] = {"resource": "TCPIP::h::5025::SOCKET"}
    with pytest.raises(InputError, match=match) as e:
        bench_from_dict(d, "b.toml")
    assert "\n" not in str(e.value)


# ------------------------------------------------------------------ acquire, end to end

PROFILE = three_step_profile("internal")


@pytest.fixture(scope="module")
def mixed_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """3 units: unit 1 on its internal sensor, units 2-3 on the scanner's PT100s (960 s
    simulated at 100x: about 10 s of wall time)."""
    from gyrolab.cli import main

    d = tmp_path_factory.mktemp("internal")
    (d / "p.toml").write_text(PROFILE)
    out = d / "mixed.mcap"
    args = ["acquire", "--bench", "sim", "--units", "3", "--internal-temperature", "1"]
    args += ["--speed", "100", "--profile", str(d / "p.toml"), "--out", str(out)]
    assert main(args) == 0
    return out


def test_every_units_temperature_is_recorded_and_read_back(mixed_run: Path) -> None:
    recs = {s: read_recording(mixed_run, unit=s) for s in ("SIM0-01", "SIM0-02", "SIM0-03")}
    one = recs["SIM0-01"]
    assert one.temperature_source == "internal" and np.isnan(one.pt100_ohm).all()
    # averaged per recorded block (1 s here) over the 960 s run, following the die
    assert one.pt100_t.size >= 900 and np.ptp(one.pt100_c) > 2.0
    units = one.bench["units"]
    assert units["SIM0-01"]["temperature_source"] == "internal"
    assert "temperature_channel" not in units["SIM0-01"]
    assert units["SIM0-01"]["adc"]["internal_temperature"] is True
    assert one.bench["scanner"]["channels"] == [102, 103]
    for s in ("SIM0-02", "SIM0-03"):
        rec = recs[s]
        assert rec.temperature_source == "pt100" and rec.pt100_t.size >= 400
        assert (
            units[s]["temperature_source"] == "pt100"
            and "internal_temperature" not in units[s]["adc"]
        )
        assert rec.require_rate().gaps() == []
    # the die lags the case, so the internal sensor and a PT100 differ most while moving
    assert abs(np.median(one.pt100_c) - np.median(recs["SIM0-02"].pt100_c)) < 5.0
    topics = {
        t
        for t, _ts, _d in iter_messages(
            mixed_run, [TOPIC_PT100, TOPIC_TEMPERATURE_INTERNAL], unit="SIM0-01"
        )
    }
    assert topics == {TOPIC_TEMPERATURE_INTERNAL}  # its own topic, no PT100


@pytest.fixture(scope="module")
def internal_model(mixed_run: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A model fitted on unit 1's internal sensor (the pipeline cut to a few seconds)."""
    from test_pipeline import SMALL

    from gyrolab.cli import main

    fast = replace(SMALL, causal_families=("poly",), ga_generations=2, bp_max_iter=50)
    out = tmp_path_factory.mktemp("model") / "m"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr("gyrolab.compensation.commands.DEFAULT_CONFIG", fast)
        assert main(["compensate", str(mixed_run), "--unit", "SIM0-01", "--out", str(out)]) == 0
    return out


def test_compensate_uses_the_internal_sensor_as_model_input(internal_model: Path) -> None:
    cal = json.loads((internal_model / "model.json").read_text())["calibration"]
    assert cal["unit"] == "SIM0-01" and cal["temperature_source"] == "internal"
    t = json.loads((internal_model / "metrics.json").read_text())["temperature"]
    # its own calibration run: the same source, no flag
    assert t["temperature_source"] == "internal" and t["temperature_source_mismatch"] is False


def test_the_report_flags_a_model_on_another_temperature_source(
    mixed_run: Path, internal_model: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from gyrolab.cli import main
    from gyrolab.compensation.guards import range_check
    from gyrolab.compensation.model_dir import load_model
    from gyrolab.compensation.prepare import prepare_file

    model = load_model(str(internal_model))
    pt100_run = prepare_file(mixed_run, model.config, unit="SIM0-02")
    assert range_check(model.calibration, pt100_run)["temperature_source_mismatch"] is True
    # a model written before the key existed was fitted on a PT100
    old = {k: v for k, v in model.calibration.items() if k != "temperature_source"}
    assert range_check(old, pt100_run)["temperature_source_mismatch"] is False
    # the report applies it, says so on stderr and in its text, and records the flag
    out = tmp_path / "r"
    args = ["report", str(mixed_run), "--unit", "SIM0-02", "--model", str(internal_model)]
    assert main([*args, "--out", str(out)]) == 0
    assert "fitted on the internal (die) sensor temperature" in capsys.readouterr().err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["temperature"]["temperature_source_mismatch"] is True
    assert "Another temperature source" in (out / "index.html").read_text()


def test_discrepancy_analyses_a_unit_on_its_die_temperature(
    mixed_run: Path, tmp_path: Path
) -> None:
    """The die model (its lag behind the case and its offset, docs/discrepancy.md): the
    unit on its internal sensor is analysed, with no PT100 candidate."""
    from gyrolab.cli import main

    out = tmp_path / "d"
    assert main(["discrepancy", str(mixed_run), "--unit", "SIM0-01", "--out", str(out)]) == 0
    doc = json.loads((out / "discrepancy.json").read_text())
    assert doc["temperature_source"] == "die"
    assert "rtd_self_heating" not in doc["detection_limits"]
    assert "die_tau_s" in (out / "model.toml").read_text()


def test_convert_names_the_internal_temperature_column(mixed_run: Path, tmp_path: Path) -> None:
    import csv

    from gyrolab.convert import convert_recording

    with pytest.raises(InputError, match="choose one with --unit"):
        convert_recording(mixed_run, "csv", tmp_path / "all.csv")
    recs = {}
    for s in ("SIM0-01", "SIM0-02"):
        convert_recording(mixed_run, "csv", tmp_path / f"{s}.csv", unit=s)
        with open(tmp_path / f"{s}.csv", encoding="utf-8") as fh:
            head = [ln for ln in fh if ln.startswith("# gyrolab_unit")]
            fh.seek(0)
            rows = list(csv.DictReader(ln for ln in fh if not ln.startswith("#")))
        assert head == [f"# gyrolab_unit: {s}\n"]
        recs[s] = (rows, read_recording(mixed_run, unit=s))
    rows, rec = recs["SIM0-01"]
    assert "internal_temperature_c" in rows[0] and "pt100_c" not in rows[0]
    # held: the last internal reading at or before each sample
    t = np.array([float(r["t_s"]) for r in rows])
    got = np.array([float(r["internal_temperature_c"]) for r in rows])
    k = np.searchsorted(rec.pt100_t, t, side="right") - 1
    assert np.array_equal(got[k >= 0], rec.pt100_c[k[k >= 0]]) and np.isnan(got[k < 0]).all()
    rows, rec = recs["SIM0-02"]
    assert "pt100_c" in rows[0] and "internal_temperature_c" not in rows[0]
    assert rows[0]["rate_dps"] and len(rows) == rec.require_rate().t.size


def test_convert_hdf5_keeps_the_internal_readings_table(mixed_run: Path, tmp_path: Path) -> None:
    h5py = pytest.importorskip("h5py")
    from gyrolab.convert import convert_recording

    convert_recording(mixed_run, "hdf5", tmp_path / "u.h5", unit="SIM0-01")
    rec = read_recording(mixed_run, unit="SIM0-01")
    with h5py.File(tmp_path / "u.h5", "r") as f:
        assert "pt100" not in f and "pt100_c" not in f["samples"]
        g = f["internal_temperature"]
        assert np.array_equal(g["temperature_c"][:], rec.pt100_c)
        assert (g["readings"][:] >= 1).all()
        assert f["samples/internal_temperature_c"].attrs["units"] == "degC"


def test_every_unit_internal_runs_without_a_scanner(tmp_path: Path) -> None:
    from gyrolab.app.acquire import sim_bench_config, start_sim_bench
    from gyrolab.profiles.profile import load_profile

    (tmp_path / "p.toml").write_text(PROFILE.replace("320", "40"))
    prof = load_profile(tmp_path / "p.toml")
    cfg = sim_bench_config(0, 2, internal=(1, 2))
    assert cfg.scanner is None
    sim, cfg = start_sim_bench(cfg, prof, seed=0, speed=40.0)
    out = tmp_path / "run.mcap"
    res = run_on_sim(cfg, prof, out, sim)
    assert res.outcome == "completed" and res.units_dropped == []
    for s in ("SIM0-01", "SIM0-02"):
        rec = read_recording(out, unit=s)
        assert rec.temperature_source == "internal" and rec.pt100_t.size >= 100  # per block
        assert "scanner" not in rec.bench
    events = [e["event"] for e in rec.events]
    assert events.count("step_started") == 3 and events[-2:] == ["run_ended", "safe_state"]
