"""``keysight34465a``: Keysight 34465A (Truevolt 6½ digits) as the bench's thermometer.

4-wire PT100 on the 1 kΩ range with **offset compensation** (the meter measures with the
current source on and off and subtracts: thermal EMFs of the leads and terminals cancel),
over LAN (``TCPIP::host::5025::SOCKET`` or ``TCPIP::host::inst0::INSTR``) or USB. The
34465A has no RS-232 port. SCPI (Keysight Truevolt Series DMM Operating and Service Guide /
Command Quick Reference; docs/instruments.md):

    *RST; *CLS; *IDN?               reset, clear, "Keysight Technologies,34465A,<serial>,<fw>"
    CONF:FRES <range>               4-wire ohms, 100 Ω … 100 MΩ (1 GΩ) ranges
    FRES:NPLC <n>                   0.02, 0.06, 0.2, 1, 10, 100 (0.001…0.006 with DIG option)
    FRES:OCOM ON|OFF                offset compensation, 100 Ω … 100 kΩ ranges
    READ?                           one reading, Ω; +9.9E+37 on overload
    SYST:ERR?                       +0,"No error" | <code>,"<text>"  (SCPI error classes)

The transport, late-reply resynchronisation and error-queue handling are the 34401A
driver's (:class:`~gyrolab.instruments.drivers.agilent34401a.Agilent34401A`): same SCPI subset,
same reply formats.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from gyrolab.instruments.drivers.agilent34401a import Agilent34401AThermometer, open_thermometer
from gyrolab.instruments.registry import DriverSpec, OpenContext, register
from gyrolab.instruments.roles import LimitError
from gyrolab.instruments.settings import Setting

OCOMP_MAX_RANGE_OHM = 100e3


def offset_compensable(on: bool, range_ohm: float) -> bool:
    """``on`` unless offset compensation is asked for on a range it does not support."""
    if on and range_ohm > OCOMP_MAX_RANGE_OHM:
        raise ValueError(f"needs a range <= 100 kΩ, not {range_ohm:g}")
    return on


@dataclass(frozen=True)
class Keysight34465AConfig:
    """``[thermometer] driver = "keysight34465a"`` (docs/bench-config.md)."""

    driver: str = "keysight34465a"
    resource: str = ""  # "TCPIP::192.168.1.21::5025::SOCKET"
    timeout_s: float = 5.0
    nplc: float = 10.0
    range_ohm: float = 1000.0
    offset_compensation: bool = True
    period_s: float = 1.0
    r0_ohm: float = 100.0
    serial: str = ""  # asset serial, if *IDN? does not give it
    calibration_due: str = ""


class Keysight34465A(Agilent34401AThermometer):
    """The 34465A in the thermometer role (see module doc)."""

    NAME = "34465A"
    MODEL_MARK = "34465A"
    NPLC_VALUES = (0.02, 0.06, 0.2, 1.0, 10.0, 100.0)

    offset_compensation = Setting(
        "FRES:OCOM {value}",
        "offset compensation (current source on and off, thermal EMFs cancel), 100 Ω … "
        "100 kΩ ranges",
        validator=offset_compensable,
        values=lambda d: d.range_ohm,
        cast=bool,
        set_process=lambda d, on: "ON" if on else "OFF",
    )

    def __init__(self, resource: Any, *, config: Any, **kw: Any) -> None:
        super().__init__(resource, config=config, **kw)
        self.hold("offset_compensation", bool(getattr(config, "offset_compensation", True)))

    def configure(self, range_ohm: float | None = None, nplc: float | None = None) -> None:
        """``CONF:FRES``, ``FRES:NPLC``, ``FRES:OCOM``, then the error queue."""
        if range_ohm is not None or nplc is not None:
            raise LimitError(self.NAME, "range and NPLC are set when the driver is created")
        self.send("range_ohm", "nplc", "offset_compensation")
        self.check_errors()

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "offset_compensation": self.offset_compensation}


def open_34465a(c: Keysight34465AConfig, ctx: OpenContext) -> Keysight34465A:
    return open_thermometer(Keysight34465A, c, ctx)


SPEC = register(
    DriverSpec(
        name="keysight34465a",
        role="thermometer",
        config=Keysight34465AConfig,
        open=open_34465a,
        address_key="resource",
        sim_backend="34465A",
        sim_address="dmm_tcp_resource",
        description="Keysight 34465A, SCPI over LAN/USB, 4-wire PT100 with offset compensation",
    )
)
