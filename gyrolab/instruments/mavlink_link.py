"""One MAVLink connection to a flight controller, shared by everything that talks to it:
the IMU streams of the ``mavlink`` rate-stream driver, the parameter protocol and commands.

Transport: a serial port (the controller's USB CDC-ACM or a telemetry UART, pyserial) or
``tcp:HOST:PORT`` (PX4/ArduPilot SITL). Messages are MAVLink 2 of pymavlink's ``common``
dialect, encoded and parsed with a private ``MAVLink`` object (no ``mavutil`` global
dialect). The link identifies the autopilot from its HEARTBEAT (``autopilot`` field:
MAV_AUTOPILOT_PX4 = 12, MAV_AUTOPILOT_ARDUPILOTMEGA = 3).

Parameter protocol (mavlink.io "Parameter Protocol"; messages PARAM_REQUEST_READ,
PARAM_SET, PARAM_VALUE of common.xml): a read is answered by PARAM_VALUE; a write is
acknowledged by the PARAM_VALUE of that name carrying the value now held — the read-back.
No answer within the timeout is retried, then :class:`InstrumentTimeout`. Integer
parameters travel in the float field bytewise for PX4 and C-cast for ArduPilot
(:func:`gyrolab.autopilot.mavlink.param_to_wire`).

:func:`write_parameters` is the one transactional write (docs/instruments.md, "Flashing"):
previous values read first (an unknown parameter refuses before anything is written),
then each value written and read back, and on any failure every value already written put
back, so that a vehicle is never left half-configured.
"""

from __future__ import annotations

import math
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gyrolab.autopilot import mavlink as ml
from gyrolab.instruments.roles import InstrumentError, InstrumentTimeout

GCS_SYSTEM_ID = 255  # a ground station's system id (MAVLink convention)
GCS_COMPONENT_ID = 190  # MAV_COMP_ID_MISSIONPLANNER
MAX_PENDING = 200_000  # IMU messages kept per instance between reads (bounded memory)


@dataclass
class ImuSample:
    """One IMU message: FC time (s), gyro (int16 mrad/s ×3), accel (int16 mG ×3), °C."""

    t: float
    gyro: tuple[int, int, int]
    accel: tuple[int, int, int]
    temperature_c: float


class _Serial:
    def __init__(self, path: str, baudrate: int) -> None:
        import serial

        self.s = serial.Serial(path, baudrate=baudrate, timeout=0.05)

    def read(self, timeout_s: float) -> bytes:
        if self.s.timeout != timeout_s:
            self.s.timeout = timeout_s
        data = self.s.read(max(1, self.s.in_waiting))
        if data and self.s.in_waiting:
            data += self.s.read(self.s.in_waiting)
        return bytes(data)

    def write(self, data: bytes) -> None:
        self.s.write(data)

    def close(self) -> None:
        self.s.close()


class _Tcp:
    def __init__(self, host: str, port: int) -> None:
        self.s = socket.create_connection((host, port), timeout=5.0)

    def read(self, timeout_s: float) -> bytes:
        self.s.settimeout(max(timeout_s, 1e-3))
        try:
            return self.s.recv(65536)
        except TimeoutError:
            return b""

    def write(self, data: bytes) -> None:
        self.s.sendall(data)

    def close(self) -> None:
        self.s.close()


def _transport(address: str, baudrate: int) -> Any:
    if address.startswith("tcp:"):
        host, _, port = address[4:].rpartition(":")
        return _Tcp(host or "127.0.0.1", int(port))
    return _Serial(address, baudrate)


@dataclass
class LinkStats:
    messages: int = 0
    bad_bytes: int = 0
    heartbeats: int = 0
    imu: dict[int, int] = field(default_factory=dict)
    dropped: int = 0  # IMU messages dropped because nobody read them (MAX_PENDING)


class MavlinkLink:
    """A connection (module doc). ``timeout_s``: per request; ``retries`` per request."""

    def __init__(
        self,
        address: str,
        *,
        baudrate: int = 921600,
        timeout_s: float = 1.0,
        retries: int = 3,
        clock: Callable[[], float] = time.monotonic,
        transport: Any = None,
    ) -> None:
        from pymavlink.dialects.v20 import common

        self.address = address
        self.timeout_s = float(timeout_s)
        self.retries = int(retries)
        self._clock = clock
        self._io = transport if transport is not None else _transport(address, baudrate)
        self.common = common
        self._mav = common.MAVLink(None, srcSystem=GCS_SYSTEM_ID, srcComponent=GCS_COMPONENT_ID)
        self._parser = common.MAVLink(None)
        self._parser.robust_parsing = True
        self._lock = threading.RLock()  # one reader of the port at a time
        self.firmware = ""
        self.target = (1, 1)
        self.imu: dict[int, deque[ImuSample]] = {}
        self._params: dict[str, tuple[float, float, int]] = {}  # name → (wire, arrival, type)
        self._acks: dict[int, tuple[int, float]] = {}  # command → (result, arrival)
        self.last_heartbeat = -float("inf")
        self.stats = LinkStats()

    # ------------------------------------------------------------------ traffic
    def send(self, msg: Any) -> None:
        with self._lock:
            self._io.write(msg.pack(self._mav))

    def pump(self, timeout_s: float = 0.05) -> None:
        """Read what has arrived (waiting up to ``timeout_s`` for the first bytes) and
        file it: IMU messages per instance, parameter values, command acks, heartbeats."""
        with self._lock:  # read, parse and file in one: messages stay in arrival order
            data = self._io.read(timeout_s)
            if not data:
                return
            now = self._clock()
            for m in self._parser.parse_buffer(data) or []:
                self._file(m, now)

    def _file(self, m: Any, now: float) -> None:
        kind = m.get_type()
        self.stats.messages += 1
        if kind == "BAD_DATA":
            self.stats.bad_bytes += len(getattr(m, "data", b""))
            return
        if self.firmware:
            names = ml.IMU_MESSAGES[self.firmware]
            if kind in names:
                k = names.index(kind)
                q = self.imu.setdefault(k, deque())
                if len(q) >= MAX_PENDING:
                    q.popleft()
                    self.stats.dropped += 1
                q.append(
                    ImuSample(
                        ml.time_s(m),
                        (int(m.xgyro), int(m.ygyro), int(m.zgyro)),
                        (int(m.xacc), int(m.yacc), int(m.zacc)),
                        ml.temperature_c(m),
                    )
                )
                self.stats.imu[k] = self.stats.imu.get(k, 0) + 1
                return
        if kind == "HEARTBEAT":
            if m.autopilot in ml.MAV_AUTOPILOT:
                self.firmware = self.firmware or ml.MAV_AUTOPILOT[m.autopilot]
                self.target = (m.get_srcSystem(), m.get_srcComponent())
                self.last_heartbeat = now
                self.stats.heartbeats += 1
        elif kind == "PARAM_VALUE":
            name = m.param_id if isinstance(m.param_id, str) else m.param_id.decode()
            self._params[name.rstrip("\0")] = (float(m.param_value), now, int(m.param_type))
        elif kind == "COMMAND_ACK":
            self._acks[int(m.command)] = (int(m.result), now)

    def _wait(self, done: Callable[[], bool], timeout_s: float) -> bool:
        end = self._clock() + timeout_s
        while not done():
            left = end - self._clock()
            if left <= 0:
                return False
            self.pump(min(0.05, left))
        return True

    # ------------------------------------------------------------------ connect
    def connect(self, timeout_s: float = 5.0) -> str:
        """Wait for the autopilot's heartbeat; returns its firmware (``px4``/``ardupilot``)."""
        if not self._wait(lambda: bool(self.firmware), timeout_s):
            raise InstrumentTimeout(
                "flight controller",
                f"{self.address}: no PX4/ArduPilot HEARTBEAT in {timeout_s:g} s",
            )
        return self.firmware

    def close(self) -> None:
        with self._lock:
            try:
                self._io.close()
            except OSError:
                pass

    # ------------------------------------------------------------------ parameters
    def _name_bytes(self, name: str) -> bytes:
        if len(name) > 16:
            raise InstrumentError("flight controller", f"parameter name {name!r} is too long")
        return name.encode("ascii")

    def _answered(self, name: str, since: float) -> bool:
        return self._params.get(name, (0.0, -math.inf, 0))[1] >= since

    def _acked(self, command: int, since: float) -> bool:
        return self._acks.get(command, (0, -math.inf))[1] >= since

    def param_read(self, name: str) -> tuple[float, int]:
        """``(value, MAV_PARAM_TYPE)`` of parameter ``name``; InstrumentTimeout when the
        vehicle does not answer (it has no such parameter)."""
        sent_at = 0.0
        for _ in range(self.retries):
            sent_at = self._clock()
            msg = self.common.MAVLink_param_request_read_message(
                *self.target, self._name_bytes(name), -1
            )
            self.send(msg)
            if self._wait(lambda at=sent_at: self._answered(name, at), self.timeout_s):
                wire, _t, ptype = self._params[name]
                return ml.param_from_wire(wire, ptype, self.firmware), ptype
        raise InstrumentTimeout(
            "flight controller", f"no PARAM_VALUE for {name} (unknown to the vehicle?)"
        )

    def param_set(self, name: str, value: float, ptype: int) -> float:
        """Write ``name`` and return the value the vehicle reads back (its PARAM_VALUE);
        InstrumentTimeout when it never acknowledges."""
        wire = ml.param_to_wire(value, ptype, self.firmware)
        for _ in range(self.retries):
            sent_at = self._clock()
            msg = self.common.MAVLink_param_set_message(
                *self.target, self._name_bytes(name), wire, int(ptype)
            )
            self.send(msg)
            if self._wait(lambda at=sent_at: self._answered(name, at), self.timeout_s):
                got, _t, gtype = self._params[name]
                return ml.param_from_wire(got, gtype, self.firmware)
        raise InstrumentTimeout("flight controller", f"PARAM_SET {name} not acknowledged")

    def command(self, command: int, *params: float) -> int:
        """COMMAND_LONG; the COMMAND_ACK result (MAV_RESULT, 0 = accepted)."""
        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        for _ in range(self.retries):
            sent_at = self._clock()
            self.send(self.common.MAVLink_command_long_message(*self.target, command, 0, *p))
            if self._wait(lambda at=sent_at: self._acked(command, at), self.timeout_s):
                return self._acks[command][0]
        raise InstrumentTimeout("flight controller", f"command {command} not acknowledged")

    def set_imu_rate(self, instance: int, rate_hz: float) -> None:
        """Stream IMU ``instance``'s message at ``rate_hz`` (0: stop):
        MAV_CMD_SET_MESSAGE_INTERVAL with the interval in µs (−1 stops it)."""
        msg_id = ml.MESSAGE_IDS[ml.message_for(self.firmware, instance)]
        interval = 1e6 / rate_hz if rate_hz > 0 else -1.0
        result = self.command(ml.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, interval)
        if result != 0:
            raise InstrumentError(
                "flight controller",
                f"SET_MESSAGE_INTERVAL for IMU {instance} refused (MAV_RESULT {result})",
            )

    def reboot(self, timeout_s: float = 30.0) -> None:
        """MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN (reboot the autopilot), then wait for its
        heartbeat again."""
        result = self.command(ml.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1)
        if result != 0:
            raise InstrumentError("flight controller", f"reboot refused (MAV_RESULT {result})")
        asked = self._clock()
        if not self._wait(lambda: self.last_heartbeat > asked, timeout_s):
            raise InstrumentTimeout("flight controller", "no HEARTBEAT after the reboot")
        for q in self.imu.values():
            q.clear()


def same_value(a: float, b: float, ptype: int) -> bool:
    """Whether two parameter values are equal as the vehicle stores them (float32, or the
    integer for an integer type)."""
    if ptype == ml.MAV_PARAM_TYPE_REAL32:
        return bool(np.float32(a) == np.float32(b))
    return int(round(a)) == int(round(b))


@dataclass
class WriteReport:
    """What :func:`write_parameters` did: ``ok``; ``previous`` (name → value before);
    ``written`` (name → value read back) in write order; ``failed`` (the name whose write
    failed, and why); ``restored`` (name → value read back after putting it back) and
    ``restore_failed`` (names that could not be put back: the vehicle needs attention)."""

    ok: bool
    previous: dict[str, float]
    types: dict[str, int] = field(default_factory=dict)  # MAV_PARAM_TYPE of each name
    written: dict[str, float] = field(default_factory=dict)
    failed: tuple[str, str] | None = None
    restored: dict[str, float] = field(default_factory=dict)
    restore_failed: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {
            "ok": self.ok,
            "previous": self.previous,
            "written": self.written,
            "failed": None
            if self.failed is None
            else {"name": self.failed[0], "why": self.failed[1]},
            "restored": self.restored,
            "restore_failed": self.restore_failed,
        }


def write_parameters(link: MavlinkLink, values: list[tuple[str, float, int]]) -> WriteReport:
    """Write ``values`` (``(name, value, MAV_PARAM_TYPE)``, in this order) as one
    transaction (module doc); never raises for a failed write — the report says what
    happened (an unknown parameter raises InstrumentError before anything is written)."""
    previous: dict[str, float] = {}
    types: dict[str, int] = {}
    for name, _v, _t in values:
        if name not in previous:
            try:
                previous[name], types[name] = link.param_read(name)
            except InstrumentTimeout as e:
                raise InstrumentError(
                    "flight controller",
                    f"cannot read {name} before writing it ({e}); nothing written",
                ) from None
    rep = WriteReport(ok=False, previous=previous, types=types)
    touched: list[str] = []
    for name, value, ptype in values:
        touched.append(name)
        try:
            got = link.param_set(name, value, ptype)
        except InstrumentError as e:
            rep.failed = (name, str(e))
            break
        if not same_value(got, value, ptype):
            rep.failed = (name, f"read back {got!r}, wrote {value!r}")
            break
        rep.written[name] = got
    else:
        rep.ok = True
        return rep
    # put back, newest first, every parameter touched — the failed one too, unless reading
    # it shows the write never landed (a write may land without its acknowledgement)
    for name in reversed(list(dict.fromkeys(touched))):
        try:
            if name not in rep.written:
                now, _t = link.param_read(name)
                if same_value(now, previous[name], types[name]):
                    rep.restored[name] = now
                    continue
            got = link.param_set(name, previous[name], types[name])
        except InstrumentError:
            rep.restore_failed.append(name)
            continue
        if same_value(got, previous[name], types[name]):
            rep.restored[name] = got
        else:
            rep.restore_failed.append(name)
    return rep
