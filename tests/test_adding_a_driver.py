"""Adding a driver touches its module and its test only (docs/instruments.md, "Adding a
driver"). The ``pt104`` thermometer below exists in this test module alone: it is
registered, named in a BENCH.toml and opened through the calls ``gyrolab acquire --bench``
makes (``load_bench`` → ``connect_instruments`` → ``registry.open_driver``), beside the
simulated F4 and ADC, and read over the expected-protocol harness."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from gyrolab.acquisition.bench_config import load_bench
from gyrolab.app.acquire import connect_instruments, lab_addresses
from gyrolab.errors import InputError
from gyrolab.instruments import registry
from gyrolab.instruments.registry import DriverSpec, OpenContext, connected
from gyrolab.instruments.roles import InstrumentError, InstrumentReport, ThermometerReading
from gyrolab.instruments.testing import ExpectedResourceManager, expected_protocol
from gyrolab.pt100 import cvd_temperature
from gyrolab.sim.bench import SimBench

IDN = "ACME,PT-104,SN0042,1.0"
R_25C = "+1.097347E+02"  # a PT100 at 25.00 °C (IEC 60751), Ω
RESOURCE = "TCPIP::10.0.0.9::5025::SOCKET"


# ------------------------------------------------------------ the driver's module
@dataclass(frozen=True)
class Pt104Config:
    """``[thermometer] driver = "pt104"``."""

    driver: str = "pt104"
    resource: str = ""
    timeout_s: float = 2.0
    period_s: float = 1.0
    r0_ohm: float = 100.0
    serial: str = ""


class Pt104:
    """A 4-wire PT100 reader speaking two SCPI queries: ``*IDN?`` and ``MEAS:FRES?`` (Ω)."""

    name = "multimeter"

    def __init__(self, resource: Any, *, config: Pt104Config) -> None:
        self.inst = resource
        self.config = config
        self.idn = ""

    def connect(self) -> None:
        self.idn = self.inst.query("*IDN?").strip()
        if "PT-104" not in self.idn:
            raise InstrumentError("PT-104", f"unexpected instrument {self.idn!r}")

    def read(self) -> ThermometerReading:
        reply = self.inst.query("MEAS:FRES?").strip()
        try:
            r = float(reply)
        except ValueError:
            raise InstrumentError("PT-104", f"MEAS:FRES? returned {reply!r}") from None
        return ThermometerReading(r, float(cvd_temperature(r, self.config.r0_ohm)))

    def reports(self) -> list[InstrumentReport]:
        return []  # no error queue

    def describe(self) -> dict[str, Any]:
        _, model, serial, firmware = (p.strip() for p in self.idn.split(","))
        return {
            "driver": self.config.driver,
            "model": model,
            "serial": self.config.serial or serial,
            "firmware": firmware,
            "resource": self.inst.resource_name,
        }

    def close(self) -> None:
        self.inst.close()


def open_pt104(c: Pt104Config, ctx: OpenContext) -> Pt104:
    rm = ctx.visa_library
    if isinstance(rm, str):
        import pyvisa

        rm = pyvisa.ResourceManager(rm)
    inst = rm.open_resource(ctx.address)
    inst.timeout = int(ctx.timeout(c.timeout_s) * 1000)
    return connected(Pt104(inst, config=c))


SPEC = DriverSpec(
    name="pt104",
    role="thermometer",
    config=Pt104Config,
    open=open_pt104,
    address_key="resource",
    description="a PT100 reader defined in a test",
)
# -----------------------------------------------------------------------------------


@pytest.fixture
def pt104() -> Iterator[DriverSpec]:
    # A driver module calls register() at import; here the registration is undone after
    # the test so that the other tests see the built-in drivers only.
    registry.register(SPEC)
    yield SPEC
    registry.unregister(SPEC.name)


def test_pt104_protocol() -> None:
    dialogue = [("*IDN?", IDN), ("MEAS:FRES?", R_25C)]
    with expected_protocol(Pt104, dialogue, config=Pt104Config()) as t:
        t.connect()
        r = t.read()
    assert r.resistance_ohm == pytest.approx(109.7347)
    assert r.temperature_c == pytest.approx(25.0, abs=0.001)


def _bench_file(tmp_path: Path, oven_port: str, adc_port: str) -> Path:
    f = tmp_path / "BENCH.toml"
    f.write_text(
        f'[thermometer]\ndriver = "pt104"\nresource = "{RESOURCE}"\nserial = "T-7"\n'
        f'[chamber]\nport = "{oven_port}"\n[rate_stream]\nport = "{adc_port}"\n'
    )
    return f


def _connect(cfg: Any, rm: ExpectedResourceManager) -> Any:
    # As run_acquisition does on the lab path, with the harness as the VISA library.
    return connect_instruments(cfg, lab_addresses(cfg), visa_library=rm)


def test_a_driver_defined_in_its_test_opens_from_a_bench_file(tmp_path, pt104) -> None:
    with SimBench(speed=200.0) as bench:
        cfg = load_bench(_bench_file(tmp_path, bench.oven_port, bench.adc_port))
        assert cfg.thermometer == Pt104Config(resource=RESOURCE, serial="T-7")
        rm = ExpectedResourceManager({RESOURCE: [("*IDN?", IDN), ("MEAS:FRES?", R_25C)]})
        inst = _connect(cfg, rm)
        try:
            assert inst.thermometer.name == "multimeter"
            assert inst.thermometer.read().temperature_c == pytest.approx(25.0, abs=0.001)
            assert inst.identity["multimeter"] == {
                "driver": "pt104",
                "model": "PT-104",
                "serial": "T-7",
                "firmware": "1.0",
                "resource": RESOURCE,
            }
            assert inst.identity["oven"]["driver"] == "watlowf4"
        finally:
            inst.close()
    rm.assert_done()


def test_a_driver_that_does_not_answer_is_one_input_error(tmp_path, pt104) -> None:
    cfg = load_bench(_bench_file(tmp_path, "/dev/null-oven", "/dev/null-adc"))
    with pytest.raises(InputError, match=r"\[thermometer\] pt104 at TCPIP.*no instrument"):
        _connect(cfg, ExpectedResourceManager({}))
    registry.unregister("pt104")
    with pytest.raises(InputError, match="no thermometer driver 'pt104'"):
        load_bench(tmp_path / "BENCH.toml")
