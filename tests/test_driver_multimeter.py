"""Agilent 34401A driver: the SCPI dialogue (PyMeasure-style expected command → reply
lists), pyvisa-sim, and end to end against the simulated meter over TCP and a pty."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest

import gyrolab.sim.bench as bench_pkg
from gyrolab.instruments.drivers.agilent34401a import Agilent34401A
from gyrolab.instruments.roles import InstrumentError, InstrumentTimeout, LimitError
from gyrolab.instruments.testing import ExpectedVisa
from gyrolab.pt100 import cvd_resistance, cvd_temperature
from gyrolab.sim.bench import FaultEvent, SimBench

IDN = "HEWLETT-PACKARD,34401A,0,11-5-2"
OK = '+0,"No error"'
YAML = Path(bench_pkg.__file__).with_name("agilent34401a.yaml")


CONNECT = [
    ("*RST", None),
    ("*CLS", None),
    ("*IDN?", IDN),
    ("CONF:FRES 1000", None),
    ("FRES:NPLC 10", None),
    ("SYST:ERR?", OK),
]


def test_connect_dialogue_gpib() -> None:
    fake = ExpectedVisa(CONNECT)
    dmm = Agilent34401A(fake)
    assert dmm.connect() == IDN
    assert fake.timeout == 5000  # ms
    assert fake.write_termination == "\n" and fake.read_termination == "\n"
    fake.assert_done()


def test_connect_dialogue_rs232_goes_remote_first_and_local_on_close() -> None:
    fake = ExpectedVisa([("SYST:REM", None), *CONNECT, ("SYST:LOC", None)], "ASRL1::INSTR")
    dmm = Agilent34401A(fake)
    dmm.connect()
    dmm.close()
    fake.assert_done()
    assert fake.closed


def test_reading_in_ohm_and_celsius() -> None:
    fake = ExpectedVisa([("READ?", "+1.09735000E+02"), ("READ?", "+8.42707000E+01")])
    dmm = Agilent34401A(fake)
    r = dmm.read()
    assert r.resistance_ohm == pytest.approx(109.735)
    assert r.temperature_c == pytest.approx(25.0, abs=2e-3)
    assert dmm.read().temperature_c == pytest.approx(-40.0, abs=2e-3)
    fake.assert_done()


def test_overload_raises() -> None:
    # A PT100 at 60 °C (123.24 Ω) overloads the 100 Ω range (120 Ω full scale).
    dmm = Agilent34401A(ExpectedVisa([("READ?", "+9.90000000E+37")]), range_ohm=100.0)
    with pytest.raises(InstrumentError, match="overload"):
        _ = dmm.resistance


def test_errors_after_configuration_raise_with_codes() -> None:
    fake = ExpectedVisa(
        [
            ("CONF:FRES 1000", None),
            ("FRES:NPLC 10", None),
            ("SYST:ERR?", '-222,"Data out of range"'),
            ("SYST:ERR?", '-113,"Undefined header"'),
            ("SYST:ERR?", OK),
        ]
    )
    with pytest.raises(InstrumentError, match=r"-222,Data out of range; -113,Undefined header"):
        Agilent34401A(fake).configure()
    fake.assert_done()


def test_bad_settings_refused_before_sending() -> None:
    fake = ExpectedVisa([])  # any command would fail the test
    with pytest.raises(LimitError):
        Agilent34401A(fake, range_ohm=120.0)
    dmm = Agilent34401A(fake)
    with pytest.raises(LimitError):
        dmm.configure(nplc=7)
    fake.assert_done()


@pytest.mark.parametrize(
    "resource", ["ASRL1::INSTR", "TCPIP::127.0.0.1::5025::SOCKET", "GPIB0::22::INSTR"]
)
def test_pyvisa_sim_protocol(resource: str) -> None:
    with Agilent34401A(resource, visa_library=f"{YAML}@sim") as dmm:
        assert dmm.connect() == IDN
        r = dmm.read()
        assert r.resistance_ohm == pytest.approx(107.794)
        assert r.temperature_c == pytest.approx(20.0, abs=2e-3)
        assert dmm.query("FRES:NPLC?") == "+1.00000000E+01"
        dmm.write("FRES:NPLC 7")  # not a 34401A value: the simulated queue reports it
        with pytest.raises(InstrumentError, match="-113"):
            dmm.check_errors()


# ------------------------------------------------------------------- end to end


def _readings(dmm: Agilent34401A, bench: SimBench, n: int) -> tuple[np.ndarray, np.ndarray]:
    """n readings through the driver, and the simulated PT100's noise-free resistance at
    the simulated moment each was taken (the bench logs every reading it serves)."""
    bench.dmm_truth.clear()
    got = np.array([dmm.read().resistance_ohm for _ in range(n)])
    log = np.array(bench.dmm_truth)
    assert log.shape == (n, 3)
    assert np.allclose(got, log[:, 2], rtol=1e-8)  # 8 significant digits on the wire
    return got, log[:, 1]


@pytest.mark.parametrize("transport", ["tcp", "pty"])
@pytest.mark.parametrize("ambient_c", [25.0, -30.0])
def test_readings_match_simulated_pt100(transport: str, ambient_c: float) -> None:
    with SimBench(speed=100.0, ambient_c=ambient_c) as bench:
        noise = bench.physics.model.sensors.dmm_noise_ohm
        res = bench.dmm_tcp_resource if transport == "tcp" else bench.dmm_serial_resource
        with Agilent34401A(res) as dmm:
            assert dmm.connect() == IDN
            got, true = _readings(dmm, bench, 25)
            temp = dmm.read().temperature_c
        if transport == "pty":
            deadline = time.monotonic() + 2.0  # the server thread handles SYST:LOC shortly
            while bench.dmm.state.remote and time.monotonic() < deadline:
                time.sleep(0.01)
            assert bench.dmm.state.remote is False  # SYST:LOC on close
    resid = got - true
    assert np.all(np.abs(resid) < 5 * noise + 1e-4)  # each within 5σ (+ 8-digit rounding)
    assert abs(resid.mean()) < 4 * noise / np.sqrt(resid.size) + 1e-4
    assert 0.4 * noise < resid.std() < 2.0 * noise  # the noise is the simulator's
    # The case warms slowly above ambient (gyro self-heating in the simulator).
    assert temp == pytest.approx(ambient_c, abs=0.5)
    assert true.mean() == pytest.approx(cvd_resistance(ambient_c), abs=0.2)


def test_outage_times_out_then_recovers() -> None:
    with SimBench(speed=20.0) as bench:
        with Agilent34401A(bench.dmm_tcp_resource, timeout_s=0.3) as dmm:
            dmm.connect()
            bench.inject(FaultEvent("outage", duration_s=20.0))  # 1 s of wall time
            with pytest.raises(InstrumentTimeout):
                dmm.read()
            # past the outage (1 s of wall at 20x; the limit guards a hang, load may slow it)
            assert bench.clock.wait_until(bench.clock.now() + 20.0, timeout_wall_s=300.0)
            assert dmm.read().temperature_c == pytest.approx(25.0, abs=0.1)


def test_injected_scpi_error_is_reported() -> None:
    with SimBench(speed=50.0) as bench:
        with Agilent34401A(bench.dmm_serial_resource) as dmm:
            dmm.connect()
            bench.inject(FaultEvent("scpi_error", detail='-310,"System error"'))
            with pytest.raises(InstrumentError, match="-310"):
                dmm.check_errors()
            dmm.check_errors()  # the queue is empty again


@pytest.mark.hardware
@pytest.mark.skipif(
    not os.environ.get("GYROLAB_DMM_RESOURCE"), reason="set GYROLAB_DMM_RESOURCE to a 34401A"
)
def test_real_meter() -> None:
    with Agilent34401A(os.environ["GYROLAB_DMM_RESOURCE"]) as dmm:
        assert "34401" in dmm.connect()
        r = dmm.read()
        assert 80.0 < r.resistance_ohm < 130.0  # a PT100 somewhere in -50…80 °C


# ------------------------------------------------------------------- PT100 (IEC 60751)


@pytest.mark.parametrize(
    ("t_c", "r_ohm"),
    [
        (-200.0, 18.52),
        (-40.0, 84.27),
        (0.0, 100.0),
        (60.0, 123.24),
        (100.0, 138.51),
        (850.0, 390.48),
    ],
)
def test_cvd_matches_iec_60751_table(t_c: float, r_ohm: float) -> None:
    assert cvd_resistance(t_c) == pytest.approx(r_ohm, abs=0.005)  # table is to 0.01 Ω
    assert cvd_temperature(r_ohm) == pytest.approx(t_c, abs=0.02)


def test_cvd_inverse_roundtrip_and_agrees_with_the_simulator() -> None:
    from gyrolab.sim import sensors  # the simulator's own, independent implementation

    t = np.linspace(-200.0, 850.0, 2101)
    r = cvd_resistance(t)
    assert np.max(np.abs(cvd_temperature(r) - t)) < 1e-9
    assert np.max(np.abs(sensors.cvd_resistance(t) - r)) < 1e-9
    assert np.isnan(cvd_temperature(-1.0))
