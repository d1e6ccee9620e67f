"""Keysight 34970A scanner driver: the SCPI dialogue (expected command → reply), its
checks before any I/O, and end to end against the simulated 34970A over a real TCP socket."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gyrolab.instruments import registry
from gyrolab.instruments.drivers.keysight34970a import (
    Keysight34970A,
    Keysight34970AConfig,
    channel_list,
)
from gyrolab.instruments.roles import InstrumentError, LimitError
from gyrolab.instruments.testing import ExpectedVisa, expected_protocol
from gyrolab.pt100 import cvd_resistance
from gyrolab.sim.bench.scanner_scpi import Scpi34970A

IDN = "Agilent Technologies,34970A,MY44000001,13-2-2"
OK = '+0,"No error"'
CHANS = (101, 102, 103)
CONNECT = [
    ("*RST", None),
    ("*CLS", None),
    ("*IDN?", IDN),
    ("CONF:FRES 1000,(@101:103)", None),
    ("FRES:NPLC 1,(@101:103)", None),
    ("ROUT:SCAN (@101:103)", None),
    ("ROUT:SCAN:SIZE?", "+3"),
    ("SYST:ERR?", OK),
]


def _scanner(port, **kw):
    return Keysight34970A(port, config=Keysight34970AConfig(channels=CHANS, **kw))


def test_connect_dialogue_configures_the_scan_list() -> None:
    with expected_protocol(_scanner, CONNECT) as s:
        assert s.connect() == IDN
        d = s.describe()
        assert (d["model"], d["serial"], d["channels"]) == ("34970A", "MY44000001", [101, 102, 103])
    daq = "Keysight Technologies,DAQ970A,MY58000001,A.02.02-01.00-02.01-00.02-03-02"
    with expected_protocol(_scanner, [*CONNECT[:2], ("*IDN?", daq), *CONNECT[3:]]) as s:
        assert s.connect() == daq


def test_sweep_gives_one_reading_per_channel_and_nan_for_an_open_sensor() -> None:
    r20, r30 = float(cvd_resistance(20.0)), float(cvd_resistance(30.0))
    sweep = f"{r20:+.8E},{r30:+.8E},+9.90000000E+37"
    with expected_protocol(
        _scanner, [("READ?", sweep), ("SYST:ERR?", '-222,"Data out of range"'), ("SYST:ERR?", OK)]
    ) as s:
        got = s.read()
        assert list(got) == [101, 102, 103]
        assert got[101].temperature_c == pytest.approx(20.0, abs=1e-4)
        assert got[102].resistance_ohm == pytest.approx(r30)
        assert math.isnan(got[103].resistance_ohm) and math.isnan(got[103].temperature_c)
        (rep,) = s.reports()
        assert (rep.code, rep.fatal) == (-222, False)


def test_refusals() -> None:
    # A sweep of the wrong length is a failed exchange (retried), not three readings.
    with expected_protocol(_scanner, [("READ?", "+1.0E+02,+1.1E+02")]) as s:
        with pytest.raises(InstrumentError, match="2 readings for 3 channels"):
            s.read()
    with pytest.raises(InstrumentError, match="scan list holds 2"):
        with expected_protocol(_scanner, [*CONNECT[:6], ("ROUT:SCAN:SIZE?", "+2")]) as s:
            s.connect()
    with pytest.raises(InstrumentError, match="unexpected instrument"):
        with expected_protocol(_scanner, [*CONNECT[:2], ("*IDN?", "HP,34401A,0,1")]) as s:
            s.connect()
    port = ExpectedVisa([])
    for chans, card, match in [
        ((101, 111), "34901A", "channel 111"),  # 111 is 101's sense channel
        ((101, 109), "34902A", "channel 109"),  # the 34902A pairs n with n+8
        ((101, 101), "34901A", "twice"),
        ((), "34901A", "no channels"),
        ((101,), "34908A", "card"),
    ]:
        with pytest.raises(LimitError, match=match):
            Keysight34970A(port, config=Keysight34970AConfig(channels=chans, card=card))
    with pytest.raises(LimitError, match="NPLC"):
        Keysight34970A(port, config=Keysight34970AConfig(channels=CHANS, nplc=0.5))
    assert port.written == []


def test_channel_list_and_registration() -> None:
    assert channel_list((101, 102, 103, 105, 201)) == "(@101:103,105,201)"
    assert channel_list((104,)) == "(@104)"
    spec = registry.get("keysight34970a", "multi_thermometer")
    assert spec.config is Keysight34970AConfig and spec.sim_backend == "34970A"
    assert registry.SOURCE_NAME["multi_thermometer"] == "scanner"


def test_simulated_scanner_speaks_the_subset() -> None:
    sim = Scpi34970A(lambda ch: 100.0 + ch / 1000 if ch < 103 else None)
    assert sim.handle("CONF:FRES 1000,(@101:103)") is None
    assert sim.handle("ROUT:SCAN?") == "#214(@101,102,103)"  # the User's Guide's example
    assert sim.handle("ROUT:SCAN:SIZE?") == "3"
    vals = sim.handle("READ?").split(",")  # type: ignore[union-attr]
    assert vals[:2] == ["+1.00101000E+02", "+1.00102000E+02"] and vals[2] == "+9.90000000E+37"
    assert sim.handle("CONF:FRES 1000,(@111)") is None  # a sense channel: refused
    assert sim.handle("SYST:ERR?") == '-221,"Settings conflict"'
    assert sim.handle("SYST:ERR?") == OK


def test_sweeps_over_tcp_match_each_units_pt100() -> None:
    from gyrolab.sim.bench import SimBench
    from gyrolab.sim.family import unit_family
    from gyrolab.sim.model import nominal_model
    from gyrolab.sim.physics import Physics

    units = unit_family(nominal_model(), 3, 5)
    phys = [Physics(u.model, rate_hz=10.0, seed=u.seed, ambient_c=30.0) for u in units]
    with SimBench(unit_physics=phys, speed=50.0, ambient_c=30.0, rate_hz=10.0) as bench:
        for src in bench.unit_adcs:
            src.unplug()  # nobody reads the ADC ports here
        assert len(set(bench.unit_adc_ports)) == 3
        ctx = registry.OpenContext(
            bench.scanner_tcp_resource, lambda t: t, (-45.0, 70.0), lambda: 0.0
        )
        cfg = Keysight34970AConfig(channels=(101, 102, 103))
        s = registry.get("keysight34970a", "multi_thermometer").open(cfg, ctx)
        try:
            sweeps = [s.read() for _ in range(3)]
            assert s.reports() == []
        finally:
            s.close()
        assert bench.scanner is not None and bench.scanner.sweeps == 3
    got = np.array([[sw[c].resistance_ohm for c in (101, 102, 103)] for sw in sweeps])
    # Every unit's own PT100 (its case at 30 °C at power-on) on its own channel.
    np.testing.assert_allclose(got, float(cvd_resistance(30.0)), atol=0.5)
