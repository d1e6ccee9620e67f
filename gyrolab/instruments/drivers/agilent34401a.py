"""``agilent34401a``: the HP / Agilent / Keysight 34401A 6½-digit multimeter as the bench's
thermometer (4-wire resistance of the PT100).

Talks SCPI over pyvisa (the pure-Python ``@py`` backend by default; NI-VISA works too).
Resources:

- RS-232: ``ASRL/dev/ttyUSB0::INSTR`` (or ``ASRL1::INSTR``): 9600 baud, 8 data bits, no
  parity, 2 stop bits, DTR/DSR handshake; ``SYST:REM`` is sent first because over RS-232
  the meter otherwise stays under front-panel control.
- LAN through a GPIB/serial-to-LAN gateway or a SCPI socket: ``TCPIP::host::5025::SOCKET``.
- GPIB: ``GPIB0::22::INSTR``.

Measurement: ``CONF:FRES 1000`` (the 100 Ω range overloads at 120 Ω, below a PT100 at
60 °C = 123.24 Ω; the 1 kΩ range covers −200…+850 °C), ``FRES:NPLC 10`` (integration over
10 power-line cycles rejects mains pickup), then ``READ?`` per reading. ``SYST:ERR?`` is
drained after configuration and any error raises. Readings come back in ohms and in °C
through the IEC 60751 inverse (:func:`gyrolab.pt100.cvd_temperature`).

:class:`Agilent34401A` is the SCPI driver; :class:`Agilent34401AThermometer` fills the
:class:`~gyrolab.instruments.roles.Thermometer` role with it (the error queue read after
every reading, the identity); :func:`open_thermometer` is the one constructor call of the
SCPI DMM family (the 34465A driver opens through it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, TypeVar

from gyrolab.instruments.registry import DriverSpec, OpenContext, connected, register
from gyrolab.instruments.roles import (
    InstrumentError,
    InstrumentReport,
    InstrumentTimeout,
    ThermometerReading,
)
from gyrolab.instruments.scpi import parse_error_reply, scpi_reports
from gyrolab.instruments.settings import Setting, Settings, one_of
from gyrolab.pt100 import R0_OHM, cvd_temperature

NAME = "34401A"


@dataclass(frozen=True)
class Agilent34401AConfig:
    """``[thermometer] driver = "agilent34401a"`` (docs/bench-config.md)."""

    driver: str = "agilent34401a"
    resource: str = ""  # "ASRL/dev/ttyUSB0::INSTR" or "TCPIP::host::5025::SOCKET"
    timeout_s: float = 5.0
    nplc: float = 10.0
    range_ohm: float = 1000.0  # 100 Ω range overflows above ~0 °C for a PT100 at 60 °C
    baud_rate: int = 9600  # RS-232 only
    period_s: float = 1.0  # one reading per period
    r0_ohm: float = 100.0  # the PT100's R at 0 °C (calibration)
    serial: str = ""  # asset serial, if *IDN? does not give it
    calibration_due: str = ""


class Agilent34401A(Settings):
    """34401A driver (PyMeasure style: settings declared below, readings one SCPI line each).

    Settings (:class:`~gyrolab.instruments.settings.Setting`: checked when the driver is
    created, sent by :meth:`configure`)
        ``range_ohm``   ``CONF:FRES <range>``  — 100, 1e3, 10e3, 100e3, 1e6, 10e6, 100e6 Ω
        ``nplc``        ``FRES:NPLC <n>``      — 0.02, 0.2, 1, 10, 100 power-line cycles
    Readings
        ``identity``    ``*IDN?``              — "HEWLETT-PACKARD,34401A,0,11-5-2"
        ``resistance``  ``READ?``              — Ω (overload, 9.9E+37, raises)
        ``errors``      ``SYST:ERR?`` repeated — [(code, message)] until ``+0,"No error"``

    ``resource`` is a VISA resource string or an already open pyvisa resource (tests);
    ``visa_library`` a pyvisa ResourceManager argument (``"@py"``, ``"file.yaml@sim"``)
    or a ResourceManager. ``timeout_s`` bounds every I/O; it must exceed the integration
    time (NPLC 10 at 50 Hz = 0.2 s, ×2 for 4-wire autozero).
    """

    NAME = NAME  # in error messages (a subclass for another model names itself)
    MODEL_MARK = "34401"  # what *IDN? must contain
    RANGES_OHM = (100.0, 1e3, 10e3, 100e3, 1e6, 10e6, 100e6)
    NPLC_VALUES = (0.02, 0.2, 1.0, 10.0, 100.0)
    OVERLOAD = 9.0e37  # the meter returns +9.90000000E+37 on overload
    # RS-232 line (pyvisa constants.StopBits / ControlFlow names): the 34401A's 2 stop
    # bits and DTR/DSR handshake; a SCPI instrument derived from it may differ.
    SERIAL_STOP_BITS = "two"
    SERIAL_FLOW_CONTROL = "dtr_dsr"

    range_ohm = Setting(
        "CONF:FRES {value:g}",
        "4-wire resistance range, Ω (the 1 kΩ range covers a PT100 from -200 to +850 °C)",
        label="range",
        unit="Ω",
        validator=one_of,
        values="RANGES_OHM",
        cast=float,
    )
    nplc = Setting(
        "FRES:NPLC {value:g}",
        "integration time in power-line cycles (10 rejects mains pickup)",
        label="NPLC",
        validator=one_of,
        values="NPLC_VALUES",
        cast=float,
    )

    def __init__(
        self,
        resource: str | Any,
        *,
        visa_library: str | Any = "@py",
        timeout_s: float = 5.0,
        range_ohm: float = 1000.0,
        nplc: float = 10.0,
        r0_ohm: float = R0_OHM,
        baud_rate: int = 9600,
    ) -> None:
        self.hold("range_ohm", range_ohm)  # LimitError before anything is opened or sent
        self.hold("nplc", nplc)
        self.r0_ohm = r0_ohm
        self.timeout_s = timeout_s
        self._rm = None
        self._out_of_step = False
        self.late_replies = 0  # replies discarded after a timeout (see query)
        if isinstance(resource, str):
            import pyvisa

            self.resource_name = resource
            if isinstance(visa_library, pyvisa.ResourceManager):
                rm = visa_library
            else:
                rm = self._rm = pyvisa.ResourceManager(visa_library)
            try:
                self.inst = rm.open_resource(resource)
            except Exception as e:  # pyvisa raises VisaIOError, OSError, ValueError …
                raise InstrumentError(self.NAME, f"cannot open {resource}: {e}") from e
        else:
            self.resource_name = str(getattr(resource, "resource_name", "<resource>"))
            self.inst = resource
        self.is_serial = self.resource_name.upper().startswith("ASRL")
        self.inst.timeout = int(timeout_s * 1000)  # pyvisa timeouts are in ms
        self.inst.write_termination = "\n"
        self.inst.read_termination = "\n"  # RS-232 replies end in CR LF; CR is stripped
        if self.is_serial:
            self._setup_serial(baud_rate)

    def _setup_serial(self, baud_rate: int) -> None:
        try:
            from pyvisa import constants

            self.inst.baud_rate = baud_rate
            self.inst.data_bits = 8
            self.inst.parity = constants.Parity.none
            self.inst.stop_bits = getattr(constants.StopBits, self.SERIAL_STOP_BITS)
            # The 34401A holds off on DSR; pyvisa-py maps this to pyserial's dsrdtr.
            self.inst.flow_control = getattr(constants.ControlFlow, self.SERIAL_FLOW_CONTROL)
        except (AttributeError, ImportError):  # a protocol-test stand-in has no such attributes
            pass

    # ------------------------------------------------------------------ low level
    def write(self, command: str) -> None:
        """Send one SCPI command line."""
        try:
            self.inst.write(command)
        except Exception as e:
            raise self._wrap(e, command) from e

    def query(self, command: str) -> str:
        """Send ``command`` and return the reply line, stripped.

        After a query that timed out (or got a reply of the wrong shape) the meter's late
        reply may still be on its way and would be taken as the answer to the next query
        (a stale ``READ?``, or a ``READ?`` value read as a ``SYST:ERR?`` entry, forever
        out of step): the next query first waits that out (:meth:`_resync`)."""
        if self._out_of_step:
            self._resync()
        try:
            return str(self.inst.query(command)).strip()
        except Exception as e:
            err = self._wrap(e, command)
            if isinstance(err, InstrumentTimeout):
                self._out_of_step = True
            raise err from e

    def _resync(self) -> None:
        """Read and discard until one read times out: the line is quiet, in step again."""
        self._out_of_step = False
        for _ in range(4):  # a late reply is one line; more means a noisy line
            try:
                self.inst.read()
            except Exception:
                return
            self.late_replies += 1

    def _wrap(self, e: Exception, command: str) -> InstrumentError:
        text = f"{type(e).__name__}: {e}"
        if "TMO" in text or "imeout" in text:
            msg = f"no reply to {command!r} within {self.timeout_s} s"
            return InstrumentTimeout(self.NAME, msg)
        return InstrumentError(self.NAME, f"{command!r} failed: {text}")

    # ------------------------------------------------------------------ readings
    @property
    def identity(self) -> str:
        """``*IDN?``: manufacturer, model, serial, firmware."""
        return self.query("*IDN?")

    @property
    def errors(self) -> list[tuple[int, str]]:
        """Drain the error queue (``SYST:ERR?`` until code 0); at most 20 entries."""
        out: list[tuple[int, str]] = []
        for _ in range(20):  # the 34401A queue holds 20 errors
            reply = self.query("SYST:ERR?")
            entry = parse_error_reply(reply)
            if entry is None:
                self._out_of_step = True  # someone else's reply: wait for quiet first
                raise InstrumentError(self.NAME, f"unparsable SYST:ERR? reply {reply!r}")
            if entry[0] == 0:
                break
            out.append(entry)
        return out

    def check_errors(self) -> None:
        """Raise :class:`InstrumentError` listing the error queue if it is not empty."""
        errs = self.errors
        if errs:
            listed = "; ".join(f"{c},{m}" for c, m in errs)
            raise InstrumentError(self.NAME, f"error queue: {listed}")

    @property
    def resistance(self) -> float:
        """``READ?``: one triggered 4-wire resistance reading, Ω."""
        reply = self.query("READ?")
        try:
            value = float(reply)
        except ValueError:
            self._out_of_step = True  # someone else's reply: wait for quiet first
            raise InstrumentError(self.NAME, f"READ? returned {reply!r}") from None
        if not math.isfinite(value) or abs(value) >= self.OVERLOAD:
            raise InstrumentError(
                self.NAME, f"overload on the {self.range_ohm:g} Ω range (reading {reply})"
            )
        return value

    def read(self) -> ThermometerReading:
        """One reading in Ω and °C."""
        r = self.resistance
        return ThermometerReading(r, float(cvd_temperature(r, self.r0_ohm)))

    # ------------------------------------------------------------------ settings
    def reset(self) -> None:
        """``*RST`` then ``*CLS`` (clears the error queue)."""
        self.write("*RST")
        self.write("*CLS")

    def configure(self, range_ohm: float | None = None, nplc: float | None = None) -> None:
        """``CONF:FRES <range>`` and ``FRES:NPLC <n>`` (new values checked before either is
        sent), then check the error queue."""
        for name, value in (("range_ohm", range_ohm), ("nplc", nplc)):
            if value is not None:
                self.hold(name, value)
        self.send("range_ohm", "nplc")
        self.check_errors()

    def connect(self) -> str:
        """Bring the meter to a known state: remote (RS-232), reset, identify, configure.
        Returns the ``*IDN?`` string."""
        if self.is_serial:
            self.write("SYST:REM")
        self.reset()
        idn = self.identity
        if self.MODEL_MARK not in idn:
            raise InstrumentError(self.NAME, f"unexpected instrument {idn!r}")
        self.configure()
        return idn

    def close(self) -> None:
        """Return the meter to local (RS-232) and close the resource."""
        try:
            if self.is_serial:
                self.write("SYST:LOC")
        except InstrumentError:
            pass
        try:
            self.inst.close()
        finally:
            if self._rm is not None:
                self._rm.close()
                self._rm = None

    def __enter__(self) -> Agilent34401A:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Agilent34401AThermometer(Agilent34401A):
    """The 34401A in the thermometer role."""

    name = "multimeter"

    def __init__(self, resource: Any, *, config: Any, **kw: Any) -> None:
        super().__init__(resource, **kw)
        self.config = config
        self.idn = ""
        self._reports: list[InstrumentReport] = []

    def connect(self) -> str:
        self.idn = super().connect()
        return self.idn

    def read(self) -> ThermometerReading:
        r = super().read()
        # The error queue after every reading: an error the meter raises mid-run (e.g.
        # -310 system error) is logged as a fault and, by its class, stops the run.
        self._reports += scpi_reports(self.errors, "after READ?")
        return r

    def reports(self) -> list[InstrumentReport]:
        out, self._reports = self._reports, []
        return out

    def describe(self) -> dict[str, Any]:
        """Identity (from ``*IDN?``: model and serial) and settings."""
        c = self.config
        parts = [p.strip() for p in self.idn.split(",")]
        return {
            "driver": c.driver,
            "model": parts[1] if len(parts) > 1 and parts[1] else self.NAME,
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


def open_34401a(c: Agilent34401AConfig, ctx: OpenContext) -> Agilent34401AThermometer:
    return open_thermometer(Agilent34401AThermometer, c, ctx, baud_rate=c.baud_rate)


SPEC = register(
    DriverSpec(
        name="agilent34401a",
        role="thermometer",
        config=Agilent34401AConfig,
        open=open_34401a,
        address_key="resource",
        sim_backend="34401A",
        sim_address="dmm_serial_resource",
        description="HP/Agilent 34401A, SCPI over RS-232/LAN/GPIB, 4-wire PT100",
    )
)
