"""ESPEC P-300 chamber driver: the command dialogue (expected command → reply), limits
checked before anything is sent, read-back, standby verified, and end to end against the
simulated controller over a real TCP socket."""

from __future__ import annotations

import pytest

from gyrolab.instruments import registry
from gyrolab.instruments.drivers.espec import EspecChamber, EspecConfig
from gyrolab.instruments.roles import InstrumentError, LimitError, is_transient
from gyrolab.instruments.testing import ExpectedVisa, expected_protocol
from gyrolab.sim.bench import FaultEvent, SimBench

CONNECT = [
    ("ROM?", "P300 ROM Ver1.20"),
    ("TYPE?", "T,S4,200.0"),
    ("TEMP?", "23.4,25.0,200.0,-75.0"),
    ("MODE?", "STANDBY"),
]


def _chamber(port, limits=(-45.0, 70.0)):
    return EspecChamber(port, config=EspecConfig(), setpoint_limits_c=limits)


def test_connect_reads_identity_and_controller_range() -> None:
    with expected_protocol(_chamber, CONNECT) as ch:
        info = ch.connect()
    assert info["range_c"] == [-75.0, 200.0] and info["mode"] == "STANDBY"
    assert ch.describe()["rom"] == "P300 ROM Ver1.20"


def test_setpoint_turns_control_on_and_is_read_back() -> None:
    with expected_protocol(
        _chamber,
        [
            ("TEMP, S60.0", "OK: TEMP, S60.0"),
            ("MODE?", "STANDBY"),
            ("MODE, CONSTANT", "OK: MODE, CONSTANT"),
            ("TEMP?", "23.5,60.0,200.0,-75.0"),
        ],
    ) as ch:
        assert ch.set_setpoint(60.0) == 60.0
    with pytest.raises(InstrumentError, match="read-back"):
        with expected_protocol(
            _chamber,
            [
                ("TEMP, S40.0", "OK: TEMP, S40.0"),
                ("MODE?", "CONSTANT"),
                ("TEMP?", "23.5,25.0,200.0,-75.0"),
            ],
        ) as ch:
            ch.set_setpoint(40.0)


@pytest.mark.parametrize("bad", [70.1, -45.5, float("nan"), float("inf"), 500.0])
def test_out_of_limit_setpoint_refused_before_any_byte(bad: float) -> None:
    port = ExpectedVisa([])
    ch = _chamber(port)
    with pytest.raises(LimitError) as ei:
        ch.set_setpoint(bad)
    assert port.written == []
    assert not is_transient(ei.value)  # the runner never retries it


def test_controller_range_is_a_limit_too() -> None:
    with expected_protocol(
        _chamber,
        CONNECT[:2] + [("TEMP?", "23.4,25.0,50.0,-20.0"), ("MODE?", "STANDBY")],
        limits=(-45.0, 70.0),
    ) as ch:
        ch.connect()
    port = ExpectedVisa([])
    ch.inst = port
    with pytest.raises(LimitError, match="controller range"):
        ch.set_setpoint(60.0)
    assert port.written == []


def test_refusal_alarm_and_standby() -> None:
    with pytest.raises(InstrumentError, match="refused: CMD ERR"):
        with expected_protocol(_chamber, [("MODE?", "NA:CMD ERR")]) as ch:
            _ = ch.mode
    # An alarm is reported with the reading; the run engine decides (its suspenders).
    with expected_protocol(
        _chamber, [("TEMP?", "23.4,25.0,200.0,-75.0"), ("MON?", "23.4,,CONSTANT,1")]
    ) as ch:
        assert ch.read() == (25.0, 23.4, "ESPEC controller reports 1 active alarm(s) (MON?)")
    with expected_protocol(
        _chamber, [("MODE, STANDBY", "OK: MODE, STANDBY"), ("MODE?", "STANDBY")]
    ) as ch:
        assert ch.standby() == "STANDBY"


def test_end_to_end_over_tcp_against_the_simulated_controller() -> None:
    with SimBench(seed=1, speed=50.0, chamber_model="P300") as bench:
        bench.adc.unplug()
        ctx = registry.OpenContext(
            bench.chamber_tcp_resource, lambda t: t, (-45.0, 70.0), lambda: 0.0
        )
        ch = registry.get("espec", "chamber").open(EspecConfig(), ctx)
        try:
            assert ch.set_setpoint(42.5) == 42.5
            assert bench.espec.mode == "CONSTANT" and bench.physics.setpoint_c == 42.5
            sp, pv, alarm = ch.read()
            assert sp == 42.5 and abs(pv - 25.0) < 5.0 and alarm == ""
            bench.inject(FaultEvent("chamber_alarm", duration_s=1e9))
            assert ch.read().alarm and bench.espec.mode == "STANDBY"
            assert bench.physics.setpoint_c == 25.0  # stopped: drifts to ambient
            bench.espec.set_alarm(False)
            assert ch.read().alarm == "" and bench.espec.mode == "STANDBY"
            assert ch.set_setpoint(42.5) == 42.5 and bench.espec.mode == "CONSTANT"
            with pytest.raises(LimitError):
                ch.set_setpoint(90.0)
            assert not any("S90" in c for c in bench.espec.log)
            assert ch.standby() == "STANDBY"
            assert bench.physics.setpoint_c == 25.0  # control off: drifts to ambient
        finally:
            ch.close()


@pytest.mark.parametrize("thermometer", ["keysight34465a", "agilent34401a"])
def test_acquire_on_the_simulated_bench_with_the_new_drivers(tmp_path, thermometer) -> None:
    """``acquire --bench sim --driver …``: any combination runs, and the recording names
    the drivers that took it."""
    from gyrolab.cli import main
    from gyrolab.record.reader import read_recording

    prof = tmp_path / "p.toml"
    prof.write_text(
        'name = "t"\n[[step]]\nsetpoint_c = 25\nduration_s = 40\n'
        "[[step]]\nsetpoint_c = 35\nduration_s = 60\n"
    )
    out = tmp_path / "run.mcap"
    argv = ["acquire", "--bench", "sim", "--driver", thermometer, "--driver", "espec"]
    argv += ["--profile", str(prof), "--speed", "50", "--out", str(out)]
    assert main(argv) == 0
    rec = read_recording(out)
    assert rec.bench["multimeter"]["driver"] == thermometer
    assert rec.bench["oven"]["driver"] == "espec"
    assert [e["event"] for e in rec.events][-1] == "safe_state"
    assert rec.oven_setpoint_c.max() == pytest.approx(35.0)
