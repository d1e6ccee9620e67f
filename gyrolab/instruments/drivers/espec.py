"""``espec``: an ESPEC P-300 / SCP-220 chamber controller over TCP, as the bench's chamber.

ESPEC's controllers speak an ASCII line protocol of their own (SCPI-like, not SCPI):
commands and replies end in CR LF; queries return comma-separated fields; a setting is
acknowledged ``OK: …``; a refused command is answered ``NA:<reason>``. On a LAN the line
is reached through the chamber's serial-to-Ethernet adapter (a raw TCP socket; ESPEC's own
library defaults to port 10001). Commands used (ESPEC North America ChamberConnectLibrary
``p300.py`` / ``especinteract.py``, ESPEC SH-641 command definitions in ATWG
``espec_sh_def.py``; docs/instruments.md):

    ROM?              firmware version                     (identity)
    TYPE?             <sensor>,<controller>,<max temp>     (identity)
    TEMP?             <PV>,<SP>,<upper limit>,<lower limit>  °C
    TEMP, S<x.x>      set the temperature setpoint (one decimal)
    MODE?             OFF | STANDBY | CONSTANT | RUN
    MODE, CONSTANT    run: control to the constant setpoint
    MODE, STANDBY     stop: heater and refrigerator off, controller on (the safe state
                      ``mode = "standby"``)
    MON?              <PV>,<humidity>,<mode>,<number of active alarms>

Safety: a setpoint outside the bench limits *or* the controller's own range (``TEMP?``
fields 3-4, read at connect) raises :class:`LimitError` before anything is sent; every
setpoint is read back with ``TEMP?``; ``MODE, STANDBY`` is verified with ``MODE?``. An
active alarm (``MON?``) is reported in ``ChamberReading.alarm``: an ESPEC chamber stops
itself on an alarm, and the run engine holds the run or ends it (its suspenders); the next
setpoint after the alarm cleared restarts it (``MODE, CONSTANT``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from gyrolab.instruments.registry import DriverSpec, OpenContext, connected, register
from gyrolab.instruments.roles import (
    ChamberReading,
    InstrumentError,
    InstrumentReport,
    InstrumentTimeout,
)
from gyrolab.instruments.settings import Setting, finite_within, one_of

NAME = "ESPEC"
MODES = ("CONSTANT", "STANDBY")  # the modes gyrolab sets (MODE? also answers OFF, RUN)


def parse_temp(reply: str) -> tuple[float, float, float, float]:
    """A ``TEMP?`` reply: process value, setpoint, upper and lower limit, °C (ValueError
    if it is not four numbers)."""
    f = [p.strip() for p in reply.split(",")]
    if len(f) < 4:
        raise ValueError(f"reply has {len(f)} fields, not 4")
    pv, sp, hi, lo = (float(x) for x in f[:4])
    return pv, sp, hi, lo


@dataclass(frozen=True)
class EspecConfig:
    """``[chamber] driver = "espec"`` (docs/bench-config.md)."""

    driver: str = "espec"
    resource: str = ""  # "TCPIP::192.168.1.30::10001::SOCKET"
    timeout_s: float = 3.0
    period_s: float = 2.0
    serial: str = ""


class EspecChamber:
    """ESPEC P-300/SCP-220 in the chamber role. ``resource``: a VISA resource string or an
    open pyvisa-like resource (tests).

    Settings (:class:`~gyrolab.instruments.settings.Setting`)
        ``setpoint_c``  ``TEMP, S<x.x>`` / ``TEMP?`` field 2 — inside the bench limits and
                        the controller's range (``TEMP?`` fields 3-4, read at connect)
        ``mode``        ``MODE, <mode>`` / ``MODE?`` — CONSTANT or STANDBY
    """

    NAME = NAME
    name = "oven"

    setpoint_c = Setting(
        "TEMP, S{value:.1f}",
        "temperature setpoint, °C (one decimal)",
        get="TEMP?",
        label="setpoint",
        unit="°C",
        validator=finite_within,
        values=lambda d: [
            ("bench limits", d.setpoint_limits_c),
            ("controller range", d.controller_range_c or d.setpoint_limits_c),
        ],
        set_process=lambda d, v: round(float(v), 1),
        get_process=lambda d, reply: d.temp(reply)[1],
    )
    mode = Setting(
        "MODE, {value}",
        "operating mode: CONSTANT (control to the setpoint) or STANDBY (heater and "
        "refrigerator off, controller on); MODE? also answers OFF or RUN",
        get="MODE?",
        validator=one_of,
        values=MODES,
        get_process=lambda d, reply: reply.upper(),
    )

    def __init__(
        self,
        resource: str | Any,
        *,
        config: EspecConfig | None = None,
        visa_library: str = "@py",
        timeout_s: float = 3.0,
        setpoint_limits_c: tuple[float, float] = (-45.0, 70.0),
    ) -> None:
        lo, hi = setpoint_limits_c
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ValueError(f"bad setpoint limits {setpoint_limits_c}")
        self.config = config or EspecConfig()
        self.setpoint_limits_c = (float(lo), float(hi))
        self.controller_range_c: tuple[float, float] | None = None
        self.identity: dict[str, str] = {}
        self._rm: Any = None
        self._out_of_step = False
        if isinstance(resource, str):
            import pyvisa

            self.resource_name = resource
            self._rm = pyvisa.ResourceManager(visa_library)
            try:
                self.inst = self._rm.open_resource(resource)
            except Exception as e:
                self._rm.close()
                raise InstrumentError(NAME, f"cannot open {resource}: {e}") from e
        else:
            self.resource_name = str(getattr(resource, "resource_name", "<resource>"))
            self.inst = resource
        self.inst.timeout = int(timeout_s * 1000)
        self.inst.write_termination = "\r\n"
        self.inst.read_termination = "\n"  # replies end in CR LF; CR is stripped
        self.timeout_s = timeout_s

    # ----------------------------------------------------------------- transport
    def query(self, command: str) -> str:
        """One command, one reply line (stripped); ``NA:`` replies raise."""
        if self._out_of_step:
            self._resync()
        try:
            reply = str(self.inst.query(command)).strip()
        except Exception as e:
            text = f"{type(e).__name__}: {e}"
            if "TMO" in text or "imeout" in text:
                self._out_of_step = True  # a late reply would answer the next command
                raise InstrumentTimeout(NAME, f"no reply to {command!r}") from e
            raise InstrumentError(NAME, f"{command!r} failed: {text}") from e
        if reply.startswith("NA:"):
            raise InstrumentError(NAME, f"{command!r} refused: {reply[3:].strip()}")
        return reply

    def _resync(self) -> None:
        self._out_of_step = False
        for _ in range(4):
            try:
                self.inst.read()
            except Exception:
                return

    def write(self, command: str) -> None:
        """One setting command, acknowledged ``OK…`` (else :class:`InstrumentError`)."""
        reply = self.query(command)
        if not reply.startswith("OK"):
            self._out_of_step = True
            raise InstrumentError(NAME, f"{command!r}: unexpected reply {reply!r}")

    def _fields(self, command: str, n: int) -> list[str]:
        parts = [p.strip() for p in self.query(command).split(",")]
        if len(parts) < n:
            self._out_of_step = True
            raise InstrumentError(NAME, f"{command!r}: reply has {len(parts)} fields, not {n}")
        return parts

    # ------------------------------------------------------------------ readings
    def temp(self, reply: str | None = None) -> tuple[float, float, float, float]:
        """``TEMP?`` (or its ``reply``): process value, setpoint, upper and lower limit, °C."""
        reply = self.query("TEMP?") if reply is None else reply
        try:
            return parse_temp(reply)
        except ValueError as e:
            self._out_of_step = True
            raise InstrumentError(NAME, f"TEMP? reply {reply!r}: {e}") from None

    def alarms(self) -> int:
        """``MON?`` field 4: the number of active alarms."""
        f = self._fields("MON?", 4)
        try:
            return int(f[3])
        except ValueError:
            raise InstrumentError(NAME, f"MON? reply {','.join(f)!r}") from None

    def read(self) -> ChamberReading:
        pv, sp, _, _ = self.temp()
        n = self.alarms()
        alarm = f"ESPEC controller reports {n} active alarm(s) (MON?)" if n else ""
        return ChamberReading(sp, pv, alarm)

    # ------------------------------------------------------------------ settings
    def set_setpoint(self, value_c: float) -> float:
        """``TEMP, S<x>`` (limits first), control on (``MODE, CONSTANT``), then read back
        with ``TEMP?``."""
        want = type(self).setpoint_c.write(self, value_c)
        if self.mode != "CONSTANT":
            self.mode = "CONSTANT"
        sp = self.setpoint_c
        if abs(sp - want) > 0.05:
            raise InstrumentError(NAME, f"setpoint read-back {sp} != written {want}")
        return sp

    def standby(self) -> str:
        """``MODE, STANDBY`` (temperature control stopped), verified with ``MODE?``."""
        self.mode = "STANDBY"
        m = self.mode
        if m != "STANDBY":
            raise InstrumentError(NAME, f"mode read-back {m!r} after MODE, STANDBY")
        return m

    def switch_off(self) -> None:
        """The safe state ``mode = "off"``: STANDBY, verified."""
        self.standby()

    # ------------------------------------------------------------------ role
    def connect(self) -> dict[str, Any]:
        self.identity = {"rom": self.query("ROM?"), "type": self.query("TYPE?")}
        _, _, hi, lo = self.temp()
        self.controller_range_c = (lo, hi)
        return {**self.identity, "range_c": [lo, hi], "mode": self.mode}

    def reports(self) -> list[InstrumentReport]:
        return []  # refusals (NA:) are raised with the command they answered

    def describe(self) -> dict[str, Any]:
        return {
            "driver": self.config.driver,
            "model": "ESPEC P-300/SCP-220 (TCP)",
            "resource": self.resource_name,
            "serial": self.config.serial,
            **self.identity,
            "controller_range_c": list(self.controller_range_c or ()),
        }

    def close(self) -> None:
        try:
            self.inst.close()
        finally:
            if self._rm is not None:
                self._rm.close()
                self._rm = None


def open_espec(c: EspecConfig, ctx: OpenContext) -> EspecChamber:
    return connected(
        EspecChamber(
            ctx.address,
            config=c,
            visa_library=ctx.visa_library,
            timeout_s=ctx.timeout(c.timeout_s),
            setpoint_limits_c=ctx.setpoint_limits_c,
        )
    )


SPEC = register(
    DriverSpec(
        name="espec",
        role="chamber",
        config=EspecConfig,
        open=open_espec,
        address_key="resource",
        sim_backend="P300",
        sim_address="chamber_tcp_resource",
        description="ESPEC P-300/SCP-220 controller, ASCII commands over TCP",
    )
)
