"""The simulated bench's parts: clock, pty plumbing, SCPI responder, Modbus slave, faults,
and the SimBench wiring (physics, stall, as-fast-as-possible mode)."""

from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest
import serial

from gyrolab.instruments.drivers.gyroadc import GyroAdcReader
from gyrolab.sim.bench import ByteFaults, FaultEvent, ModbusFaults, SimBench, SimClock
from gyrolab.sim.bench.dmm_scpi import OVERLOAD, Scpi34401A
from gyrolab.sim.bench.oven_modbus import OvenHooks, WatlowF4Slave, request_length, with_crc
from gyrolab.sim.bench.serial_pty import PortClosed, PtyPort

# ------------------------------------------------------------------------- clock


def test_clock_paced_runs_at_speed() -> None:
    clock = SimClock(speed=50.0)
    t0 = time.monotonic()
    for k in range(1, 11):
        assert clock.advance_to(k * 0.5)  # 5 s simulated
    wall = time.monotonic() - t0
    assert clock.now() == 5.0
    assert 0.09 < wall < 0.6  # 5 s / 50 = 0.1 s (upper bound generous for a loaded box)


def test_clock_sleep_waits_for_the_master_and_stop_wakes_it() -> None:
    clock = SimClock(speed=None)
    woke: list[bool] = []
    t = threading.Thread(target=lambda: woke.append(clock.sleep(2.0, timeout_wall_s=5.0)))
    t.start()
    time.sleep(0.05)
    clock.advance_to(1.0)
    time.sleep(0.05)
    assert not woke  # 1 s is not enough
    clock.advance_to(2.5)
    t.join(2.0)
    assert woke == [True]
    t2 = threading.Thread(target=lambda: woke.append(clock.sleep(100.0)))
    t2.start()
    clock.stop()
    t2.join(2.0)
    assert woke == [True, False]
    assert not clock.advance_to(10.0)


# ------------------------------------------------------------------------- pty


def test_pty_link_survives_unplug_and_replug(tmp_path: os.PathLike[str]) -> None:
    port = PtyPort(os.path.join(tmp_path, "ttyUSB0"))
    port.connect()
    s = serial.Serial(port.path, timeout=0.5)
    s.write(b"ping\r\n")  # raw mode: no CR/LF translation, no echo
    assert port.read(0.5) == b"ping\r\n"
    port.write(b"\x00\x11\x13\x03\xff")  # NUL, XON, XOFF, ^C pass untouched
    assert s.read(5) == b"\x00\x11\x13\x03\xff"
    port.disconnect()
    assert not os.path.exists(port.path)
    with pytest.raises(serial.SerialException):
        s.read(1)
    with pytest.raises(PortClosed):
        port.write(b"x")
    s.close()
    port.connect()
    s = serial.Serial(port.path, timeout=0.5)
    port.write(b"back")
    assert s.read(4) == b"back"
    assert port.generation == 2
    s.close()
    port.disconnect()


# ------------------------------------------------------------------------- SCPI


def _meter(ohm: float = 109.735) -> Scpi34401A:
    return Scpi34401A(lambda: ohm, clock=None)


def test_scpi_short_long_and_optional_forms() -> None:
    m = _meter()
    assert m.handle("*IDN?").startswith("HEWLETT-PACKARD,34401A")
    assert m.handle("CONFigure:FRESistance 1000") is None
    assert m.handle(":SENSe:FRESistance:NPLCycles 1") is None
    assert m.handle("fres:nplc?") == "+1.00000000E+00"
    assert m.handle("FRES:RANG?") == "+1.00000000E+03"
    assert m.handle("READ?") == "+1.09735000E+02"
    assert m.handle("SYSTem:ERRor:NEXT?") == '+0,"No error"'
    assert m.handle("*RST;FUNC?") == '"VOLT"'


def test_scpi_error_queue_codes_and_overflow() -> None:
    m = _meter()
    m.handle("BOGUS:CMD")
    m.handle("FRES:NPLC 7")
    m.handle("CONF:FRES 1e9")
    assert m.handle("SYST:ERR?") == '-113,"Undefined header"'
    assert m.handle("SYST:ERR?") == '-224,"Illegal parameter value"'
    assert m.handle("SYST:ERR?") == '-222,"Data out of range"'
    assert m.handle("SYST:ERR?") == '+0,"No error"'
    for _ in range(25):
        m.handle("NOPE")
    errs = [m.handle("SYST:ERR?") for _ in range(21)]
    assert errs[18] == '-113,"Undefined header"' and errs[19] == '-350,"Too many errors"'
    assert errs[20] == '+0,"No error"'


def test_scpi_range_overload_above_120_percent() -> None:
    m = _meter(123.24)  # PT100 at 60 °C
    m.handle("CONF:FRES 100")
    assert m.handle("READ?") == OVERLOAD
    m.handle("CONF:FRES 1000")
    assert m.handle("READ?") == "+1.23240000E+02"


def test_scpi_reading_takes_integration_time_in_simulated_time() -> None:
    clock = SimClock(speed=None)
    m = Scpi34401A(lambda: 100.0, clock)
    m.handle("CONF:FRES 1000;FRES:NPLC 10")
    out: list[str | None] = []
    t = threading.Thread(target=lambda: out.append(m.handle("READ?")))
    t.start()
    time.sleep(0.05)
    assert not out  # waiting for 2 × 10 / 50 Hz = 0.4 s of simulated time
    clock.advance_to(0.5)
    t.join(2.0)
    assert out == ["+1.00000000E+02"]


# ------------------------------------------------------------------------- Modbus


class _Oven:
    def __init__(self) -> None:
        self.sp = 25.0

    def hooks(self) -> OvenHooks:
        return OvenHooks(lambda: 20.0, lambda: self.sp, self._set)

    def _set(self, v: float) -> None:
        self.sp = v


def test_modbus_slave_registers_and_exceptions() -> None:
    oven = _Oven()
    slave = WatlowF4Slave(oven.hooks(), decimals=1)
    assert slave.process(with_crc(bytes.fromhex("01 03 00 64 00 01"))) == with_crc(
        bytes.fromhex("01 03 02 00 c8")
    )  # PV 20.0 °C
    # 200 is the profile mode (0: constant, no profile); 103 the heat power in 0.01 %:
    # setpoint 25 > air 20 → full heat (10000), 107 cool power 0 (docs/instruments.md)
    assert slave.process(with_crc(bytes.fromhex("01 03 00 c8 00 01")))[3:5] == b"\x00\x00"
    assert slave.process(with_crc(bytes.fromhex("01 03 00 67 00 01")))[3:5] == b"\x27\x10"
    assert slave.process(with_crc(bytes.fromhex("01 03 00 6b 00 01")))[3:5] == b"\x00\x00"
    # event output 2 (register 2010 = 0x07da): written, read back; 2 is not a state
    ev = with_crc(bytes.fromhex("01 06 07 da 00 01"))
    assert slave.process(ev) == ev and slave.events[1] == 1
    assert slave.process(with_crc(bytes.fromhex("01 06 07 da 00 02")))[1:3] == b"\x86\x03"
    # write 300 = -12.5 °C
    req = with_crc(bytes.fromhex("01 06 01 2c ff 83"))
    assert slave.process(req) == req and oven.sp == -12.5
    # write PV (read only) → illegal data value; unknown register → illegal address
    assert slave.process(with_crc(bytes.fromhex("01 06 00 64 00 00")))[1:3] == b"\x86\x03"
    assert slave.process(with_crc(bytes.fromhex("01 03 00 01 00 01")))[1:3] == b"\x83\x02"
    # beyond the controller's own range → illegal data value, setpoint unchanged
    assert slave.process(with_crc(bytes.fromhex("01 06 01 2c 09 c4")))[1:3] == b"\x86\x03"
    assert oven.sp == -12.5
    # bad CRC or another slave address → silence, as on a real RS-485 line
    assert slave.process(bytes.fromhex("01 03 00 64 00 01 00 00")) is None
    assert slave.process(with_crc(bytes.fromhex("02 03 00 64 00 01"))) is None
    assert request_length(b"\x01\x10\x01\x2c\x00\x02\x04") == 13


def test_modbus_faults_random_and_burst() -> None:
    f = ModbusFaults(exception_prob=0.1, crc_error_prob=0.1, no_reply_prob=0.1, seed=3)
    draws = [f.draw() for _ in range(3000)]
    for kind in ("modbus_exception", "modbus_crc", "modbus_no_reply"):
        assert 0.08 < draws.count(kind) / 3000 < 0.12
    f.burst("modbus_crc", 3)
    assert [f.draw() for _ in range(3)] == ["modbus_crc"] * 3
    oven = _Oven()
    slave = WatlowF4Slave(oven.hooks(), faults=ModbusFaults())
    slave.faults.burst("modbus_crc", 1)
    bad = slave.process(with_crc(bytes.fromhex("01 03 00 64 00 01")))
    assert bad is not None and with_crc(bad[:-2]) != bad


def test_byte_faults_rates_and_reproducibility() -> None:
    data = bytes(range(256)) * 400
    a = ByteFaults(corrupt_prob=0.01, drop_prob=0.001, seed=5)
    b = ByteFaults(corrupt_prob=0.01, drop_prob=0.001, seed=5)
    wa, da = a.apply(data)
    wb, _ = b.apply(data)
    assert wa == wb and da
    assert len(data) - len(wa) == a.bytes_dropped
    assert 0.008 < a.bytes_corrupted / len(data) < 0.012
    assert 0.0006 < a.bytes_dropped / len(data) < 0.0014
    with pytest.raises(ValueError):
        FaultEvent("meltdown")


# ------------------------------------------------------------------------- SimBench


def test_bench_clock_and_physics_stay_in_step() -> None:
    with SimBench(speed=100.0, rate_hz=100.0, tcp=False) as bench:
        bench.clock.wait_until(5.0, timeout_wall_s=5.0)
        with bench.lock:
            assert bench.physics.t == pytest.approx(bench.clock.now(), abs=0.11)
        assert bench.resources()["rate_hz"] == 100.0
        assert os.path.islink(bench.adc_port)
    assert not os.path.exists(bench.workdir)  # cleaned up


def test_bench_stall_delivers_the_backlog_late_without_loss() -> None:
    bench = SimBench(speed=20.0, rate_hz=1000.0, keep_truth=True, tcp=False)
    bench.inject(FaultEvent("stall", t_s=1.0, duration_s=1.0))
    reader = GyroAdcReader(bench.adc_port, samples_per_frame=10, rate_hz=1000.0)
    quiet = 0.0
    with bench:
        reader.open()
        seqs: list[int] = []
        last = time.monotonic()
        while bench.clock.now() < 3.0:
            r = reader.read(0.02)
            now = time.monotonic()
            if r.blocks:
                quiet = max(quiet, now - last)
                last = now
            for b in r.blocks:
                seqs += list(range(b.first_seq, b.first_seq + b.counts.size // 10))
    reader.close()
    assert quiet > 0.03  # 1 s simulated at 20× ≈ 50 ms without a byte
    assert np.array_equal(seqs, np.arange(seqs[0], seqs[-1] + 1))  # nothing lost
    assert reader.decoder.stats.gaps == 0


def test_bench_as_fast_as_possible_is_throttled_by_the_reader() -> None:
    with SimBench(speed=None, rate_hz=1000.0, tcp=False) as bench:
        reader = GyroAdcReader(bench.adc_port, samples_per_frame=10, rate_hz=1000.0)
        reader.open()
        t0 = time.monotonic()
        n = 0
        while time.monotonic() - t0 < 1.0:
            n += reader.read(0.02).samples
        reader.close()
        sim_s = bench.clock.now()
    assert sim_s > 2.0  # faster than real time (typically 20-50x here; loaded box)
    assert n > 0.5 * sim_s * 1000  # and the reader saw most of it (it opened late)
