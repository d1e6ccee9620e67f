"""Simulated Watlow F4-style oven controller: a Modbus RTU slave on a pty.

Functions 03 (read holding registers) and 06 (write single register) on the map of
docs/instruments.md (100 process value, 200 status, 300 setpoint, 606 decimal places,
901 units). A request with a bad CRC or for another address is ignored, as on a real
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

REG_PV, REG_STATUS, REG_SP, REG_DP, REG_UNITS = 100, 200, 300, 606, 901
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
    ) -> None:
        self.hooks = hooks
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
            return self._to_raw(self.hooks.setpoint_c())
        if reg == REG_DP:
            return self.decimals
        if reg == REG_UNITS:
            return 1 if self.units_c else 0
        if reg == REG_STATUS:
            air, sp = self.hooks.chamber_c(), self.hooks.setpoint_c()
            bits = 0
            if sp > air + 0.5:
                bits |= 0x01
            if sp < air - 0.5:
                bits |= 0x02
            if not self.alarm_c[0] <= air <= self.alarm_c[1]:
                bits |= 0x04
            return bits
        return None

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
            if reg != REG_SP:
                exists = self.register(reg) is not None
                return bytes([a, 0x86, EX_ILLEGAL_VALUE if exists else EX_ILLEGAL_ADDRESS])
            value = self._from_raw(raw)
            if not self.limits_c[0] <= value <= self.limits_c[1]:
                return bytes([a, 0x86, EX_ILLEGAL_VALUE])
            self.hooks.set_setpoint(value)
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
