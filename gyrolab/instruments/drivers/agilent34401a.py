"""``agilent34401a``: the HP/Agilent 34401A as the bench's thermometer (4-wire PT100).

The SCPI driver is :class:`gyrolab.instruments.multimeter.Agilent34401A`; this module
makes it fill the :class:`~gyrolab.instruments.roles.Thermometer` role (the error queue
read after every reading, the identity) and registers it.
"""

from __future__ import annotations

from typing import Any, TypeVar

from gyrolab.acquisition.bench_config import MultimeterConfig
from gyrolab.instruments.errors import InstrumentReport
from gyrolab.instruments.multimeter import Agilent34401A, scpi_reports
from gyrolab.instruments.registry import DriverSpec, OpenContext, connected, register
from gyrolab.instruments.roles import ThermometerReading


class Agilent34401AThermometer(Agilent34401A):
    """The 34401A in the thermometer role."""

    name = "multimeter"

    def __init__(self, resource: Any, *, config: MultimeterConfig, **kw: Any) -> None:
        super().__init__(resource, **kw)
        self.config = config
        self.idn = ""
        self._reports: list[InstrumentReport] = []

    def connect(self) -> str:
        self.idn = super().connect()
        return self.idn

    def read(self) -> ThermometerReading:  # type: ignore[override]
        r = super().read()
        # The error queue after every reading: an error the meter raises mid-run (e.g.
        # -310 system error) is logged as a fault and, by its class, stops the run.
        self._reports += scpi_reports(self.errors, "after READ?")
        return ThermometerReading(float(r.resistance_ohm), float(r.temperature_c))

    def reports(self) -> list[InstrumentReport]:
        out, self._reports = self._reports, []
        return out

    def describe(self) -> dict[str, Any]:
        c = self.config
        parts = [p.strip() for p in self.idn.split(",")]
        return {
            "driver": "agilent34401a",
            "model": "34401A",
            "idn": self.idn,
            "resource": self.resource_name,
            "serial": c.serial or (parts[2] if len(parts) > 2 else ""),
            "calibration_due": c.calibration_due,
            "range_ohm": c.range_ohm,
            "nplc": c.nplc,
            "r0_ohm": c.r0_ohm,
        }


_T = TypeVar("_T", bound=Agilent34401AThermometer)


def open_thermometer(cls: type[_T], c: Any, ctx: OpenContext, **extra: Any) -> _T:
    """Open and identify ``cls`` — this driver or a SCPI DMM derived from it — with the
    settings every such config has (``extra``: the model's own, e.g. ``baud_rate``)."""
    return connected(
        cls(
            ctx.address,
            config=c,
            visa_library=ctx.visa_library,
            timeout_s=ctx.timeout(c.timeout_s),
            range_ohm=c.range_ohm,
            nplc=c.nplc,
            r0_ohm=c.r0_ohm,
            **extra,
        )
    )


def open_34401a(c: MultimeterConfig, ctx: OpenContext) -> Agilent34401AThermometer:
    return open_thermometer(Agilent34401AThermometer, c, ctx, baud_rate=c.baud_rate)


SPEC = register(
    DriverSpec(
        name="agilent34401a",
        role="thermometer",
        config=MultimeterConfig,
        open=open_34401a,
        address_key="resource",
        sim_backend="34401A",
        sim_address="dmm_serial_resource",
        description="HP/Agilent 34401A, SCPI over RS-232/LAN/GPIB, 4-wire PT100",
    )
)
