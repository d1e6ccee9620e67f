"""Watlow F4 driver: the Modbus RTU bytes (PyMeasure-style expected request → reply
lists), limits checked before any I/O, read-back, retries, and end to end over a pty."""

from __future__ import annotations

import os
import threading
import time

import minimalmodbus
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gyrolab.instruments.drivers import watlowf4
from gyrolab.instruments.drivers.watlowf4 import WatlowF4
from gyrolab.instruments.roles import InstrumentError, InstrumentTimeout, LimitError
from gyrolab.instruments.testing import ExpectedSerial
from gyrolab.sim.bench import FaultEvent, SimBench
from gyrolab.sim.bench.oven_modbus import OvenHooks, WatlowF4Slave, crc16_modbus, with_crc
from gyrolab.sim.bench.serial_pty import PtyPort

H = bytes.fromhex
# Requests (slave 1) and replies, CRC included, written out byte by byte.
READ_DP = H("01 03 02 5e 00 01 e4 60")
DP_1 = H("01 03 02 00 01 79 84")
READ_UNITS = H("01 03 03 85 00 01 95 a7")
UNITS_C = DP_1  # register value 1 = °C
READ_SP = H("01 03 01 2c 00 01 44 3f")
WRITE_SP_M40 = H("01 06 01 2c fe 70 08 7b")  # setpoint -40.0 °C = raw -400
SP_M40 = H("01 03 02 fe 70 f9 c0")
READ_PV = H("01 03 00 64 00 01 c5 d5")
PV_25_3 = H("01 03 02 00 fd 79 c5")  # 25.3 °C = raw 253
BUSY = H("01 86 06 c2 62")  # exception 06, slave device busy


def test_crc_matches_minimalmodbus() -> None:
    frame = H("01 03 00 64 00 01")
    assert with_crc(frame) == READ_PV
    assert crc16_modbus(frame).to_bytes(2, "little") == minimalmodbus._calculate_crc(frame)


def test_set_setpoint_bytes_and_readback() -> None:
    fake = ExpectedSerial(
        [
            (READ_DP, DP_1),
            (READ_UNITS, UNITS_C),
            (WRITE_SP_M40, WRITE_SP_M40),  # function 06 echoes the request
            (READ_SP, SP_M40),
        ]
    )
    oven = WatlowF4(fake)
    assert oven.set_setpoint(-40.0) == -40.0
    fake.assert_done()


def test_process_value_signed_with_implied_decimals() -> None:
    fake = ExpectedSerial([(READ_PV, PV_25_3), (READ_DP, DP_1), (READ_UNITS, UNITS_C)])
    assert WatlowF4(fake).process_value_c == pytest.approx(25.3)
    fake.assert_done()


def test_fahrenheit_controller_is_converted() -> None:
    f_units = with_crc(H("01 03 02 00 00"))  # 0 = °F
    raw_104f = with_crc(H("01 03 02 04 10"))  # 104.0 °F = 40.0 °C
    fake = ExpectedSerial(
        [
            (READ_DP, DP_1),
            (READ_UNITS, f_units),
            (with_crc(H("01 06 01 2c 04 10")), with_crc(H("01 06 01 2c 04 10"))),
            (READ_SP, raw_104f),
        ]
    )
    assert WatlowF4(fake).set_setpoint(40.0) == pytest.approx(40.0)
    fake.assert_done()


@pytest.mark.parametrize("bad", [80.0, -60.0, float("nan"), float("inf")])
def test_out_of_limit_setpoint_refused_before_any_byte(bad: float) -> None:
    fake = ExpectedSerial([])  # any write fails the test
    oven = WatlowF4(fake, setpoint_limits_c=(-45.0, 70.0))
    with pytest.raises(LimitError):
        oven.set_setpoint(bad)
    assert fake.written == []


def test_out_of_limit_setpoint_puts_nothing_on_a_real_port() -> None:
    port = PtyPort()
    port.connect()
    try:
        oven = WatlowF4(port.path, setpoint_limits_c=(-45.0, 70.0))
        with pytest.raises(LimitError):
            oven.setpoint_c = 100.0
        oven.close()
        assert port.read(0.2) == b""  # not one byte reached the far end of the wire
    finally:
        port.disconnect()


def test_readback_mismatch_raises() -> None:
    fake = ExpectedSerial(
        [
            (READ_DP, DP_1),
            (READ_UNITS, UNITS_C),
            (WRITE_SP_M40, WRITE_SP_M40),
            (READ_SP, PV_25_3),  # the controller kept another value
        ]
    )
    with pytest.raises(InstrumentError, match="read-back 253 != written -400"):
        WatlowF4(fake).set_setpoint(-40.0)


def test_exception_response_retried_then_succeeds() -> None:
    fake = ExpectedSerial([(READ_PV, BUSY), (READ_PV, PV_25_3)])
    oven = WatlowF4(fake, retries=2)
    assert oven.read_register(100) == 253
    assert oven.stats.exceptions == 1 and oven.stats.retries == 1


def test_crc_error_and_silence_exhaust_retries() -> None:
    bad_crc = PV_25_3[:-1] + bytes([PV_25_3[-1] ^ 0xFF])
    fake = ExpectedSerial([(READ_PV, bad_crc), (READ_PV, bad_crc), (READ_PV, bad_crc)])
    oven = WatlowF4(fake, retries=2)
    with pytest.raises(InstrumentError, match="failed after 3 tries"):
        oven.read_register(100)
    assert oven.stats.bad_reply == 3
    silent = ExpectedSerial([(READ_PV, None), (READ_PV, None)])
    with pytest.raises(InstrumentTimeout):
        WatlowF4(silent, retries=1).read_register(100)


# ------------------------------------------------------------------- end to end


def test_end_to_end_setpoint_moves_the_simulated_oven() -> None:
    with SimBench(speed=200.0) as bench:
        # Nobody reads the ADC here; an undrained pty would pace the bench at ~20x (each
        # tick waits on the full port), so unplug it for the test.
        bench.inject(FaultEvent("disconnect", duration_s=1e9))
        with WatlowF4(bench.oven_port) as oven:
            info = oven.connect()
            assert info["units"] == "C" and info["decimals"] == 1
            assert info["process_value_c"] == pytest.approx(25.0, abs=0.1)
            assert oven.set_setpoint(45.5) == 45.5
            assert bench.physics.setpoint_c == 45.5
            assert oven.status.heating
            t0 = bench.clock.now()
            # 0.6 s of wall at 200x; the limit guards a hang (load may slow the clock's ticks)
            assert bench.clock.wait_until(t0 + 120.0, timeout_wall_s=300.0)
            pv = oven.process_value_c
            with bench.lock:
                air = bench.physics.chamber_c()
            assert 25.5 < pv <= 46.0  # the chamber is heating toward the setpoint
            assert pv == pytest.approx(air, abs=0.5)  # PV is the simulated air (0.1 °C steps)


def test_end_to_end_modbus_fault_burst_is_retried() -> None:
    with SimBench(speed=50.0) as bench:
        with WatlowF4(bench.oven_port, retries=3, timeout_s=0.2) as oven:
            oven.connect()
            for kind in ("modbus_exception", "modbus_crc", "modbus_no_reply"):
                bench.inject(FaultEvent(kind, count=2))
                assert oven.process_value_c == pytest.approx(25.0, abs=0.2)
            assert oven.stats.exceptions == 2
            assert oven.stats.bad_reply == 2
            assert oven.stats.no_reply == 2
            bench.inject(FaultEvent("modbus_no_reply", count=10))
            with pytest.raises(InstrumentTimeout):
                _ = oven.process_value_c


def test_simulated_controller_rejects_its_own_out_of_range_setpoint() -> None:
    # The driver's limits are the lab's; the controller has its own (-73…190 °C) too.
    with SimBench(speed=50.0) as bench:
        with WatlowF4(bench.oven_port, setpoint_limits_c=(-100.0, 300.0), retries=0) as oven:
            with pytest.raises(InstrumentError, match="failed"):
                oven.set_setpoint(250.0)
            assert bench.physics.setpoint_c == 25.0


def test_pty_unplugged_port_raises_instrument_error(tmp_path: os.PathLike[str]) -> None:
    with pytest.raises(InstrumentError, match="cannot open"):
        WatlowF4(os.path.join(tmp_path, "ttyUSB9"))


@pytest.mark.hardware
@pytest.mark.skipif(not os.environ.get("GYROLAB_OVEN_PORT"), reason="set GYROLAB_OVEN_PORT")
def test_real_oven_reads_only() -> None:
    with WatlowF4(os.environ["GYROLAB_OVEN_PORT"]) as oven:
        info = oven.connect()
        assert -80.0 < info["process_value_c"] < 200.0


class LoopbackSerial(ExpectedSerial):
    """The driver's bytes go straight into a simulated controller (no pty, no thread)."""

    def __init__(self, slave: WatlowF4Slave) -> None:
        super().__init__([])
        self.slave = slave

    def write(self, data: bytes) -> int:
        self.written.append(bytes(data))
        self._rx += self.slave.process(bytes(data)) or b""
        return len(data)


@settings(max_examples=60, deadline=None)
@given(
    setpoint=st.floats(-45.0, 70.0, allow_nan=False),
    decimals=st.sampled_from([0, 1, 2]),
    units_c=st.booleans(),
)
def test_setpoint_roundtrip_any_scaling(setpoint: float, decimals: int, units_c: bool) -> None:
    state = {"sp": 25.0}
    slave = WatlowF4Slave(
        OvenHooks(lambda: 20.0, lambda: state["sp"], lambda v: state.update(sp=v)),
        decimals=decimals,
        units_c=units_c,
    )
    oven = WatlowF4(LoopbackSerial(slave))
    got = oven.set_setpoint(setpoint)
    # Quantized to the controller's resolution (in its own units), and nothing else.
    step_c = 10.0**-decimals * (1.0 if units_c else 5.0 / 9.0)
    assert abs(got - setpoint) <= step_c / 2 + 1e-9
    assert state["sp"] == pytest.approx(got, abs=1e-9)
    assert oven.process_value_c == pytest.approx(20.0, abs=step_c / 2 + 1e-9)
    assert slave.writes == [(300, slave._to_raw(got))]


# ------------------------------------------------------------------- late replies


class LateSlave:
    """A Watlow F4 slave on a real pty that answers the requests numbered in ``late``
    (0-based) ``delay_s`` after they arrive, i.e. after the master has given up; every
    other one ``turnaround_s`` after it arrives. ``split`` bytes of a late reply go out at
    once, the rest late (a reply straddling the timeout). One thread, like a real
    controller: a request that arrives while a late reply is pending is served after it."""

    def __init__(
        self, late: set[int], delay_s: float, turnaround_s: float = 0.0, split: int = 0
    ) -> None:
        self.slave = WatlowF4Slave(OvenHooks(lambda: 25.3, lambda: 25.0, lambda v: None))
        self.late, self.delay_s, self.turnaround_s = late, delay_s, turnaround_s
        self.split = split
        self.port = PtyPort()
        self.seen: list[int] = []  # register of every request, in order
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> LateSlave:
        self.port.connect()
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.port.disconnect()

    def _run(self) -> None:
        buf = b""
        while not self._stop.is_set():
            buf += self.port.read(0.01)
            while len(buf) >= 8:  # functions 03 and 06: 8-byte requests
                req, buf = buf[:8], buf[8:]
                k = len(self.seen)
                self.seen.append(int.from_bytes(req[2:4], "big"))
                reply = self.slave.process(req) or b""
                if k in self.late:
                    self.port.write(reply[: self.split])
                    reply = reply[self.split :]
                time.sleep(self.delay_s if k in self.late else self.turnaround_s)
                self.port.write(reply)


def test_late_reply_is_not_taken_as_the_next_registers_value() -> None:
    # The reply to "read 300" (raw 250) comes 50 ms after the 0.1 s timeout. Without the
    # wait for line silence the next request, "read 606", read back 250 (seen on a bench).
    # silence_s is generous so that a loaded test machine cannot push the late reply out
    # of the window the driver guards (timeout_s + silence_s after the request).
    with LateSlave(late={0}, delay_s=0.15) as sim:
        with WatlowF4(sim.port.path, timeout_s=0.1, retries=0, silence_s=0.3) as oven:
            with pytest.raises(InstrumentTimeout):
                oven.read_register(300)
            assert oven.read_register(606) == 1
            assert oven.read_register(901) == 1
            assert oven.read_register(100) == 253
            assert oven.stats.late_bytes == 7  # the late reply, discarded
    assert sim.seen == [300, 606, 901, 100]


def test_late_reply_during_retries_leaves_every_later_read_in_step() -> None:
    # A retry must not take the first try's late reply either: its own reply would then
    # be left over as the answer to the next request, and every read after it off by one
    # (the 30 ms turnaround makes that leftover arrive after the next request is sent).
    with LateSlave(late={0}, delay_s=0.15, turnaround_s=0.03) as sim:
        with WatlowF4(sim.port.path, timeout_s=0.1, retries=2, silence_s=0.3) as oven:
            assert oven.read_register(300) == 250
            assert (oven.stats.no_reply, oven.stats.retries, oven.stats.late_bytes) == (1, 1, 7)
            assert [oven.read_register(r) for r in (606, 901, 100, 300)] == [1, 1, 253, 250]
    assert sim.seen == [300, 300, 606, 901, 100, 300]


def test_reply_straddling_the_timeout_is_waited_out_whole() -> None:
    # 3 bytes in time, 4 after the timeout: a partial reply (bad_reply). The rest is still
    # coming, so the full silence applies, not just the trailing-bytes wait.
    with LateSlave(late={0}, delay_s=0.15, split=3) as sim:
        with WatlowF4(sim.port.path, timeout_s=0.1, retries=0, silence_s=0.3) as oven:
            with pytest.raises(InstrumentError, match="failed after 1 tries"):
                oven.read_register(300)
            assert oven.stats.bad_reply == 1
            assert [oven.read_register(r) for r in (606, 901, 100)] == [1, 1, 253]
            assert oven.stats.late_bytes == 4 and oven.stats.bad_reply == 1
    assert sim.seen == [300, 606, 901, 100]


class DriverTime:
    """The driver module's ``time`` in simulated seconds: ``sleep`` advances ``monotonic``.
    A wait is then measured in the driver's own clock, exactly, whatever the machine's load
    (a wall-clock bound on it failed at load 10+ on 2 cores)."""

    def __init__(self) -> None:
        self.t = 0.0

    def monotonic(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        self.t += s


@pytest.fixture
def driver_time(monkeypatch: pytest.MonkeyPatch) -> DriverTime:
    clock = DriverTime()
    monkeypatch.setattr(watlowf4, "time", clock)
    return clock


def test_whole_reply_with_bad_crc_waits_only_for_trailing_bytes(driver_time: DriverTime) -> None:
    # The slave has finished answering: no silence_s wait (a burst of CRC errors must not
    # cost a timeout each), unlike silence, which waits silence_s before the retry.
    # The stand-in answers at once; its port timeout only decides (round trip < timeout)
    # whether a reply was whole, so it is set far above any scheduling delay.
    bad_crc = PV_25_3[:-1] + bytes([PV_25_3[-1] ^ 0xFF])
    fake = ExpectedSerial([(READ_PV, bad_crc), (READ_PV, PV_25_3)])
    fake.timeout = 30.0
    oven = WatlowF4(fake, timeout_s=0.3)
    assert oven.read_register(100) == 253
    assert oven.stats.bad_reply == 1
    assert oven.trailing_quiet_s <= driver_time.t < oven.trailing_quiet_s + 0.01 < 0.3
    fake = ExpectedSerial([(READ_PV, None), (READ_PV, PV_25_3)])
    oven = WatlowF4(fake, timeout_s=0.3)
    t0 = driver_time.t
    assert oven.read_register(100) == 253
    assert 0.3 <= driver_time.t - t0 < 0.31 and oven.stats.no_reply == 1


class BusyLine(ExpectedSerial):
    """A line another talker (or a wrong baud rate) never leaves quiet: a new byte has
    arrived each time the driver looks. (A chatter thread on a pty could not promise that:
    starved for 20 ms under load, it let the line look quiet.)"""

    looks = 0

    @property
    def in_waiting(self) -> int:
        self.looks += 1
        assert self.looks < 10_000, "the driver never stopped waiting for silence"
        self._rx += b"\x55"
        return len(self._rx)


def test_silence_wait_is_bounded_on_a_line_that_never_goes_quiet(driver_time: DriverTime) -> None:
    # The wait ends at its cap and is counted; the transaction then fails its checks
    # instead of hanging. Garbage answers both tries; the one wait between them is capped.
    junk = b"\x55" * 7
    port = BusyLine([(READ_PV, junk), (READ_PV, junk)])
    oven = WatlowF4(port, timeout_s=0.02, retries=1)
    with pytest.raises(InstrumentError, match="failed after 2 tries"):
        oven.read_register(100)
    cap = 10 * oven.silence_s + 1.0  # 1.2 s
    assert cap <= driver_time.t < cap + 0.01  # ended at its cap, once
    assert oven.stats.noisy_line == 1 and oven.stats.late_bytes > 0
    port.assert_done()


# ----------------------------------------------------------- the F4's documented map
# Register map of ESPEC's ChamberConnectLibrary watlowf4.py (docs/instruments.md): 200 is
# the profile mode (0/1 constant, 2 running, 3 paused), 103/107 heat/cool power in 0.01 %,
# event output N at 2000 + 10(N - 1).


def _rd(reg: int) -> bytes:
    return with_crc(bytes([1, 3]) + reg.to_bytes(2, "big") + (1).to_bytes(2, "big"))


def _val(v: int) -> bytes:
    return with_crc(bytes([1, 3, 2]) + v.to_bytes(2, "big", signed=True))


def _wr(reg: int, v: int) -> bytes:
    return with_crc(bytes([1, 6]) + reg.to_bytes(2, "big") + v.to_bytes(2, "big", signed=True))


def test_status_reads_profile_mode_and_output_power() -> None:
    fake = ExpectedSerial([(_rd(200), _val(0)), (_rd(103), _val(4250)), (_rd(107), _val(0))])
    st = WatlowF4(fake).status
    fake.assert_done()
    assert (st.profile_mode, st.heat_pct, st.cool_pct) == (0, 42.5, 0.0)
    assert st.heating and not st.cooling and st.mode == "heat" and not st.profile_active


def test_event_output_written_and_read_back() -> None:
    # Event 3 is register 2020: written 0, read back 0.
    fake = ExpectedSerial([(_wr(2020, 0), _wr(2020, 0)), (_rd(2020), _val(0))])
    WatlowF4(fake).set_event(3, False)
    fake.assert_done()
    fake = ExpectedSerial([(_wr(2000, 1), _wr(2000, 1)), (_rd(2000), _val(0))])
    with pytest.raises(InstrumentError, match="event output 1 read back 0"):
        WatlowF4(fake).set_event(1, True)


def test_running_profile_refused_at_connect_and_a_fault_mid_run() -> None:
    from gyrolab.instruments.drivers.watlowf4 import WatlowF4Chamber, WatlowF4Config
    from gyrolab.instruments.roles import InstrumentFault

    connect = [(READ_DP, DP_1), (READ_UNITS, UNITS_C), (READ_SP, SP_M40), (READ_PV, PV_25_3)]
    fake = ExpectedSerial([*connect, (_rd(200), _val(2))])
    with pytest.raises(InstrumentError, match="profile is running"):
        WatlowF4Chamber(fake, config=WatlowF4Config()).connect()
    fake = ExpectedSerial(
        [*connect, (_rd(200), _val(0)), (READ_SP, SP_M40), (READ_PV, PV_25_3), (_rd(200), _val(3))]
    )
    ch = WatlowF4Chamber(fake, config=WatlowF4Config())
    ch.connect()
    with pytest.raises(InstrumentFault, match="register 200 = 3"):
        ch.read()


def test_alarm_input_read_as_espec_reads_it() -> None:
    """``alarm_input = 2``: connect reads digital input 2's active condition (register
    1063), each reading its state (register 213); the chamber is in alarm while they agree
    (ChamberConnectLibrary ``watlowf4.py``)."""
    from gyrolab.instruments.drivers.watlowf4 import WatlowF4Chamber, WatlowF4Config

    connect = [(READ_DP, DP_1), (READ_UNITS, UNITS_C), (READ_SP, SP_M40), (READ_PV, PV_25_3)]
    reading = [(READ_SP, SP_M40), (READ_PV, PV_25_3), (_rd(200), _val(0))]
    fake = ExpectedSerial(
        [*connect, (_rd(200), _val(0)), (_rd(1063), _val(1))]
        + [*reading, (_rd(213), _val(0))]
        + [*reading, (_rd(213), _val(1))]
    )
    ch = WatlowF4Chamber(fake, config=WatlowF4Config(alarm_input=2))
    assert ch.connect()["digital_input_2_condition"] == 1
    assert ch.read().alarm == ""
    r = ch.read()
    fake.assert_done()
    assert (r.setpoint_c, r.process_value_c) == (-40.0, 25.3)
    assert r.alarm == "limit alarm: digital input 2 active (register 213 = 1)"


def test_simulated_f4_alarm_stops_the_chamber_until_it_clears() -> None:
    from gyrolab.instruments.drivers.watlowf4 import WatlowF4Chamber, WatlowF4Config

    with SimBench(speed=200.0, oven_alarm_input=1, ambient_c=22.0) as bench:
        bench.inject(FaultEvent("disconnect", duration_s=1e9))
        with WatlowF4Chamber(bench.oven_port, config=WatlowF4Config(alarm_input=1)) as oven:
            oven.connect()
            assert oven.set_setpoint(50.0) == 50.0 and oven.read().alarm == ""
            bench.inject(FaultEvent("chamber_alarm", duration_s=1e9))
            assert "digital input 1 active" in oven.read().alarm
            assert bench.physics.setpoint_c == 22.0  # heater and refrigerator off
            assert oven.setpoint_c == 50.0  # the controller keeps its setpoint
            bench.oven.set_alarm(False)
            assert oven.read().alarm == "" and bench.physics.setpoint_c == 50.0


def test_simulated_f4_control_event_switches_the_chamber() -> None:
    from gyrolab.instruments.drivers.watlowf4 import WatlowF4Chamber, WatlowF4Config

    with SimBench(speed=200.0, oven_control_event=2, ambient_c=22.0) as bench:
        bench.inject(FaultEvent("disconnect", duration_s=1e9))
        with WatlowF4Chamber(bench.oven_port, config=WatlowF4Config(control_event=2)) as oven:
            assert oven.connect()["event_2"] == 0
            assert oven.set_setpoint(50.0) == 50.0  # and event 2 on, read back
            assert bench.oven.events[1] == 1 and bench.physics.setpoint_c == 50.0
            assert oven.status.heating
            oven.switch_off()
            assert bench.oven.events[1] == 0 and bench.physics.setpoint_c == 22.0
            assert oven.setpoint_c == 50.0  # register 300 keeps its value; the chamber is off
            assert oven.status.heat_pct == 0.0


@pytest.mark.parametrize("chamber", ["watlowf4", "espec"])
def test_safe_state_off_leaves_the_chamber_switched_off(tmp_path, chamber) -> None:
    """``[safe_state] mode = "off"``: at the end of a run the safe setpoint is verified and
    the chamber switched off (F4: its control event output; ESPEC: STANDBY), verified."""
    from gyrolab.acquisition.bench_config import bench_from_dict
    from gyrolab.app.acquire import run_acquisition
    from gyrolab.app.sim_bench import start_sim_bench
    from gyrolab.profiles.profile import load_profile
    from gyrolab.record.reader import read_recording

    prof_file = tmp_path / "p.toml"
    prof_file.write_text('name = "t"\n[[step]]\nsetpoint_c = 30\nduration_s = 40\n')
    prof = load_profile(prof_file)
    table = {"driver": chamber, **({"control_event": 1} if chamber == "watlowf4" else {})}
    safe = {"mode": "off", "setpoint_c": 20.0}
    cfg = bench_from_dict({"chamber": table, "safe_state": safe}, "b.toml")
    sim, cfg = start_sim_bench(cfg, prof, seed=0, speed=50.0)
    out = tmp_path / "run.mcap"
    try:
        res = run_acquisition(cfg=cfg, profile=prof, out=out, force=False, sim=sim)
        bench = sim.bench
        off = bench.oven.events[0] == 0 if chamber == "watlowf4" else bench.espec.mode == "STANDBY"
        # Off: the chamber drifts to ambient (25 °C), not to the 20 °C setpoint it holds.
        assert off and bench.physics.setpoint_c == pytest.approx(25.0)
    finally:
        sim.stop()
    assert res.safe_state_ok
    (ev,) = [e for e in read_recording(out).events if e["event"] == "safe_state"]
    assert ev["detail"] == "setpoint 20 °C verified, chamber off verified"


def test_safe_state_off_needs_a_control_event() -> None:
    from gyrolab.acquisition.bench_config import bench_from_dict
    from gyrolab.errors import InputError

    with pytest.raises(InputError, match="needs \\[chamber\\] control_event"):
        bench_from_dict({"safe_state": {"mode": "off"}}, "b.toml")
    with pytest.raises(InputError, match="control_event must be"):
        bench_from_dict({"chamber": {"control_event": 9}}, "b.toml")
