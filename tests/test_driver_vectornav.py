"""The ``vectornav`` driver: the VN-100's ASCII register commands and binary output packets
(UM001), checked as exact byte dialogues, and against the simulated VN-100 on a pty."""

from __future__ import annotations

import math
import struct
import time
from pathlib import Path

import numpy as np
import pytest

from gyrolab import vectornav as vn
from gyrolab.instruments import registry
from gyrolab.instruments.drivers.vectornav import VectorNavConfig, VectorNavStream
from gyrolab.instruments.roles import InstrumentError
from gyrolab.instruments.testing import expected_protocol

USER_COMP = "1,0,0,0,1,0,0,0,1,0.0012,-0.0008,0.0005"
OURS = "1,16,05,0001,001C"  # serial port 1, 800/16 = 50 Hz, this project's packet


def _sample(k: int, gyro=(0.01, -0.02, 0.03), temp=31.5) -> vn.Sample:
    return vn.Sample(k * 20_000_000, (0.0, 0.0, -9.81), gyro, temp)


def test_checksums_and_crc_are_the_manuals_examples() -> None:
    # UM001 §5.1: "$VNRRG,5*46" → "$VNRRG,5,9600*65"; "$VNWRG,5,9600*60"; §6.2.3's 84 reply
    assert vn.line("VNRRG,5") == b"$VNRRG,5*46\r\n"
    assert vn.parse_line(b"$VNRRG,5,9600*65") == ["VNRRG", "5", "9600"]
    assert vn.line("VNWRG,5,9600") == b"$VNWRG,5,9600*60\r\n"
    assert vn.parse_line(b"$VNRRG,84,1,0,0,0,1,0,0,0,1,0,0,0*7E") is not None
    assert vn.parse_line(b"$VNRRG,5,9600*66") is None  # one bit off
    # §4.3.7 example case 1: yaw, pitch, roll in group 1, CRC 0x9288
    pkt = bytes.fromhex("FA01080093502E42833EF13F48B504BB9288")
    assert vn.crc16(pkt[1:-2]) == 0x9288 and vn.crc16(pkt[1:]) == 0
    assert struct.unpack("<3f", pkt[4:16])[0] == pytest.approx(43.578686)
    # our packet: 6 header + 36 payload + 2 CRC; decodes to what was packed
    p = vn.packet(_sample(3))
    assert len(p) == vn.PACKET_LEN == 44 and vn.crc16(p[1:]) == 0
    (s,), lines = vn.Decoder().feed(p)
    assert s.time_ns == 60_000_000 and s.gyro_rad_s == pytest.approx((0.01, -0.02, 0.03))
    assert not lines


def test_decoder_resyncs_and_skips_what_is_not_ours() -> None:
    d = vn.Decoder()
    good = [vn.packet(_sample(k)) for k in range(4)]
    bad = bytearray(good[1])
    bad[20] ^= 0x40  # a flipped bit in the payload
    ymr = vn.line("VNYMR,+000.000,+000.000,+000.000,+0.0000,+0.0000,+0.0000,+0.1,-0.2,-9.8")
    other = bytes.fromhex("FA01080093502E42833EF13F48B504BB9288")  # the manual's YPR packet
    stream = b"\x00\x13" + good[0] + bytes(bad) + ymr + other + good[2] + b"$VNx" + good[3]
    samples, lines = [], []
    for i in range(0, len(stream), 7):  # in pieces, as a port delivers them
        s, ln = d.feed(stream[i : i + 7])
        samples += s
        lines += ln
    assert [s.time_ns // 20_000_000 for s in samples] == [0, 2, 3]
    assert d.stats.crc_errors == 1 and d.stats.other_packets == 1
    assert lines and lines[0][0] == "VNYMR"


def _connect_dialogue(comp: str = USER_COMP) -> list[tuple[bytes, bytes | None]]:
    L = vn.line
    return [
        (L("VNRRG,1"), L("VNRRG,01,VN-100T-CR")),
        (L("VNRRG,3"), L("VNRRG,03,0100012345")),
        (L("VNRRG,4"), L("VNRRG,04,2.1.0.0")),
        (L("VNRRG,26"), L("VNRRG,26,1,0,0,0,1,0,0,0,1")),
        (L("VNRRG,6"), L("VNRRG,06,14")),
        (L("VNWRG,6,0"), L("VNWRG,06,0")),
        (L("VNRRG,6"), L("VNRRG,06,0")),
        (L("VNRRG,84"), L(f"VNRRG,84,{comp}")),
        (L(f"VNWRG,84,{vn.GYRO_COMPENSATION_NONE}"), L(f"VNWRG,84,{vn.GYRO_COMPENSATION_NONE}")),
        (L("VNRRG,84"), L("VNRRG,84,1,0,0,0,1,0,0,0,1,0,0,0")),
        (L("VNRRG,75"), L("VNRRG,75,0,1,00")),
        (L(f"VNWRG,75,{OURS}"), L(f"VNWRG,75,{OURS}")),
    ]


def _restore_dialogue(comp: str = USER_COMP) -> list[tuple[bytes, bytes | None]]:
    L = vn.line
    return [
        (L("VNWRG,75,0,1,00"), L("VNWRG,75,0,1,00")),
        (L("VNRRG,75"), L("VNRRG,75,0,1,00")),
        (L(f"VNWRG,84,{comp}"), L(f"VNWRG,84,{comp}")),
        (L("VNRRG,84"), L(f"VNRRG,84,{comp}")),
        (L("VNWRG,6,14"), L("VNWRG,06,14")),
        (L("VNRRG,6"), L("VNRRG,06,14")),
    ]


def _open(port, **kw) -> VectorNavStream:
    s = VectorNavStream(port, config=VectorNavConfig(**kw), timeout_s=0.05)
    s.connect()
    return s


def test_connect_stream_and_close_as_a_byte_dialogue() -> None:
    # The read-back of the output register comes with the first packets (the unit streams
    # from the write on); packets 0, 1, 1 (repeated), 4 (2 and 3 lost), 5.
    pk = b"".join(
        vn.packet(_sample(k, gyro=(0.001 * k, 0.0, -0.5), temp=30 + k)) for k in (0, 1, 1, 4, 5)
    )
    dialogue = [
        *_connect_dialogue(),
        (vn.line("VNRRG,75"), vn.line(f"VNRRG,75,{OURS}") + pk),
        *_restore_dialogue(),
    ]
    with expected_protocol(_open, dialogue) as s:
        r = s.read(0.0)
        assert [(b.first_index, len(b.counts)) for b in r.blocks] == [(0, 2), (4, 2)]
        assert r.blocks[1].counts[0].tolist() == [40_000, 0, -5_000_000]  # 1e-7 rad/s
        assert s.config.to_dps(r.blocks[1].counts)[0, 2] == pytest.approx(-0.5 * 180 / math.pi)
        assert r.blocks[1].temperature_c.tolist() == [34.0, 35.0]
        assert s.counters() == {"frames_ok": 4, "frames_bad": 0, "frames_lost": 2, "repeated": 1}
        meta = s.describe()
        assert meta["model"] == "VN-100T-CR" and meta["serial"] == "0100012345"
        assert meta["registers_changed"]["84"] == [USER_COMP, vn.GYRO_COMPENSATION_NONE]
        s.close()


def test_a_refused_write_puts_back_what_was_written() -> None:
    L = vn.line
    dialogue = [
        *_connect_dialogue()[:7],
        (L("VNRRG,84"), L(f"VNRRG,84,{USER_COMP}")),
        (L(f"VNWRG,84,{vn.GYRO_COMPENSATION_NONE}"), L("VNERR,09")),  # unauthorized access
        (L("VNWRG,84,1,0,0,0,1,0,0,0,1,0.0012,-0.0008,0.0005"), L(f"VNWRG,84,{USER_COMP}")),
        (L("VNRRG,84"), L(f"VNRRG,84,{USER_COMP}")),
        (L("VNWRG,6,14"), L("VNWRG,06,14")),
        (L("VNRRG,6"), L("VNRRG,06,14")),
    ]
    why = r"register 84: error 9 \(unauthorized access\).*put back"
    with pytest.raises(InstrumentError, match=why), expected_protocol(_open, dialogue):
        pass


def test_config_is_checked() -> None:
    for bad in ({"sample_rate_hz": 30.0}, {"serial_port": 3}, {"output_register": 74}):
        with pytest.raises(ValueError):
            VectorNavConfig(**bad).check("hold")
    VectorNavConfig(sample_rate_hz=400.0).check("hold")
    spec = registry.get("vectornav", "rate_stream")
    assert spec.sim_backend == "VN100" and spec.config is VectorNavConfig


@pytest.fixture
def vn_bench(tmp_path: Path):
    from gyrolab.sim.bench import SimBench
    from gyrolab.sim.bench.vectornav import VnSpec
    from gyrolab.sim.fc_imus import imu_physics

    bench = SimBench(
        device=VnSpec(imu_physics(3, 50.0, imus=1), seed=3),
        samples_per_frame=1,
        tcp=False,
        workdir=tmp_path / "bench",
        tick_s=0.2,
        speed=20.0,
    ).start()
    yield bench
    bench.stop()


def test_against_the_simulated_unit_on_a_pty(vn_bench) -> None:
    sim = vn_bench.device
    before = dict(sim.reg)
    port = vn_bench.resources()["vn_port"]
    s = VectorNavStream(port, config=VectorNavConfig(sample_rate_hz=50.0), timeout_s=0.5)
    s.connect()
    try:
        assert sim.reg[6] == "0" and sim.reg[84] == vn.GYRO_COMPENSATION_NONE
        blocks = []
        deadline = time.monotonic() + 20.0
        while sum(len(b.counts) for b in blocks) < 400 and time.monotonic() < deadline:
            blocks += s.read(0.2).blocks
        counts = np.concatenate([b.counts for b in blocks])
        temps = np.concatenate([b.temperature_c for b in blocks])
        assert len(counts) >= 400 and s.counters()["frames_lost"] == 0
        # the IMU model's zero-rate offsets (1.5-2 °/s)
        rate = s.config.to_dps(counts).mean(axis=0)
        assert np.all((np.abs(rate) > 1.2) & (np.abs(rate) < 2.3)), rate
        assert 20.0 < temps.mean() < 40.0  # the die sensor near the chamber air at start
    finally:
        s.close()
    assert sim.reg == before  # the user's ASCII output, compensation and outputs back
    # ... and in use: VNYMR lines again after close (the bench's next tick; a loaded machine
    # may give it none between its start and the connect)
    deadline = time.monotonic() + 20.0
    while sim.stats.ascii_lines == 0 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert sim.stats.ascii_lines > 0


def test_a_unit_that_drops_a_write_is_left_as_it_was(tmp_path: Path) -> None:
    from gyrolab.sim.bench import SimBench
    from gyrolab.sim.bench.vectornav import VnSpec
    from gyrolab.sim.fc_imus import imu_physics

    spec = VnSpec(imu_physics(4, 50.0, imus=1), refuse_writes={75: None})
    bench = SimBench(device=spec, samples_per_frame=1, tcp=False, workdir=tmp_path, speed=20.0)
    with bench:
        before = dict(bench.device.reg)
        s = VectorNavStream(bench.device_port, config=VectorNavConfig(), timeout_s=0.2)
        with pytest.raises(InstrumentError, match="no reply.*previous values put back"):
            s.connect()
        s.ser.close()
        assert bench.device.reg == before


def test_acquire_with_the_simulated_vn100(tmp_path: Path) -> None:
    from gyrolab.cli import main
    from gyrolab.record.reader import read_recording

    prof = tmp_path / "p.toml"
    prof.write_text('name = "t"\n[[step]]\nsetpoint_c = 25\nduration_s = 60\n')
    out = tmp_path / "run.mcap"
    argv = ["acquire", "--bench", "sim", "--driver", "vectornav", "--profile", str(prof)]
    assert main([*argv, "--speed", "30", "--out", str(out)]) == 0
    rec = read_recording(out)
    assert rec.bench["adc"]["driver"] == "vectornav"
    assert rec.bench["adc"]["registers_changed"]["84"][1] == vn.GYRO_COMPENSATION_NONE
    rate = rec.require_rate().values
    assert rate.shape[1] == 3 and len(rate) > 40 * 50
    assert np.all(np.abs(rate.mean(axis=0)) > 1.2)
