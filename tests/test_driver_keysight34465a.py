"""Keysight 34465A driver: the SCPI dialogue (expected command → reply) and end to end
against the simulated 34465A over a real TCP socket."""

from __future__ import annotations

import numpy as np
import pytest

from gyrolab.instruments import registry
from gyrolab.instruments.drivers.keysight34465a import Keysight34465A, Keysight34465AConfig
from gyrolab.instruments.roles import InstrumentError, LimitError
from gyrolab.instruments.testing import ExpectedVisa, expected_protocol
from gyrolab.pt100 import cvd_resistance
from gyrolab.sim.bench import SimBench

IDN = "Keysight Technologies,34465A,MY59000001,A.03.01-03.15-03.01-00.52-04-02"
OK = '+0,"No error"'
CONNECT = [
    ("*RST", None),
    ("*CLS", None),
    ("*IDN?", IDN),
    ("CONF:FRES 1000", None),
    ("FRES:NPLC 10", None),
    ("FRES:OCOM ON", None),
    ("SYST:ERR?", OK),
]


def _dmm(port, **kw):
    return Keysight34465A(port, config=Keysight34465AConfig(**kw))


def test_connect_dialogue_sets_offset_compensation() -> None:
    with expected_protocol(_dmm, CONNECT) as dmm:
        assert dmm.connect() == IDN
    off = [c if c[0] != "FRES:OCOM ON" else ("FRES:OCOM OFF", None) for c in CONNECT]
    with expected_protocol(_dmm, off, offset_compensation=False) as dmm:
        dmm.connect()
        assert dmm.describe()["offset_compensation"] is False


def test_reading_drains_the_error_queue_and_converts_to_celsius() -> None:
    r20 = float(cvd_resistance(20.0))
    with expected_protocol(
        _dmm,
        [("READ?", f"{r20:+.8E}"), ("SYST:ERR?", '-222,"Data out of range"'), ("SYST:ERR?", OK)],
    ) as dmm:
        r = dmm.read()
        assert r.temperature_c == pytest.approx(20.0, abs=1e-4)
        (rep,) = dmm.reports()
        assert (rep.code, rep.fatal) == (-222, False)


def test_wrong_instrument_and_bad_settings_refused() -> None:
    with pytest.raises(InstrumentError, match="unexpected instrument"):
        with expected_protocol(
            _dmm, [("*RST", None), ("*CLS", None), ("*IDN?", "HEWLETT-PACKARD,34401A,0,11-5-2")]
        ) as dmm:
            dmm.connect()
    port = ExpectedVisa([])
    with pytest.raises(LimitError, match="NPLC"):
        Keysight34465A(port, config=Keysight34465AConfig(), nplc=0.5)
    with pytest.raises(LimitError, match="offset compensation"):
        Keysight34465A(port, config=Keysight34465AConfig(), range_ohm=1e6)
    assert port.written == []


def test_registered_and_selectable() -> None:
    spec = registry.get("keysight34465a", "thermometer")
    assert spec.config is Keysight34465AConfig and spec.sim_backend == "34465A"


def test_readings_over_tcp_match_the_simulated_pt100() -> None:
    with SimBench(seed=3, speed=50.0, dmm_model="34465A", ambient_c=30.0) as bench:
        bench.adc.unplug()
        ctx = registry.OpenContext(bench.dmm_tcp_resource, lambda t: t, (-45.0, 70.0), lambda: 0.0)
        dmm = registry.get("keysight34465a", "thermometer").open(
            Keysight34465AConfig(nplc=1.0), ctx
        )
        try:
            assert "FRES:OCOM ON" in bench.dmm.log and bench.dmm.ocomp
            got = np.array([dmm.read().resistance_ohm for _ in range(5)])
            assert dmm.reports() == []
        finally:
            dmm.close()
        truth = np.array([r for _, _, r in list(bench.dmm_truth)[-5:]])
    # The driver reports exactly what the simulated meter read (8 significant digits).
    np.testing.assert_allclose(got, truth, rtol=1e-8)
    assert got.mean() == pytest.approx(float(cvd_resistance(30.0)), abs=0.5)
