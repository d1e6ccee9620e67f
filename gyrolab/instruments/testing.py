"""Expected-protocol test harness for instrument drivers (PyMeasure's ``expected_protocol``
style): a stand-in for the driver's port that checks every command the driver sends
against an expected list, in order, and plays back the paired reply.

* :class:`ExpectedVisa` stands in for a pyvisa resource (SCPI lines: ``write``, ``read``,
  ``query``); dialogue ``[(command, reply or None)]``.
* :class:`ExpectedResourceManager` stands in for a pyvisa ResourceManager: a driver opened
  by address (as ``gyrolab acquire`` opens it) gets an :class:`ExpectedVisa`.
* :class:`ExpectedSerial` stands in for a pyserial port (bytes: Modbus RTU frames, any
  binary protocol); dialogue ``[(request bytes, reply bytes or None = stay silent)]``.
* :func:`expected_protocol` opens a driver on either and checks, on leaving the block,
  that the whole dialogue was used.

Each driver's test uses these (``tests/test_driver_*.py``); a driver takes an already-open
resource or port in place of its address for this purpose (docs/instruments.md, "Adding a
driver").
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Sequence
from typing import Any


class ExpectedVisa:
    """Stands in for a pyvisa resource and checks the exact dialogue, in order:
    ``(command written, reply read back or None)``."""

    def __init__(self, dialogue: list[tuple[str, str | None]], name: str = "GPIB0::22::INSTR"):
        self.dialogue = list(dialogue)
        self.resource_name = name
        self.timeout = 0
        self.write_termination = self.read_termination = ""
        self._reply: str | None = None
        self.closed = False
        self.written: list[str] = []

    def write(self, command: str) -> None:
        self.written.append(command)
        assert self.dialogue, f"unexpected command {command!r}"
        want, reply = self.dialogue.pop(0)
        assert command == want
        self._reply = reply

    def read(self) -> str:
        assert self._reply is not None, "read with no reply pending"
        r, self._reply = self._reply, None
        return r + "\n"

    def query(self, command: str) -> str:
        self.write(command)
        return self.read()

    def close(self) -> None:
        self.closed = True

    def assert_done(self) -> None:
        assert not self.dialogue, f"commands never sent: {self.dialogue}"


class ExpectedResourceManager:
    """Stands in for a pyvisa ``ResourceManager`` (a driver's ``visa_library``): hands out
    an :class:`ExpectedVisa` per resource name, each with its own dialogue, so that a
    driver can be opened by address the way ``gyrolab acquire`` opens it
    (``OpenContext.visa_library``)."""

    def __init__(self, dialogues: dict[str, list[tuple[str, str | None]]]) -> None:
        self.dialogues = {name: list(d) for name, d in dialogues.items()}
        self.opened: dict[str, ExpectedVisa] = {}

    def open_resource(self, name: str, **kw: Any) -> ExpectedVisa:
        if name not in self.dialogues:
            # pyvisa raises VisaIOError (an OSError-like failure) for an absent resource
            raise OSError(f"no instrument at {name!r}")
        res = self.opened[name] = ExpectedVisa(self.dialogues.pop(name), name)
        return res

    def close(self) -> None:
        pass

    def assert_done(self) -> None:
        assert not self.dialogues, f"resources never opened: {sorted(self.dialogues)}"
        for res in self.opened.values():
            res.assert_done()


class ExpectedSerial:
    """A pyserial stand-in that checks every request against the expected list and
    plays the paired reply (None: stay silent)."""

    def __init__(self, dialogue: list[tuple[bytes, bytes | None]]) -> None:
        self.dialogue = list(dialogue)
        self.written: list[bytes] = []
        self._rx = b""
        self.is_open = True
        self.port = "expected"
        self.baudrate = 19200
        self.timeout = 0.05

    def open(self) -> None:
        self.is_open = True

    def close(self) -> None:
        self.is_open = False

    def write(self, data: bytes) -> int:
        self.written.append(bytes(data))
        assert self.dialogue, f"unexpected request {data.hex(' ')}"
        want, reply = self.dialogue.pop(0)
        assert data == want, f"sent {data.hex(' ')}, expected {want.hex(' ')}"
        self._rx += reply or b""
        return len(data)

    def read(self, n: int = 1) -> bytes:
        out, self._rx = self._rx[:n], self._rx[n:]
        return out

    @property
    def in_waiting(self) -> int:
        return len(self._rx)

    def reset_input_buffer(self) -> None:
        self._rx = b""

    def reset_output_buffer(self) -> None:
        pass

    def assert_done(self) -> None:
        assert not self.dialogue, f"never sent: {[d[0].hex(' ') for d in self.dialogue]}"


@contextlib.contextmanager
def expected_protocol(
    factory: Callable[..., Any],
    dialogue: Sequence[tuple[str, str | None]] | Sequence[tuple[bytes, bytes | None]],
    **kw: Any,
) -> Iterator[Any]:
    """``factory(port, **kw)`` on an :class:`ExpectedVisa` (str commands) or an
    :class:`ExpectedSerial` (bytes); asserts on exit that every command was sent.

    >>> with expected_protocol(Agilent34401A, [("*IDN?", "HP,34401A,0,1")]) as dmm:
    ...     assert dmm.identity == "HP,34401A,0,1"
    """
    binary = bool(dialogue) and isinstance(dialogue[0][0], bytes)
    port: Any = ExpectedSerial(list(dialogue)) if binary else ExpectedVisa(list(dialogue))
    inst = factory(port, **kw)
    yield inst
    port.assert_done()
