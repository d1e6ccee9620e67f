"""``watlowf4``: the Watlow F4 temperature chamber controller over Modbus RTU, as the
bench's chamber.

minimalmodbus (on pyserial) is used rather than pymodbus: the oven is one slave on one
RS-232/RS-485 line polled a few times a second, and minimalmodbus is small, synchronous
and blocking, which is exactly that; pymodbus's asyncio client/server machinery buys
nothing here and is more to audit (docs/instruments.md).

Register map (holding registers, function 03 to read, 06 to write; 16-bit signed values
with implied decimals: raw = round(value · 10**decimals)). The map of ESPEC's
ChamberConnectLibrary ``watlowf4.py``, the code ESPEC drives its F4 chambers with
(docs/instruments.md says what was and was not checked against Watlow's manual):

    100        process value, input 1 (chamber air)      read        °C or °F per 901
    103, 107   output 1A (heat) / 1B (cool) power, 0.01 %  read
    200        profile mode: 0/1 constant (no profile), 2 running, 3 paused   read
    300        static setpoint, loop 1                    read/write  °C or °F per 901
    606        decimal places, input 1                    read
    901        temperature units (0 = °F, 1 = °C)         read
    1209/1210/1217  profile resume / pause / terminate    write 1
    2000 + 10(N-1)  event output N (1..8): 0 off, 1 on    read/write
    201 + 12(N-1)   digital input N (1..4): its state      read
    1061 + 2(N-1)   digital input N: its active condition  read

A chamber's limit controller (its over/under-temperature cut-out, a door switch) is wired
to one of the F4's digital inputs (``[chamber] alarm_input``): the chamber is in alarm
while that input's state equals its active condition — the test ESPEC's library makes
(``get_alarm_status``), reported in ``ChamberReading.alarm``.

Safety: a setpoint outside ``setpoint_limits_c`` (or not finite, or beyond int16 after
scaling) raises :class:`LimitError` before a single byte is written. Every setpoint write
is read back and compared. Transport errors (no reply, CRC error, exception response)
are retried ``retries`` times, then raised as :class:`InstrumentError` /
:class:`InstrumentTimeout`.

Late replies. An RTU reply carries no transaction id (a function-03 reply does not even
name the register), so a reply that arrives after the driver gave up on it would be taken
as the answer to the next request — the next read returns another register's value. So
after a transaction that ended without a whole reply (no reply, or a partial one: the
read timed out) the driver reads and discards until the line has been quiet for
``silence_s`` (default ``timeout_s``) before it sends anything again. After a whole but
bad reply (CRC error, malformed) the slave has finished answering, so only trailing bytes
are waited out (quiet for 3.5 character times, at least 20 ms for USB adapters' latency).
The input buffer is also cleared before every request. A reply later than ``timeout_s +
silence_s`` cannot be told apart from the answer to the next request on any RTU master;
raise ``silence_s`` for such a slave.

:class:`WatlowF4` is the Modbus driver; :class:`WatlowF4Chamber` fills the
:class:`~gyrolab.instruments.roles.Chamber` role with it.
"""

from __future__ import annotations

import math
import re
import time
from dataclasses import dataclass, field
from typing import Any

import minimalmodbus
import serial

from gyrolab.instruments.registry import DriverSpec, OpenContext, connected, register
from gyrolab.instruments.roles import (
    ChamberReading,
    InstrumentError,
    InstrumentFault,
    InstrumentReport,
    InstrumentTimeout,
    LimitError,
)
from gyrolab.instruments.settings import Setting, finite_within

NAME = "WatlowF4"

REG_PROCESS_VALUE = 100
REG_HEAT_POWER = 103  # output 1A, 0.01 %
REG_COOL_POWER = 107  # output 1B, 0.01 %
REG_PROFILE_MODE = 200  # 0/1 constant, 2 profile running, 3 profile paused
REG_SETPOINT = 300
REG_PROFILE_RESUME, REG_PROFILE_PAUSE, REG_PROFILE_TERMINATE = 1209, 1210, 1217
PROFILE_RUNNING, PROFILE_PAUSED = 2, 3
REG_DECIMALS = 606
# Digital input N (1..4): its state, and the condition (level) at which it is active.
REG_DIGITAL_INPUT, REG_DIGITAL_INPUT_STEP = 201, 12
REG_DIGITAL_CONDITION, REG_DIGITAL_CONDITION_STEP = 1061, 2
REG_UNITS = 901
UNITS_F, UNITS_C = 0, 1

# Modbus exception codes (Modbus Application Protocol Specification V1.1b3, §7) and the
# message minimalmodbus (2.x) raises for each, to recover the code from the exception.
MODBUS_EXCEPTIONS = {
    1: ("ILLEGAL FUNCTION", "illegal function"),
    2: ("ILLEGAL DATA ADDRESS", "illegal data address"),
    3: ("ILLEGAL DATA VALUE", "illegal data value"),
    4: ("SERVER DEVICE FAILURE", "device failure"),
    5: ("ACKNOWLEDGE", "acknowledge"),
    6: ("SERVER DEVICE BUSY", "device busy"),
    7: ("NEGATIVE ACKNOWLEDGE", "negative acknowledge"),
    8: ("MEMORY PARITY ERROR", "memory parity error"),
    10: ("GATEWAY PATH UNAVAILABLE", "gateway path unavailable"),
    11: ("GATEWAY TARGET DEVICE FAILED TO RESPOND", "gateway target device failed"),
}


def modbus_exception_code(e: Exception) -> int | None:
    """The exception code of a minimalmodbus ``SlaveReportedException`` (None: unknown)."""
    msg = str(e).lower()
    m = re.search(r"error code (\d+)", msg)
    if m:
        return int(m.group(1))
    # Longest phrase first: "negative acknowledge" also contains "acknowledge".
    for code, (_, phrase) in sorted(MODBUS_EXCEPTIONS.items(), key=lambda kv: -len(kv[1][1])):
        if phrase in msg:
            return code
    return None


def modbus_report(e: Exception, context: str) -> InstrumentReport:
    """A Modbus exception response as an :class:`InstrumentReport`. Never fatal on its
    own: the driver retries, and a controller that keeps refusing is caught by the
    transaction failing and, if it lasts, by the runner's communication timeout."""
    code = modbus_exception_code(e)
    name = MODBUS_EXCEPTIONS.get(code, (str(e), ""))[0] if code is not None else str(e)
    return InstrumentReport(
        "Modbus", -1 if code is None else code, name, "exception response", False, context
    )


def digital_input_registers(n: int) -> tuple[int, int]:
    """Holding registers of digital input ``n`` (1..4): its state, 201 + 12(n − 1), and
    its active condition, 1061 + 2(n − 1) (ChamberConnectLibrary ``watlowf4.py``)."""
    if not 1 <= n <= 4:
        raise ValueError(f"digital input {n} is not one of 1..4")
    return (
        REG_DIGITAL_INPUT + REG_DIGITAL_INPUT_STEP * (n - 1),
        REG_DIGITAL_CONDITION + REG_DIGITAL_CONDITION_STEP * (n - 1),
    )


def event_register(n: int) -> int:
    """Holding register of event output ``n`` (1..8): 2000 + 10(n − 1)."""
    if not 1 <= n <= 8:
        raise ValueError(f"event output {n} is not one of 1..8")
    return 2000 + 10 * (n - 1)


@dataclass(frozen=True)
class OvenStatus:
    """Registers 200 (profile mode), 103 and 107 (heat and cool power, %)."""

    profile_mode: int
    heat_pct: float
    cool_pct: float

    @property
    def profile_active(self) -> bool:
        """A profile runs or is paused: it, not register 300, drives the loop."""
        return self.profile_mode in (PROFILE_RUNNING, PROFILE_PAUSED)

    @property
    def heating(self) -> bool:
        return self.heat_pct > 0.0

    @property
    def cooling(self) -> bool:
        return self.cool_pct > 0.0

    @property
    def mode(self) -> str:
        """``profile`` | ``heat`` | ``cool`` | ``hold``."""
        if self.profile_active:
            return "profile"
        if self.heating:
            return "heat"
        if self.cooling:
            return "cool"
        return "hold"


@dataclass
class ModbusStats:
    """Transport errors seen (and retried) since the driver was created."""

    transactions: int = 0
    no_reply: int = 0
    bad_reply: int = 0  # CRC error or malformed
    exceptions: int = 0  # slave exception responses
    retries: int = 0
    late_bytes: int = 0  # bytes discarded while waiting for line silence after a failure
    noisy_line: int = 0  # waits for silence that ended at the cap, line still busy
    last_error: str = ""
    by_kind: dict[str, int] = field(default_factory=dict)


class WatlowF4:
    """Watlow F4 over Modbus RTU.

    Settings (:class:`~gyrolab.instruments.settings.Setting` on holding registers)
        ``setpoint_c``        reg 300, °C: limits checked first, written, read back
    Readings
        ``process_value_c``   reg 100, chamber air temperature, °C
        ``status``            regs 200, 103, 107: :class:`OvenStatus`
        ``event(n)``          reg 2000 + 10(n − 1), event output n (``set_event``)
        ``decimals``          reg 606, implied decimal places
        ``units``             reg 901, 0 = °F, 1 = °C

    ``port`` is a device path (``/dev/ttyUSB0``, a pty) or an open pyserial-like object
    (tests). Line: 19200 baud 8N1 by default (the F4 supports 9600/19200/38400).
    ``silence_s`` (default ``timeout_s``): after a failed transaction, how long the line
    must stay quiet before the next request (late replies are discarded meanwhile).
    """

    NAME = NAME

    setpoint_c = Setting(
        REG_SETPOINT,
        "static setpoint of loop 1, °C (register 300, in the controller's units and decimal "
        "places: 901, 606)",
        get=REG_SETPOINT,
        label="setpoint",
        unit="°C",
        validator=finite_within,
        values=lambda d: [("bench limits", d.setpoint_limits_c)],
        set_process=lambda d, v: d.register_value(v),
        get_process=lambda d, raw: d.celsius(raw),
        readback=True,
    )

    def __init__(
        self,
        port: str | Any,
        *,
        address: int = 1,
        baudrate: int = 19200,
        timeout_s: float = 0.3,
        setpoint_limits_c: tuple[float, float] = (-45.0, 70.0),
        retries: int = 2,
        silence_s: float | None = None,
    ) -> None:
        lo, hi = setpoint_limits_c
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ValueError(f"bad setpoint limits {setpoint_limits_c}")
        self.setpoint_limits_c = (float(lo), float(hi))
        self.retries = retries
        self.stats = ModbusStats()
        # Exception responses since the last pop_reports() (the runner logs them).
        self._reports: list[InstrumentReport] = []
        # RTU frames are delimited by 3.5 character times of silence (11 bits a character;
        # fixed 1.75 ms above 19200 baud, Modbus over serial line spec §2.5.1.1).
        self.frame_gap_s = 3.5 * 11 / baudrate if baudrate <= 19200 else 0.00175
        self.silence_s = max(self.frame_gap_s, timeout_s if silence_s is None else silence_s)
        self.trailing_quiet_s = min(self.silence_s, max(self.frame_gap_s, 0.02))
        self._quiet_s = 0.0  # quiet time the line needs before the next request
        # Wall time of the last failed transaction while its reply may still be in flight.
        self._dirty_since: float | None = None
        if isinstance(port, str):
            self.port_name = port
            try:
                ser = serial.Serial(
                    port, baudrate=baudrate, bytesize=8, parity="N", stopbits=1, timeout=timeout_s
                )
            except (serial.SerialException, OSError) as e:
                raise InstrumentError(NAME, f"cannot open {port}: {e}") from e
        else:
            self.port_name = str(getattr(port, "port", "<port>"))
            ser = port
        self.serial = ser
        self._mb = minimalmodbus.Instrument(ser, address, mode=minimalmodbus.MODE_RTU)
        # Drops whatever arrived since the last transaction (minimalmodbus resets the
        # input buffer before writing). Not enough on its own: a late reply can still
        # arrive after the request is written; _await_silence covers that.
        self._mb.clear_buffers_before_each_transaction = True
        self._decimals: int | None = None
        self._units: int | None = None

    # ----------------------------------------------------------------- transport
    def _reply_was_whole(self) -> bool:
        """Whether minimalmodbus's last read got every byte it asked for: it returned
        before the port's timeout. (Round trip = write + read, so a slow write can only
        make a whole reply look partial: the safe side.)"""
        rt = self._mb.roundtrip_time
        timeout = getattr(self.serial, "timeout", None)
        if rt is None:
            return False
        return timeout is None or rt < timeout

    def _mark_dirty(self, quiet_s: float) -> None:
        self._dirty_since = time.monotonic()
        self._quiet_s = max(self._quiet_s, quiet_s)

    def _await_silence(self) -> None:
        """Read and discard until the line has been quiet for the time the last failure
        needs (``silence_s`` when a reply may still be on its way).

        Called before the first request after a failed transaction: the slave may still
        be answering the request the driver gave up on. Quiet time counts from the
        failure, so a poll long after it waits only if late bytes are found. Bounded (a
        line that never goes quiet, e.g. another master or a wrong baud rate, is counted
        and left to fail the next transaction's checks)."""
        ser = self.serial
        quiet = self._quiet_s
        poll = min(0.005, quiet / 4)
        last = self._dirty_since if self._dirty_since is not None else time.monotonic()
        cap = time.monotonic() + 10 * quiet + 1.0
        while True:
            n = ser.in_waiting
            now = time.monotonic()
            if n:
                self.stats.late_bytes += len(ser.read(n))
                last = now  # arrival time unknown: count the quiet from now
            elif now - last >= quiet:
                break
            if now >= cap:
                self.stats.noisy_line += 1
                break
            time.sleep(poll)
        ser.reset_input_buffer()
        self._dirty_since = None
        self._quiet_s = 0.0

    def _call(self, what: str, fn: Any, *args: Any, **kw: Any) -> Any:
        last: Exception | None = None
        for attempt in range(self.retries + 1):
            self.stats.transactions += 1
            if attempt:
                self.stats.retries += 1
            try:
                if self._dirty_since is not None:
                    self._await_silence()
                return fn(*args, **kw)
            except minimalmodbus.NoResponseError as e:
                self.stats.no_reply += 1
                last = e
                self._mark_dirty(self.silence_s)  # the reply may yet come
            except minimalmodbus.SlaveReportedException as e:
                # A complete, valid frame from the slave: the line is in step.
                self.stats.exceptions += 1
                self._reports.append(modbus_report(e, what))
                last = e
            except (minimalmodbus.InvalidResponseError, minimalmodbus.ModbusException) as e:
                # Bad CRC or content: if the reply was whole the slave is done and only
                # trailing bytes can follow; a partial one may still be arriving.
                self.stats.bad_reply += 1
                last = e
                whole = self._reply_was_whole()
                self._mark_dirty(self.trailing_quiet_s if whole else self.silence_s)
            except (serial.SerialException, OSError) as e:
                self._mark_dirty(self.silence_s)
                raise InstrumentError(NAME, f"{what}: port error {e}") from e
            kind = type(last).__name__
            self.stats.by_kind[kind] = self.stats.by_kind.get(kind, 0) + 1
            self.stats.last_error = f"{kind}: {last}"
        msg = f"{what} failed after {self.retries + 1} tries ({self.stats.last_error})"
        if isinstance(last, minimalmodbus.NoResponseError):
            raise InstrumentTimeout(NAME, msg)
        raise InstrumentError(NAME, msg)

    def pop_reports(self) -> list[InstrumentReport]:
        """The exception responses received since the last call (retried or not)."""
        out, self._reports = self._reports, []
        return out

    def read_register(self, register: int) -> int:
        """Raw signed 16-bit value of one holding register (function 03)."""
        return int(
            self._call(f"read {register}", self._mb.read_register, register, 0, 3, signed=True)
        )

    def write_register(self, register: int, raw: int) -> None:
        """Write one signed 16-bit raw value (function 06)."""
        self._call(
            f"write {register}",
            self._mb.write_register,
            register,
            raw,
            0,
            6,
            signed=True,
        )

    # ------------------------------------------------------------------ readings
    @property
    def decimals(self) -> int:
        """Implied decimal places (reg 606), read once and cached."""
        if self._decimals is None:
            d = self.read_register(REG_DECIMALS)
            if d not in (0, 1, 2):
                raise InstrumentError(NAME, f"decimal places register reads {d}")
            self._decimals = d
        return self._decimals

    @property
    def units(self) -> int:
        """Temperature units (reg 901): 0 = °F, 1 = °C; read once and cached."""
        if self._units is None:
            u = self.read_register(REG_UNITS)
            if u not in (UNITS_F, UNITS_C):
                raise InstrumentError(NAME, f"units register reads {u}")
            self._units = u
        return self._units

    def celsius(self, raw: int) -> float:
        """A temperature register's raw value in °C (reads 606 and 901 once)."""
        scale = 10**self.decimals  # read 606 before 901, always in that order
        v = raw / scale
        return v if self.units == UNITS_C else (v - 32.0) * 5.0 / 9.0

    def register_value(self, value_c: float) -> int:
        """The raw value of a temperature register for ``value_c`` (reads 606 and 901
        once, never writes); :class:`LimitError` if it does not fit 16 bits."""
        scale = 10**self.decimals
        v = value_c if self.units == UNITS_C else value_c * 9.0 / 5.0 + 32.0
        raw = round(v * scale)
        if not -32768 <= raw <= 32767:
            raise LimitError(NAME, f"setpoint {value_c} °C does not fit a 16-bit register")
        return raw

    @property
    def process_value_c(self) -> float:
        """Chamber air temperature, °C (reg 100)."""
        return self.celsius(self.read_register(REG_PROCESS_VALUE))

    @property
    def profile_mode(self) -> int:
        """Reg 200: 0/1 constant, 2 profile running, 3 profile paused."""
        return self.read_register(REG_PROFILE_MODE)

    @property
    def status(self) -> OvenStatus:
        """Profile mode (reg 200), heat and cool power (regs 103, 107; 0.01 %)."""
        mode = self.profile_mode
        heat = self.read_register(REG_HEAT_POWER) / 100.0
        cool = self.read_register(REG_COOL_POWER) / 100.0
        return OvenStatus(mode, heat, cool)

    def event(self, n: int) -> bool:
        """Event output ``n`` (1..8) on?"""
        return bool(self.read_register(event_register(n)))

    def set_event(self, n: int, on: bool) -> None:
        """Switch event output ``n`` and verify it by reading it back."""
        reg = event_register(n)
        self.write_register(reg, 1 if on else 0)
        back = self.read_register(reg)
        if back != (1 if on else 0):
            msg = f"event output {n} read back {back} after writing {int(on)}"
            raise InstrumentError(NAME, msg)

    # ------------------------------------------------------------------ settings
    def set_setpoint(self, value_c: float) -> float:
        """Command a new setpoint (°C) and verify it by reading it back (``setpoint_c``).

        Limits are checked before anything is sent (:class:`LimitError`). Returns the
        setpoint the controller now holds, °C (quantized to its decimal places)."""
        return self.celsius(type(self).setpoint_c.write(self, value_c))

    def connect(self) -> dict[str, Any]:
        """Read the configuration registers; returns them (for the ``bench`` metadata)."""
        self._decimals = self._units = None
        return {
            "decimals": self.decimals,
            "units": "C" if self.units == UNITS_C else "F",
            "setpoint_c": self.setpoint_c,
            "process_value_c": self.process_value_c,
        }

    def close(self) -> None:
        try:
            self.serial.close()
        except Exception:
            pass

    def __enter__(self) -> WatlowF4:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(frozen=True)
class WatlowF4Config:
    """``[chamber] driver = "watlowf4"`` (docs/bench-config.md)."""

    driver: str = "watlowf4"
    port: str = ""  # "/dev/ttyUSB1"
    slave_address: int = 1
    baud_rate: int = 19200
    timeout_s: float = 0.3
    period_s: float = 2.0  # /oven/state poll period
    serial: str = ""
    # The F4 event output (1..8) that switches the chamber on (ESPEC wires one so); 0: none.
    # Needed for [safe_state] mode = "off".
    control_event: int = 0
    # The F4 digital input (1..4) the chamber's limit controller (alarm) is wired to; 0:
    # none (then the driver reports no chamber alarm).
    alarm_input: int = 0

    def check(self, safe_state_mode: str) -> None:
        """ValueError unless the settings make sense for a bench whose safe state is
        ``safe_state_mode`` ("setpoint" | "off")."""
        if not 0 <= self.control_event <= 8:
            raise ValueError("control_event must be an event output 1..8 (0: none)")
        if not 0 <= self.alarm_input <= 4:
            raise ValueError("alarm_input must be a digital input 1..4 (0: none)")
        if safe_state_mode == "off" and self.control_event == 0:
            raise ValueError(
                "[safe_state] mode = 'off' needs [chamber] control_event (the F4 event output "
                "that switches the chamber)"
            )


class WatlowF4Chamber(WatlowF4):
    """The F4 in the chamber role."""

    name = "oven"

    def __init__(self, port: Any, *, config: WatlowF4Config, **kw: Any) -> None:
        super().__init__(port, **kw)
        self.config = config
        self.registers: dict[str, Any] = {}
        self._alarm_level: int | None = None  # the alarm input's active condition

    def connect(self) -> dict[str, Any]:
        self.registers = super().connect()
        mode = self.profile_mode
        self.registers["profile_mode"] = mode
        if mode in (PROFILE_RUNNING, PROFILE_PAUSED):
            # A profile drives the loop, not register 300: our setpoints would do nothing.
            raise InstrumentError(
                NAME,
                f"a profile is running on the controller (register 200 = {mode}): "
                "end it at the controller first",
            )
        ev = self.config.control_event
        if ev:
            self.registers[f"event_{ev}"] = int(self.event(ev))
        n = self.config.alarm_input
        if n:
            self._alarm_level = self.read_register(digital_input_registers(n)[1])
            self.registers[f"digital_input_{n}_condition"] = self._alarm_level
        return self.registers

    def read(self) -> ChamberReading:
        sp = self.setpoint_c
        pv = self.process_value_c
        mode = self.profile_mode
        if mode in (PROFILE_RUNNING, PROFILE_PAUSED):
            raise InstrumentFault(
                f"a profile was started on the controller (register 200 = {mode}): "
                "register 300 no longer controls the chamber"
            )
        return ChamberReading(float(sp), float(pv), self.alarm())

    def alarm(self) -> str:
        """The chamber's alarm ("" when none): its ``alarm_input`` active."""
        n = self.config.alarm_input
        if not n:
            return ""
        state_reg, condition_reg = digital_input_registers(n)
        if self._alarm_level is None:
            self._alarm_level = self.read_register(condition_reg)
        state = self.read_register(state_reg)
        if state != self._alarm_level:
            return ""
        return f"limit alarm: digital input {n} active (register {state_reg} = {state})"

    def set_setpoint(self, value_c: float) -> float:
        """Setpoint (limits first, read back), then the chamber on through its control
        event output, if the bench wires one (read back)."""
        sp = super().set_setpoint(value_c)
        ev = self.config.control_event
        if ev and not self.event(ev):
            self.set_event(ev, True)
        return sp

    def switch_off(self) -> None:
        """Chamber off: its control event output to 0, verified by read-back."""
        ev = self.config.control_event
        if not ev:
            raise InstrumentError(NAME, "no control_event configured: cannot switch off")
        self.set_event(ev, False)

    def reports(self) -> list[InstrumentReport]:
        return self.pop_reports()

    def describe(self) -> dict[str, Any]:
        return {
            "driver": self.config.driver,
            "model": "Watlow F4 (Modbus RTU)",
            "port": self.port_name,
            "slave_address": self.config.slave_address,
            "serial": self.config.serial,
            "control_event": self.config.control_event,
            "registers": self.registers,
        }


def open_f4(c: WatlowF4Config, ctx: OpenContext) -> WatlowF4Chamber:
    timeout_s = ctx.timeout(c.timeout_s)
    return connected(
        WatlowF4Chamber(
            ctx.address,
            config=c,
            address=c.slave_address,
            baudrate=c.baud_rate,
            timeout_s=timeout_s,
            # A reply later than timeout + silence cannot be told from the next one's
            # (WatlowF4 above); the simulated slave is late by scheduling jitter at most.
            silence_s=timeout_s,
            setpoint_limits_c=ctx.setpoint_limits_c,
        )
    )


SPEC = register(
    DriverSpec(
        name="watlowf4",
        role="chamber",
        config=WatlowF4Config,
        open=open_f4,
        address_key="port",
        sim_backend="F4",
        sim_address="oven_port",
        description="Watlow F4 controller, Modbus RTU on RS-232/RS-485",
    )
)
