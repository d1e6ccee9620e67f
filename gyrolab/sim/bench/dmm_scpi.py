"""Simulated HP/Agilent 34401A: a SCPI responder served over a pty (RS-232) and TCP.

The responder implements the subset the driver uses, with the meter's short/long forms
and optional nodes (``CONF:FRES`` = ``CONFigure:FRESistance``), a 20-entry error queue
with the meter's codes, range overload (+9.9E+37 above 120 % of range), and readings
that take the integration time (NPLC / 50 Hz, ×2 for autozero) in *simulated* time.
Readings come from a callback (the bench's ``physics.pt100_ohm``). docs/instruments.md
lists the subset.
"""

from __future__ import annotations

import contextlib
import re
import socket
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from gyrolab.sim.bench.clock import SimClock
from gyrolab.sim.bench.serial_pty import PortClosed, PtyPort
from gyrolab.sim.identities import AGILENT_34401A_IDN, KEYSIGHT_34465A_IDN

RANGES = (100.0, 1e3, 10e3, 100e3, 1e6, 10e6, 100e6)
NPLCS = (0.02, 0.2, 1.0, 10.0, 100.0)
OVERLOAD = "+9.90000000E+37"
NO_ERROR = '+0,"No error"'
E_UNDEFINED = '-113,"Undefined header"'
E_RANGE = '-222,"Data out of range"'
E_PARAM = '-224,"Illegal parameter value"'
E_SYNTAX = '-102,"Syntax error"'
E_OVERFLOW = '-350,"Too many errors"'


def scpi_re(spec: str) -> re.Pattern[str]:
    """SCPI header spec → regex: ``[SENSe:]FRESistance:NPLCycles?`` matches ``FRES:NPLC?``,
    ``sense:fresistance:nplcycles?`` …; uppercase letters are the short form."""

    def node(name: str) -> str:
        short = "".join(ch for ch in name if ch.isupper() or ch == "*")
        alts = sorted({re.escape(short), re.escape(name.upper())}, key=len, reverse=True)
        return "(?:" + "|".join(alts) + ")"

    out = ""
    for m in re.finditer(r"\[(:?)([*A-Za-z]+)(:?)\]|([*A-Za-z]+)|(:)|(\?)", spec):
        if m.group(2):  # optional node, with its colon where the spec puts it
            out += f"(?:{m.group(1)}{node(m.group(2))}{m.group(3)})?"
        elif m.group(4):
            out += node(m.group(4))
        elif m.group(5):
            out += ":"
        else:
            out += r"\?"
    return re.compile(r":?" + out, re.IGNORECASE)


@dataclass
class DmmState:
    """Settings of the meter (what ``*RST`` restores)."""

    function: str = "VOLT"
    range_ohm: float = 1e3
    nplc: float = 10.0
    remote: bool = False
    errors: list[str] = field(default_factory=list)


class Scpi34401A:
    """The meter's command interpreter. ``read_ohm()`` returns the 4-wire resistance
    now (Ω); ``clock`` paces readings in simulated time (None: instant)."""

    line_frequency_hz = 50.0
    IDN = AGILENT_34401A_IDN  # what ``*IDN?`` answers

    def __init__(self, read_ohm: Callable[[], float], clock: SimClock | None = None) -> None:
        self.read_ohm = read_ohm
        self.clock = clock
        self.state = DmmState()
        self.outage_until: float = -1.0  # simulated time; silent (no replies) before it
        self.readings = 0
        self.log: list[str] = []  # every command received, for tests
        self._lock = threading.RLock()
        # The error queue has a lock of its own: a fault pushed by the bench's tick thread
        # must not wait for ``_lock``, which a reading holds while it waits for that very
        # thread to advance the simulated clock.
        self._qlock = threading.Lock()
        self._table = self.system_commands() + [
            (scpi_re("CONFigure:FRESistance"), self._conf_fres),
            (scpi_re("CONFigure?"), self._conf_q),
            (scpi_re("[SENSe:]FRESistance:NPLCycles"), self._nplc),
            (scpi_re("[SENSe:]FRESistance:NPLCycles?"), lambda a: f"{self.state.nplc:+.8E}"),
            (scpi_re("[SENSe:]FRESistance:RANGe"), self._range),
            (scpi_re("[SENSe:]FRESistance:RANGe?"), lambda a: f"{self.state.range_ohm:+.8E}"),
            (scpi_re("[SENSe:]FUNCtion?"), lambda a: f'"{self.state.function}"'),
            (scpi_re("READ?"), self._read),
            (scpi_re("MEASure:FRESistance?"), self._meas),
        ]

    def system_commands(self) -> list[tuple[re.Pattern[str], Callable[[str], str | None]]]:
        """The IEEE 488.2 common commands and the SYSTem subsystem this meter (and a SCPI
        instrument derived from it) answers: identity (``IDN``), reset, error queue, remote."""
        return [
            (scpi_re("*IDN?"), lambda a: self.IDN),
            (scpi_re("*RST"), self._rst),
            (scpi_re("*CLS"), self._cls),
            (scpi_re("*OPC?"), lambda a: "1"),
            (scpi_re("SYSTem:ERRor[:NEXT]?"), self._err),
            (scpi_re("SYSTem:REMote"), self._remote(True)),
            (scpi_re("SYSTem:RWLock"), self._remote(True)),
            (scpi_re("SYSTem:LOCal"), self._remote(False)),
        ]

    # ---------------------------------------------------------------- faults
    def push_error(self, error: str) -> None:
        """Put ``error`` (``-222,"Data out of range"``) into the error queue."""
        self._push(error)

    def start_outage(self, until_t_sim: float) -> None:
        """Say nothing until simulated time ``until_t_sim`` (cable pulled, meter hung)."""
        self.outage_until = until_t_sim

    # ---------------------------------------------------------------- interpreter
    def _push(self, error: str) -> None:
        with self._qlock:
            q = self.state.errors
            if len(q) < 19:
                q.append(error)
            elif len(q) == 19:
                q.append(E_OVERFLOW)

    def handle(self, line: str) -> str | None:
        """Execute one line (commands separated by ``;``); the reply, or None."""
        now = self.clock.now() if self.clock is not None else 0.0
        if now < self.outage_until:
            return None
        replies: list[str] = []
        with self._lock:
            self.log.append(line)
            for cmd in line.split(";"):
                cmd = cmd.strip()
                if not cmd:
                    continue
                header, _, arg = cmd.partition(" ")
                for pat, fn in self._table:
                    if pat.fullmatch(header):
                        r = fn(arg.strip())
                        if r is not None:
                            replies.append(r)
                        break
                else:
                    self._push(E_UNDEFINED)
        return ";".join(replies) if replies else None

    def _rst(self, arg: str) -> None:
        remote = self.state.remote
        errors = self.state.errors
        self.state = DmmState(remote=remote, errors=errors)

    def _cls(self, arg: str) -> None:
        with self._qlock:
            self.state.errors.clear()

    def _err(self, arg: str) -> str:
        with self._qlock:
            return self.state.errors.pop(0) if self.state.errors else NO_ERROR

    def _remote(self, on: bool) -> Callable[[str], None]:
        def f(arg: str) -> None:
            self.state.remote = on

        return f

    @staticmethod
    def _number(arg: str, choices: tuple[float, ...], default: float) -> float | None:
        a = arg.strip().upper()
        if a in ("", "DEF", "DEFAULT"):
            return default
        if a in ("MIN", "MINIMUM"):
            return choices[0]
        if a in ("MAX", "MAXIMUM"):
            return choices[-1]
        try:
            return float(a)
        except ValueError:
            return None

    def _set_range(self, arg: str) -> bool:
        v = self._number(arg.split(",")[0], RANGES, 1e3)
        if v is None:
            self._push(E_SYNTAX)
            return False
        fit = [r for r in RANGES if r >= v]  # the meter picks the range that holds v
        if not fit:
            self._push(E_RANGE)
            return False
        self.state.range_ohm = fit[0]
        return True

    def _conf_fres(self, arg: str) -> None:
        if self._set_range(arg):
            self.state.function = "FRES"

    def _range(self, arg: str) -> None:
        self._set_range(arg)

    def _conf_q(self, arg: str) -> str:
        if self.state.function == "FRES":
            return f'"FRES {self.state.range_ohm:+.6E},{self.state.range_ohm * 1e-7:+.6E}"'
        return f'"{self.state.function} +1.000000E+01,+3.000000E-06"'

    def _nplc(self, arg: str) -> None:
        v = self._number(arg, NPLCS, 10.0)
        if v is None:
            self._push(E_SYNTAX)
        elif v not in NPLCS:
            self._push(E_PARAM)
        else:
            self.state.nplc = v

    def integration_s(self) -> float:
        """Time one reading takes: NPLC power-line cycles, ×2 for autozero (4-wire)."""
        return 2.0 * self.state.nplc / self.line_frequency_hz

    def _read(self, arg: str) -> str:
        if self.clock is not None:
            self.clock.sleep(self.integration_s(), timeout_wall_s=10.0)
        self.readings += 1
        if self.state.function != "FRES":
            return "+1.23400000E-06"  # a DC volts reading of the shorted input
        r = float(self.read_ohm())
        if not r < 1.2 * self.state.range_ohm:
            return OVERLOAD
        return f"{r:+.8E}"

    def _meas(self, arg: str) -> str:
        self._conf_fres(arg)
        return self._read("")


class Scpi34465A(Scpi34401A):
    """Keysight 34465A (Truevolt): the 34401A's SCPI subset plus offset-compensated
    4-wire ohms (``[SENSe:]FRESistance:OCOMpensated {ON|OFF}``, 34465A/70A only) and the
    Truevolt NPLC set (0.02, 0.06, 0.2, 1, 10, 100). Keysight Truevolt DMM Command Quick
    Reference (docs/instruments.md). Offset compensation doubles the reading time."""

    IDN = KEYSIGHT_34465A_IDN
    NPLCS_34465A = (0.02, 0.06, 0.2, 1.0, 10.0, 100.0)

    def __init__(self, read_ohm: Callable[[], float], clock: SimClock | None = None) -> None:
        super().__init__(read_ohm, clock)
        self.ocomp = False
        self._table += [
            (scpi_re("[SENSe:]FRESistance:OCOMpensated"), self._ocomp),
            (scpi_re("[SENSe:]FRESistance:OCOMpensated?"), lambda a: str(int(self.ocomp))),
        ]

    def _rst(self, arg: str) -> None:
        super()._rst(arg)
        self.ocomp = False

    def _ocomp(self, arg: str) -> None:
        a = arg.strip().upper()
        if a in ("ON", "1"):
            self.ocomp = True
        elif a in ("OFF", "0"):
            self.ocomp = False
        else:
            self._push(E_PARAM)

    def _nplc(self, arg: str) -> None:
        v = self._number(arg, self.NPLCS_34465A, 10.0)
        if v is None:
            self._push(E_SYNTAX)
        elif v not in self.NPLCS_34465A:
            self._push(E_PARAM)
        else:
            self.state.nplc = v

    def integration_s(self) -> float:
        return super().integration_s() * (2.0 if self.ocomp else 1.0)


# --------------------------------------------------------------------------- transports


class _LineServer:
    """Reads command lines from a byte source, writes replies; one thread."""

    def __init__(self, responder: Any, eol: bytes) -> None:
        self.responder = responder
        self.eol = eol
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _serve_bytes(self, read: Callable[[], bytes], write: Callable[[bytes], None]) -> None:
        buf = b""
        while not self._stop.is_set():
            data = read()
            if data is None:
                return
            buf += data
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                reply = self.responder.handle(line.decode("ascii", "replace").strip("\r "))
                if reply is not None and not self._stop.is_set():
                    write(reply.encode("ascii") + self.eol)

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)


class ScpiSerialServer(_LineServer):
    """The meter on a pty: RS-232 replies end in CR LF."""

    def __init__(self, responder: Scpi34401A, port: PtyPort) -> None:
        super().__init__(responder, b"\r\n")
        self.port = port

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="sim-dmm-serial", daemon=True)
        self._thread.start()

    def _read(self) -> bytes:
        try:
            return self.port.read(0.05)
        except PortClosed:
            self._stop.wait(0.05)
            return b""

    def _write(self, data: bytes) -> None:
        with contextlib.suppress(PortClosed):
            self.port.write(data)

    def _run(self) -> None:
        self._serve_bytes(self._read, self._write)


class ScpiTcpServer(_LineServer):
    """The meter on a TCP socket (``TCPIP::127.0.0.1::<port>::SOCKET``): replies end in LF
    (``eol``; any responder with ``handle(line) -> reply | None``)."""

    def __init__(
        self, responder: Any, host: str = "127.0.0.1", port: int = 0, eol: bytes = b"\n"
    ) -> None:
        super().__init__(responder, eol)
        self._sock = socket.create_server((host, port))
        self._sock.settimeout(0.1)
        self.address: tuple[str, int] = self._sock.getsockname()[:2]
        self._conns: list[socket.socket] = []

    @property
    def resource(self) -> str:
        return f"TCPIP::{self.address[0]}::{self.address[1]}::SOCKET"

    def start(self) -> None:
        self._thread = threading.Thread(target=self._accept, name="sim-dmm-tcp", daemon=True)
        self._thread.start()

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            conn.settimeout(0.1)
            self._conns.append(conn)
            threading.Thread(
                target=self._serve_conn, args=(conn,), name="sim-dmm-conn", daemon=True
            ).start()

    def _serve_conn(self, conn: socket.socket) -> None:
        def read() -> bytes | None:
            try:
                data = conn.recv(4096)
            except TimeoutError:
                return b""
            except OSError:
                return None
            return data if data else None  # b"" from recv: the client closed

        def write(data: bytes) -> None:
            with contextlib.suppress(OSError):
                conn.sendall(data)

        try:
            self._serve_bytes(read, write)  # type: ignore[arg-type]
        finally:
            with contextlib.suppress(OSError):
                conn.close()

    def stop(self) -> None:
        self._stop.set()
        with contextlib.suppress(OSError):
            self._sock.close()
        for c in self._conns:
            with contextlib.suppress(OSError):
                c.close()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
