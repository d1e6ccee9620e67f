"""``keysight34970a``: a Keysight/Agilent 34970A, 34972A or DAQ970A data-acquisition/switch
unit with a 20-channel multiplexer (34901A, DAQM901A) as a multi-unit bench's
:class:`~gyrolab.instruments.roles.MultiThermometer`: one 4-wire PT100 per unit.

4-wire wiring: the instrument pairs channel *n* (source, HI/LO) with channel *n*+10
(sense) on the 34901A/DAQM901A, *n*+8 on the 16-channel 34902A/DAQM902A; so a 34901A
reads up to ten PT100s, on channels 1…10 of its slot (``101``…``110`` in slot 1). Keysight
34970A/34972A User's Guide, ch. 7 "Four-Wire Multiplexers"; DAQ970A User's Guide, ch. 4
(docs/instruments.md). SCPI used (34970A/34972A User's Guide ch. 5, DAQ970A Programming
Guide; the scan list is the ``(@…)`` channel list):

    *RST; *CLS; *IDN?              reset, clear, "Agilent Technologies,34970A,<serial>,<fw>"
    CONF:FRES <range>,(@<list>)    4-wire ohms on the channels; (re)defines the scan list
    FRES:NPLC <n>,(@<list>)        integration: 0.02, 0.2, 1, 2, 10, 20, 100, 200 PLC
    ROUT:SCAN (@<list>)            the scan list, stated explicitly (CONF already set it)
    ROUT:SCAN:SIZE?                channels in the scan list (checked after configuring)
    READ?                          one sweep: one reading per channel, comma separated, in
                                   scan-list order; +9.9E+37 where a channel overloads
    SYST:ERR?                      +0,"No error" | <code>,"<text>"  (SCPI error classes)

The transport (pyvisa, late-reply resynchronisation, error queue, SCPI error classes) is
the 34401A driver's (:class:`gyrolab.instruments.drivers.agilent34401a.Agilent34401A`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from gyrolab.instruments.drivers.agilent34401a import (
    Agilent34401A,
    Agilent34401AThermometer,
    open_thermometer,
)
from gyrolab.instruments.registry import DriverSpec, OpenContext, register
from gyrolab.instruments.roles import InstrumentError, LimitError, ThermometerReading
from gyrolab.instruments.scpi import scpi_reports
from gyrolab.instruments.settings import Setting
from gyrolab.pt100 import cvd_temperature

# Multiplexer card → the offset of the sense channel paired with a 4-wire channel n
# (User's Guides above): channels 1..offset of a slot can read a 4-wire sensor.
FOUR_WIRE_PAIR_OFFSET = {"34901A": 10, "DAQM901A": 10, "34902A": 8, "DAQM902A": 8}
MODELS = ("34970A", "34972A", "DAQ970A")


@dataclass(frozen=True)
class Keysight34970AConfig:
    """``[scanner] driver = "keysight34970a"`` (docs/bench-config.md). ``channels`` is not a
    BENCH.toml key: the bench loader fills it from the units' ``temperature_channel``."""

    driver: str = "keysight34970a"
    resource: str = ""  # "TCPIP::192.168.1.40::5025::SOCKET" (34972A/DAQ970A LAN), GPIB, ASRL
    timeout_s: float = 10.0  # a sweep of 10 channels at NPLC 10 takes about 5 s
    nplc: float = 1.0
    range_ohm: float = 1000.0  # a PT100 at 60 °C is 123 Ω: the 100 Ω range overloads
    card: str = "34901A"  # the multiplexer in the scanned slots (FOUR_WIRE_PAIR_OFFSET)
    baud_rate: int = 57600  # RS-232 only (34970A); set to the instrument's front-panel value
    period_s: float = 2.0  # one sweep per period
    r0_ohm: float = 100.0
    serial: str = ""
    calibration_due: str = ""
    channels: tuple[int, ...] = ()


def channel_list(channels: tuple[int, ...] | list[int]) -> str:
    """SCPI channel list: runs of consecutive channels as ``first:last``:
    ``(101, 102, 103, 105)`` → ``(@101:103,105)``."""
    parts: list[str] = []
    run: list[int] = []
    for ch in channels:
        if run and ch == run[-1] + 1:
            run.append(ch)
            continue
        if run:
            parts.append(f"{run[0]}:{run[-1]}" if len(run) > 1 else str(run[0]))
        run = [ch]
    if run:
        parts.append(f"{run[0]}:{run[-1]}" if len(run) > 1 else str(run[0]))
    return "(@" + ",".join(parts) + ")"


def four_wire_channels(channels: tuple[int, ...], card: str) -> tuple[int, ...]:
    """``channels`` if every one is a 4-wire source channel of ``card`` in slot 1-3
    (1xx/2xx/3xx), each once (a settings validator: ``ValueError`` otherwise)."""
    off = FOUR_WIRE_PAIR_OFFSET.get(card)
    if off is None:
        raise ValueError(f"need a card of {sorted(FOUR_WIRE_PAIR_OFFSET)}, not card {card!r}")
    if not channels:
        raise ValueError("are no channels to scan")
    if len(set(channels)) != len(channels):
        raise ValueError("name a channel twice")
    for ch in channels:
        slot, n = divmod(int(ch), 100)
        if not (1 <= slot <= 3 and 1 <= n <= off):
            raise ValueError(
                f"hold channel {ch}: 4-wire channels of a {card} are s01..s{off:02d} in slot "
                f"s=1..3 (channel n is paired with its sense channel n+{off})"
            )
    return channels


class Keysight34970A(Agilent34401AThermometer):
    """The scanner in the multi-thermometer role (see module doc); the 34401A thermometer's
    transport, error reports and identity, with a scan list."""

    NAME = "34970A"
    MODEL_MARK = "34970A"
    NPLC_VALUES = (0.02, 0.2, 1.0, 2.0, 10.0, 20.0, 100.0, 200.0)
    # RS-232: the baud rate chosen on its front panel, 8 data bits, no parity, 1 stop bit,
    # XON/XOFF flow control (its factory setting; User's Guide ch. 4).
    SERIAL_STOP_BITS = "one"
    SERIAL_FLOW_CONTROL = "xon_xoff"
    name = "scanner"

    # the meter's settings, on the scan list's channels
    range_ohm = Agilent34401A.range_ohm.with_command("CONF:FRES {value:g},{drv.scan_list}")
    nplc = Agilent34401A.nplc.with_command("FRES:NPLC {value:g},{drv.scan_list}")
    channels = Setting(
        "ROUT:SCAN {value}",
        "the 4-wire channels one READ? sweeps, in order (docs/instruments.md)",
        validator=four_wire_channels,
        values=lambda d: d.card,
        cast=tuple,
        set_process=lambda d, chans: channel_list(chans),
    )

    def __init__(self, resource: Any, *, config: Keysight34970AConfig, **kw: Any) -> None:
        self.card = config.card
        self.hold("channels", tuple(int(c) for c in config.channels))  # before any I/O
        kw.setdefault("range_ohm", config.range_ohm)
        kw.setdefault("nplc", config.nplc)
        kw.setdefault("r0_ohm", config.r0_ohm)
        super().__init__(resource, config=config, **kw)

    @property
    def scan_list(self) -> str:
        """The channels as a SCPI channel list, ``(@101:103)``."""
        return channel_list(self.channels)

    def configure(self, range_ohm: float | None = None, nplc: float | None = None) -> None:
        """``CONF:FRES``, ``FRES:NPLC`` and ``ROUT:SCAN`` on the channel list, then the scan
        list's size read back and the error queue checked."""
        if range_ohm is not None or nplc is not None:
            raise LimitError(self.NAME, "range and NPLC are set when the driver is created")
        chans = self.scan_list
        self.send("range_ohm", "nplc", "channels")
        size = self.query("ROUT:SCAN:SIZE?")
        try:
            n = int(float(size))
        except ValueError:
            raise InstrumentError(self.NAME, f"ROUT:SCAN:SIZE? returned {size!r}") from None
        if n != len(self.channels):
            raise InstrumentError(
                self.NAME, f"scan list holds {n} channels, not {len(self.channels)} ({chans})"
            )
        self.check_errors()

    def connect(self) -> str:
        """Remote (RS-232), reset, identify (34970A, 34972A or DAQ970A), configure the scan."""
        if self.is_serial:
            self.write("SYST:REM")
        self.reset()
        idn = self.identity
        if not any(m in idn for m in MODELS):
            raise InstrumentError(self.NAME, f"unexpected instrument {idn!r}")
        self.configure()
        self.idn = idn
        return idn

    def read(self) -> dict[int, ThermometerReading]:  # type: ignore[override]
        """One sweep (``READ?``): Ω and °C per channel; NaN for an overloaded channel (an
        open or unplugged sensor: that unit's reading is lost, not the others')."""
        reply = self.query("READ?")
        try:
            values = [float(v) for v in reply.split(",")]
        except ValueError:
            self._out_of_step = True  # someone else's reply: wait for quiet first
            raise InstrumentError(self.NAME, f"READ? returned {reply!r}") from None
        if len(values) != len(self.channels):
            self._out_of_step = True
            raise InstrumentError(
                self.NAME,
                f"READ? returned {len(values)} readings for {len(self.channels)} channels",
            )
        # The error queue after every sweep, as the single-channel meters do.
        self._reports += scpi_reports(self.errors, "after READ?")
        out: dict[int, ThermometerReading] = {}
        for ch, r in zip(self.channels, values, strict=True):
            if not math.isfinite(r) or abs(r) >= self.OVERLOAD:
                out[ch] = ThermometerReading(math.nan, math.nan)
            else:
                out[ch] = ThermometerReading(r, float(cvd_temperature(r, self.r0_ohm)))
        return out

    def describe(self) -> dict[str, Any]:
        d = super().describe()
        parts = [p.strip() for p in self.idn.split(",")]
        d.update(
            driver="keysight34970a",
            model=parts[1] if len(parts) > 1 else "34970A",
            card=self.config.card,
            channels=list(self.channels),
        )
        return d


def open_34970a(c: Keysight34970AConfig, ctx: OpenContext) -> Keysight34970A:
    return open_thermometer(Keysight34970A, c, ctx, baud_rate=c.baud_rate)


SPEC = register(
    DriverSpec(
        name="keysight34970a",
        role="multi_thermometer",
        config=Keysight34970AConfig,
        open=open_34970a,
        address_key="resource",
        sim_backend="34970A",
        sim_address="scanner_tcp_resource",
        description="Keysight 34970A/34972A/DAQ970A with a 34901A multiplexer, one 4-wire "
        "PT100 per unit",
    )
)
