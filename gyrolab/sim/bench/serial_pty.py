"""Pseudo-terminals that look like the bench's serial ports.

:class:`PtyPort` opens a pty pair (``os.openpty``): the simulated instrument holds the
master, the driver opens the slave path with pyserial exactly as it would open
``/dev/ttyUSB0``. A stable symlink (like udev's ``/dev/serial/by-id/…``) points at the
current slave, so a simulated unplug/replug (:meth:`PtyPort.disconnect` /
:meth:`PtyPort.connect`) makes the driver see EIO, then a missing device, then the same
path again — what a real USB-serial adapter does.
"""

from __future__ import annotations

import contextlib
import errno
import os
import select
import threading
import time
import tty
from pathlib import Path

# How often a write waiting for room looks at its ``cancel`` event (wall s).
CANCEL_POLL_S = 0.05

# A device whose last write was cut short (nobody drains its port) waits at most this long
# per write until one completes again: a UART transmits regardless, so a port nobody reads
# costs the tick thread 50 ms a write, not its whole back-pressure wait.
CONGESTED_WAIT_S = 0.05


class PortClosed(Exception):
    """The simulated port is unplugged."""


class PtyPort:
    """One simulated serial port. ``link`` is the stable path drivers open (optional)."""

    def __init__(self, link: str | os.PathLike[str] | None = None) -> None:
        self.link = None if link is None else Path(link)
        self._master: int | None = None
        self._slave: int | None = None
        self.slave_name = ""
        self._lock = threading.Lock()
        self.generation = 0  # +1 per (re)connect
        # since a :meth:`write_capped` was cut short, until one completes
        self.congested = False

    @property
    def path(self) -> str:
        """The path a driver opens."""
        return str(self.link) if self.link is not None else self.slave_name

    @property
    def connected(self) -> bool:
        return self._master is not None

    def connect(self) -> None:
        """Plug the port in: a fresh pty, the link pointed at it."""
        with self._lock:
            if self._master is not None:
                return
            master, slave = os.openpty()
            # Raw mode on our copy of the slave: no echo, no CR/LF translation, no
            # signals, before any driver opens it (pyserial sets raw mode again).
            tty.setraw(slave)
            os.set_blocking(master, False)
            self._master, self._slave = master, slave
            self.slave_name = os.ttyname(slave)
            if self.link is not None:
                tmp = self.link.with_name(self.link.name + ".tmp")
                with contextlib.suppress(FileNotFoundError):
                    tmp.unlink()
                tmp.symlink_to(self.slave_name)
                os.replace(tmp, self.link)  # atomic: never a half-made link
            self.generation += 1

    def disconnect(self) -> None:
        """Unplug: the driver's next read fails (EIO) and the path disappears."""
        with self._lock:
            if self.link is not None:
                with contextlib.suppress(FileNotFoundError):
                    self.link.unlink()
            for fd in (self._master, self._slave):
                if fd is not None:
                    with contextlib.suppress(OSError):
                        os.close(fd)
            self._master = self._slave = None

    close = disconnect

    def write(
        self, data: bytes, timeout_s: float = 0.5, cancel: threading.Event | None = None
    ) -> int:
        """Write ``data``; waits up to ``timeout_s`` while the pty buffer is full
        (back-pressure from a slow reader; every byte the reader takes starts the wait
        again), then gives up on the rest (a UART would overrun). ``cancel`` set ends the
        wait at once (it is looked at every ``CANCEL_POLL_S``). Returns bytes written;
        raises :class:`PortClosed` when unplugged."""
        mv = memoryview(data)
        done = 0
        give_up = None  # monotonic time at which the current wait for room ends
        while done < len(mv):
            fd = self._master
            if fd is None:
                raise PortClosed(self.path)
            try:
                done += os.write(fd, mv[done:])
                give_up = None
                continue
            except BlockingIOError:
                pass
            except OSError as e:
                if e.errno in (errno.EIO, errno.EBADF):
                    raise PortClosed(self.path) from e
                raise
            now = time.monotonic()
            give_up = now + timeout_s if give_up is None else give_up
            left = give_up - now
            if left <= 0 or (cancel is not None and cancel.is_set()):
                break
            try:
                select.select([], [fd], [], left if cancel is None else min(left, CANCEL_POLL_S))
            except (OSError, ValueError) as e:
                raise PortClosed(self.path) from e
        return done

    def write_capped(
        self, data: bytes, timeout_s: float, cancel: threading.Event | None = None
    ) -> int:
        """:meth:`write` for a device that transmits on its own clock (a sensor's stream,
        a device's replies): while the port is :attr:`congested` — since a write was cut
        short, until one completes — the wait is at most ``CONGESTED_WAIT_S``, so a port
        nobody drains costs the device 50 ms a write, not its whole back-pressure wait;
        a reader that comes back drains the pty, a write completes, the wait is restored."""
        if self.congested:
            timeout_s = min(timeout_s, CONGESTED_WAIT_S)
        done = self.write(data, timeout_s, cancel)
        self.congested = done < len(data)
        return done

    def read(self, timeout_s: float = 0.05, max_bytes: int = 65536) -> bytes:
        """Bytes the driver sent, waiting up to ``timeout_s``; b"" if none."""
        fd = self._master
        if fd is None:
            raise PortClosed(self.path)
        try:
            r, _, _ = select.select([fd], [], [], timeout_s)
        except (OSError, ValueError) as e:
            raise PortClosed(self.path) from e
        if not r:
            return b""
        try:
            return os.read(fd, max_bytes)
        except BlockingIOError:
            return b""
        except OSError as e:
            if e.errno == errno.EIO:
                # No process has the slave open besides us: nothing to read. (Linux
                # reports EIO on the master only when every slave fd is closed.)
                return b""
            if e.errno == errno.EBADF:
                raise PortClosed(self.path) from e
            raise


class PtyDevice:
    """A simulated device on a :class:`PtyPort` (the flight controller, the VN-100): it
    answers on its own thread — :meth:`on_bytes` gets whatever the driver sent — and writes
    with :meth:`write`, under one lock (the tick thread streams, the serving thread
    replies). A subclass calls :meth:`init_device` from its constructor."""

    thread_name = "sim-device"

    def init_device(self, port: PtyPort, write_timeout_s: float) -> None:
        self.port = port
        self.write_timeout_s = write_timeout_s
        self._write_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: BaseException | None = None

    def on_bytes(self, data: bytes) -> None:
        """What the driver sent (the serving thread)."""
        raise NotImplementedError

    def write(self, data: bytes, timeout_s: float | None = None) -> int | None:
        """Write ``data`` (back-pressure or overrun as :meth:`PtyPort.write`), waiting for
        room up to ``timeout_s`` (None: ``write_timeout_s``; ``CONGESTED_WAIT_S`` while
        the port is congested, i.e. since a write was cut short, until one completes);
        :meth:`stop` ends a wait. The bytes written, None while unplugged."""
        wait = self.write_timeout_s if timeout_s is None else timeout_s
        with self._write_lock:
            try:
                return self.port.write_capped(data, wait, cancel=self._stop)
            except PortClosed:
                return None

    def start(self) -> None:
        self._thread = threading.Thread(target=self._serve, name=self.thread_name, daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)

    def _serve(self) -> None:
        try:
            while not self._stop.is_set():
                try:
                    data = self.port.read(timeout_s=0.05)
                except PortClosed:
                    self._stop.wait(0.05)
                    continue
                if data:
                    self.on_bytes(data)
        except BaseException as e:  # surfaced by the bench; never silent
            self.error = e
            raise
