"""Simulated Watlow F4 oven controller: a Modbus RTU slave on a pty.

Functions 03 (read holding registers) and 06 (write single register) on the map of
docs/instruments.md (100 process value, 103/107 heat/cool power in 0.01 %, 200 profile
mode (0/1 constant, 2 running, 3 paused), 300 setpoint, 606 decimal places, 901 units,
1209/1210/1217 profile resume/pause/terminate, event outputs 1-8 at 2000 + 10(N-1),
digital inputs 1-4: state at 201 + 12(N-1), active condition at 1061 + 2(N-1)).
With ``control_event`` = N the chamber is switched by event output N (as ESPEC wires
its F4 chambers): off, the heater and refrigerator stop and the air settles to ambient.
With ``alarm_input`` = N the chamber's limit controller is wired to digital input N:
:meth:`WatlowF4Slave.set_alarm` (the ``chamber_alarm`` fault) makes that input active and
cuts the heater and refrigerator (the air settles to ambient) until it clears; the
controller's setpoint is then in force again.
A request with a bad CRC or for another address is ignored, as on a real
line; a bad register or value gets an exception response (02 illegal data address,
03 illegal data value). Faults from :class:`~gyrolab.sim.bench.faults.ModbusFaults`:
exception responses, replies with a wrong CRC, no reply.
"""

from __future__ import annotations

import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from gyrolab.sim.bench.faults import ModbusFaults
from gyrolab.sim.bench.serial_pty import PortClosed, PtyPort

REG_PV, REG_PROFILE_MODE, REG_SP, REG_DP, REG_UNITS = 100, 200, 300, 606, 901
REG_HEAT_POWER, REG_COOL_POWER = 103, 107  # output 1A / 1B, signed, 0.01 %
REG_RESUME, REG_PAUSE, REG_TERMINATE = 1209, 1210, 1217  # write 1
EVENTS = {2000 + 10 * (n - 1): n for n in range(1, 9)}  # event output N: 0 off, 1 on
DIGITAL_INPUTS = {201 + 12 * (n - 1): n for n in range(1, 5)}  # digital input N: its state
DIGITAL_CONDITIONS = {1061 + 2 * (n - 1): n for n in range(1, 5)}  # its active condition
ACTIVE = 1  # the simulated inputs' active condition (their state when active)
EX_ILLEGAL_FUNCTION, EX_ILLEGAL_ADDRESS, EX_ILLEGAL_VALUE = 0x01, 0x02, 0x03


def crc16_modbus(data: bytes) -> int:
    """CRC-16/MODBUS (poly 0xA001 reflected, init 0xFFFF); sent low byte first."""
    crc = 0xFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def with_crc(pdu: bytes) -> bytes:
    return pdu + struct.pack("<H", crc16_modbus(pdu))


@dataclass
class OvenHooks:
    """How the slave reaches the physics (all °C)."""

    chamber_c: Callable[[], float]
    setpoint_c: Callable[[], float]
    set_setpoint: Callable[[float], None]
    ambient_c: float = 25.0


class WatlowF4Slave:
    """Register logic of the controller (transport-free, for direct tests too)."""

    def __init__(
        self,
        hooks: OvenHooks,
        *,
        address: int = 1,
        decimals: int = 1,
        units_c: bool = True,
        limits_c: tuple[float, float] = (-73.0, 190.0),
        alarm_c: tuple[float, float] = (-60.0, 80.0),
        faults: ModbusFaults | None = None,
        control_event: int | None = None,
        alarm_input: int | None = None,
    ) -> None:
        self.hooks = hooks
        if control_event is not None and not 1 <= control_event <= 8:
            raise ValueError("control_event is an event output 1..8")
        if alarm_input is not None and not 1 <= alarm_input <= 4:
            raise ValueError("alarm_input is a digital input 1..4")
        self.control_event = control_event
        self.alarm_input = alarm_input
        self.inputs = [1 - ACTIVE] * 4  # digital inputs 1..4, all inactive
        self.events = [0] * 8
        self.profile_mode = 0  # no profile is ever started on the simulated controller
        self.setpoint_raw: int | None = None  # register 300 as written (None: physics')
        self.address = address
        self.decimals = decimals
        self.units_c = units_c
        self.limits_c = limits_c  # the controller's own setpoint range
        self.alarm_c = alarm_c
        self.faults = faults or ModbusFaults()
        self.requests = 0
        self.writes: list[tuple[int, int]] = []  # (register, raw) of every accepted write
        self.fault_counts: dict[str, int] = {}

    def _to_raw(self, c: float) -> int:
        v = c if self.units_c else c * 9.0 / 5.0 + 32.0
        return max(-32768, min(32767, round(v * 10**self.decimals)))

    def _from_raw(self, raw: int) -> float:
        v = raw / 10**self.decimals
        return v if self.units_c else (v - 32.0) * 5.0 / 9.0

    def register(self, reg: int) -> int | None:
        """Raw signed value of a register, None if it does not exist."""
        if reg == REG_PV:
            return self._to_raw(self.hooks.chamber_c())
        if reg == REG_SP:
            if self.setpoint_raw is not None:
                return self.setpoint_raw
            return self._to_raw(self.hooks.setpoint_c())
        if reg == REG_DP:
            return self.decimals
        if reg == REG_UNITS:
            return 1 if self.units_c else 0
        if reg == REG_PROFILE_MODE:
            return self.profile_mode
        if reg in (REG_HEAT_POWER, REG_COOL_POWER):
            if not self.chamber_on():
                return 0
            # A proportional band of 5 °C: enough to show which output works, not a PID.
            err = self.hooks.setpoint_c() - self.hooks.chamber_c()
            pct = min(100.0, max(0.0, (err if reg == REG_HEAT_POWER else -err) * 20.0))
            return round(pct * 100)
        if reg in (REG_RESUME, REG_PAUSE, REG_TERMINATE):
            return 0
        if reg in EVENTS:
            return self.events[EVENTS[reg] - 1]
        if reg in DIGITAL_INPUTS:
            return self.inputs[DIGITAL_INPUTS[reg] - 1]
        if reg in DIGITAL_CONDITIONS:
            return ACTIVE
        return None

    def set_alarm(self, on: bool) -> None:
        """The limit controller trips (``on``) or resets: its digital input follows, and
        the heater and refrigerator stop while it is tripped."""
        if self.alarm_input is None:
            raise ValueError("no alarm_input: the chamber's alarm is not wired")
        self.inputs[self.alarm_input - 1] = ACTIVE if on else 1 - ACTIVE
        self._apply()

    def alarm(self) -> bool:
        """Whether the limit controller has tripped."""
        return self.alarm_input is not None and self.inputs[self.alarm_input - 1] == ACTIVE

    def chamber_on(self) -> bool:
        """Whether heater and refrigerator may run: the control event, if wired, is on and
        the limit controller, if wired, has not tripped."""
        on = self.control_event is None or bool(self.events[self.control_event - 1])
        return on and not self.alarm()

    def _apply(self) -> None:
        """Drive the physics: the setpoint when on, the air settling to ambient when off."""
        if self.setpoint_raw is None:
            if not self.chamber_on():  # tripped before any setpoint was written
                self.hooks.set_setpoint(self.hooks.ambient_c)
            return
        on = self.chamber_on()
        self.hooks.set_setpoint(self._from_raw(self.setpoint_raw) if on else self.hooks.ambient_c)

    def process(self, req: bytes) -> bytes | None:
        """One request frame (with CRC) → reply frame, or None (ignored / no reply)."""
        if len(req) < 4 or crc16_modbus(req[:-2]) != struct.unpack("<H", req[-2:])[0]:
            return None
        if req[0] != self.address:
            return None
        self.requests += 1
        fault = self.faults.draw()
        if fault is not None:
            self.fault_counts[fault] = self.fault_counts.get(fault, 0) + 1
        if fault == "modbus_no_reply":
            return None
        func = req[1]
        if fault == "modbus_exception":
            reply = bytes([self.address, func | 0x80, self.faults.exception_code])
        else:
            reply = self._execute(func, req[2:-2])
        out = with_crc(reply)
        if fault == "modbus_crc":
            out = out[:-2] + bytes([out[-2] ^ 0xFF, out[-1]])
        return out

    def _execute(self, func: int, data: bytes) -> bytes:
        a = self.address
        if func == 0x03 and len(data) == 4:
            start, count = struct.unpack(">HH", data)
            if not 1 <= count <= 125:
                return bytes([a, 0x83, EX_ILLEGAL_VALUE])
            values = [self.register(r) for r in range(start, start + count)]
            if any(v is None for v in values):
                return bytes([a, 0x83, EX_ILLEGAL_ADDRESS])
            body = b"".join(struct.pack(">h", v) for v in values)  # type: ignore[arg-type]
            return bytes([a, 0x03, len(body)]) + body
        if func == 0x06 and len(data) == 4:
            reg, raw = struct.unpack(">Hh", data)
            if reg in EVENTS or reg in (REG_RESUME, REG_PAUSE, REG_TERMINATE):
                if raw not in (0, 1):
                    return bytes([a, 0x86, EX_ILLEGAL_VALUE])
                if reg in EVENTS:
                    self.events[EVENTS[reg] - 1] = raw
                    self._apply()
                elif raw and reg == REG_TERMINATE:
                    self.profile_mode = 0
                self.writes.append((reg, raw))
                return bytes([a, 0x06]) + data
            if reg != REG_SP:
                exists = self.register(reg) is not None
                return bytes([a, 0x86, EX_ILLEGAL_VALUE if exists else EX_ILLEGAL_ADDRESS])
            value = self._from_raw(raw)
            if not self.limits_c[0] <= value <= self.limits_c[1]:
                return bytes([a, 0x86, EX_ILLEGAL_VALUE])
            self.setpoint_raw = raw
            self._apply()
            self.writes.append((reg, raw))
            return bytes([a, 0x06]) + data  # echo
        return bytes([a, func | 0x80, EX_ILLEGAL_FUNCTION])


def request_length(buf: bytes) -> int | None:
    """Length of the RTU request at the start of ``buf`` (None: not known yet)."""
    if len(buf) < 2:
        return None
    func = buf[1]
    if func in (0x03, 0x04, 0x06):
        return 8
    if func == 0x10:
        return 9 + buf[6] if len(buf) >= 7 else None
    return -1  # unknown function: take what arrived until the line goes quiet


class ModbusRtuServer:
    """Serves a :class:`WatlowF4Slave` on a pty, one thread. Frames are delimited by
    their known length; anything left after 20 ms of silence (the RTU 3.5-character
    rule, generously) is discarded, which resynchronises after line noise."""

    silence_s = 0.02

    def __init__(self, slave: WatlowF4Slave, port: PtyPort) -> None:
        self.slave = slave
        self.port = port
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="sim-oven", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)

    def _run(self) -> None:
        buf = b""
        last = time.monotonic()
        while not self._stop.is_set():
            try:
                data = self.port.read(self.silence_s)
            except PortClosed:
                self._stop.wait(0.05)
                buf = b""
                continue
            now = time.monotonic()
            if not data:
                if buf and now - last >= self.silence_s:
                    ln = request_length(buf)
                    if ln == -1:
                        self._reply(buf)
                    buf = b""
                continue
            last = now
            buf += data
            while True:
                ln = request_length(buf)
                if ln is None or ln == -1 or len(buf) < ln:
                    break
                frame, buf = buf[:ln], buf[ln:]
                self._reply(frame)

    def _reply(self, frame: bytes) -> None:
        out = self.slave.process(frame)
        if out is not None:
            try:
                self.port.write(out)
            except PortClosed:
                pass
