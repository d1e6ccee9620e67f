"""``vectornav``: a VectorNav VN-100 IMU's binary output as the bench's rate stream.

The protocol is :mod:`gyrolab.vectornav` (VN-100 User Manual UM001; docs/instruments.md,
"VectorNav VN-100"). At connect the driver reads the model, serial number and firmware
(registers 1, 3, 4) and the reference-frame rotation (26, recorded, never changed), then
sets up the run, each register read first and each write read back:

1. asynchronous ASCII output off (register 6 = 0), so that replies are not buried in it;
2. with ``calibration = true`` (the default) the user's gyro compensation off (register 84 =
   identity, zero bias: the sensor's output with its factory calibration only);
3. the binary output register (``output_register``, 75 by default) set to this project's
   packet — ``TimeStartup``, ``UncompAccel``, ``UncompGyro``, ``Temp`` — at
   ``sample_rate_hz`` (divisor 800/rate) on ``serial_port``.

A failed write or read-back puts back what was written (newest first) and refuses the
bench. Closing — the run's end, a fault, Ctrl-C — writes the user's values back in reverse
order and reads them back. Nothing is saved to the unit's non-volatile memory (no
``$VNWNV``): a power cycle restores the user's settings too.

Samples: ``UncompGyro`` (float32 rad/s) as int32 counts of 1e-7 rad/s (``to_dps``; the
rounding, ≤ 2.9e-6 °/s, is far below the VN-100's noise), indexed by ``TimeStartup`` on the
``sample_rate_hz`` grid so that a lost packet is a gap and a repeated one is dropped; the
IMU temperature (``Temp``) with every sample (a ``[[unit]]`` with ``temperature =
"internal"`` records it).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import serial

from gyrolab import vectornav as vn
from gyrolab.instruments.registry import DriverSpec, OpenContext, register
from gyrolab.instruments.roles import (
    AdcRead,
    InstrumentError,
    InstrumentReport,
    InstrumentTimeout,
)
from gyrolab.instruments.stamped import StampedBlocks

NAME = "VN-100"
COUNTS_PER_RAD_S = 1e7


@dataclass(frozen=True)
class VectorNavConfig:
    """``driver = "vectornav"`` (docs/bench-config.md)."""

    driver: str = "vectornav"
    port: str = ""  # "/dev/ttyUSB0"
    baud_rate: int = 115200  # the unit's factory setting
    sample_rate_hz: float = 50.0  # 800 Hz / RateDivisor
    block_s: float = 0.5
    axes: int = 3
    serial_port: int = 1  # the unit's serial port this port is wired to (AsyncMode 1 or 2)
    output_register: int = 75  # Binary Output Register 1, 2 or 3 (75, 76, 77)
    calibration: bool = True  # the user's gyro compensation (register 84) off for the run
    timeout_s: float = 0.5  # per command (retried twice)
    serial: str = ""
    internal_temperature: bool = True  # the IMU's own sensor, in every packet

    def divisor(self) -> int:
        return round(vn.IMU_RATE_HZ / self.sample_rate_hz)

    def to_dps(self, counts: Any) -> Any:
        """Counts of 1e-7 rad/s → °/s."""
        return counts * (180.0 / math.pi / COUNTS_PER_RAD_S)

    def check(self, safe_state_mode: str) -> None:
        d = vn.IMU_RATE_HZ / self.sample_rate_hz if self.sample_rate_hz > 0 else 0.0
        if not (1 <= d <= 65535 and abs(d - round(d)) < 1e-9):
            raise ValueError("sample_rate_hz must be 800 Hz divided by a whole number")
        if self.serial_port not in (1, 2):
            raise ValueError("serial_port must be 1 or 2")
        if self.output_register not in vn.REG_BINARY_OUTPUTS:
            raise ValueError("output_register must be 75, 76 or 77")
        if self.axes != 3:
            raise ValueError("a VN-100 has 3 axes")


@dataclass
class RegisterChange:
    """One register the driver changed: the user's values and the run's (restored on
    close; not a declared :class:`~gyrolab.instruments.settings.Setting`)."""

    register: int
    previous: str
    written: str


@dataclass
class SetupReport:
    """What connect changed (in order) and what close put back."""

    changed: list[RegisterChange] = field(default_factory=list)
    restored: list[int] = field(default_factory=list)
    restore_failed: list[int] = field(default_factory=list)


class VectorNavStream:
    """A VN-100 in the rate-stream role (module doc). ``port`` is a path (pyserial opens
    it) or an open port (the expected-protocol harness)."""

    name = "adc"

    def __init__(
        self,
        port: Any,
        *,
        config: VectorNavConfig,
        timeout_s: float | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.config = config
        self.timeout_s = config.timeout_s if timeout_s is None else timeout_s
        self._clock = clock
        if isinstance(port, str):
            self.port_name = port
            self.ser: Any = serial.Serial(port, baudrate=config.baud_rate, timeout=0)
        else:
            self.port_name = getattr(port, "port", "?")
            self.ser = port
        self.decoder = vn.Decoder()
        self.stamped = StampedBlocks(1.0 / config.sample_rate_hz)
        self.identity: dict[str, str] = {}
        self.reference_frame = ""
        self.setup = SetupReport()
        self._pending: list[vn.Sample] = []
        self._closed = False

    # ---------------------------------------------------------------- commands
    def _io(self, timeout_s: float) -> list[list[str]]:
        """Read what arrived (waiting up to ``timeout_s`` for something); keep packets."""
        deadline = self._clock() + timeout_s
        while True:
            try:
                n = self.ser.in_waiting
                data = self.ser.read(n) if n else b""
            except (serial.SerialException, OSError) as e:
                raise InstrumentError(NAME, f"{self.port_name}: {e}") from None
            if data:
                samples, lines = self.decoder.feed(data)
                self._pending += samples
                return lines
            if self._clock() >= deadline:
                return []
            time.sleep(0.002)

    def command(self, kind: str, register: int, values: str = "") -> list[str]:
        """``$VN<kind>,<register>[,values]`` (RRG or WRG) → the reply's values; an error
        reply raises :class:`InstrumentError`, none (three tries) :class:`InstrumentTimeout`."""
        body = f"VN{kind},{register}" + (f",{values}" if values else "")
        what = f"{'write' if kind == 'WRG' else 'read'} of register {register}"
        for _try in range(3):
            try:
                self.ser.write(vn.line(body))
            except (serial.SerialException, OSError) as e:
                raise InstrumentError(NAME, f"{self.port_name}: {e}") from None
            deadline = self._clock() + self.timeout_s
            while self._clock() < deadline:
                for fields in self._io(max(0.0, deadline - self._clock())):
                    if fields[0] == "VNERR":
                        code = int(fields[1]) if len(fields) > 1 and fields[1].isdigit() else -1
                        why = vn.ERRORS.get(code, "unknown error")
                        raise InstrumentError(NAME, f"{what}: error {code} ({why})")
                    if fields[0] == f"VN{kind}" and len(fields) > 1 and _int(fields[1]) == register:
                        return fields[2:]
        raise InstrumentTimeout(NAME, f"{what}: no reply from {self.port_name}")

    def read_register(self, register: int) -> str:
        return ",".join(self.command("RRG", register))

    def write_register(self, register: int, values: str) -> None:
        """Write, then read back; InstrumentError unless the unit holds ``values``."""
        self.command("WRG", register, values)
        back = self.read_register(register)
        if not _same(back, values):
            raise InstrumentError(NAME, f"register {register}: wrote {values}, read {back}")

    # ---------------------------------------------------------------- connect / close
    def connect(self) -> None:
        """Identify the unit, set the run up (module doc); a failure puts back what was
        written and raises."""
        _drop_input(self.ser)
        c = self.config
        self.identity = {
            "model": self.read_register(vn.REG_MODEL),
            "serial": self.read_register(vn.REG_SERIAL),
            "firmware": self.read_register(vn.REG_FIRMWARE),
        }
        if not self.identity["model"].startswith("VN-"):
            raise InstrumentError(NAME, f"unexpected model {self.identity['model']!r}")
        self.reference_frame = self.read_register(vn.REG_REFERENCE_FRAME)
        plan = [(vn.REG_ASYNC_OUTPUT, "0")]
        if c.calibration:
            plan.append((vn.REG_GYRO_COMPENSATION, vn.GYRO_COMPENSATION_NONE))
        plan.append((c.output_register, vn.binary_output(c.serial_port, c.divisor())))
        try:
            for register, values in plan:
                previous = self.read_register(register)
                self.setup.changed.append(RegisterChange(register, previous, values))
                self.write_register(register, values)
        except InstrumentError as e:
            self.restore()
            left = self.setup.restore_failed
            tail = f"; NOT restored: registers {left}" if left else "; previous values put back"
            why = str(e).removeprefix(f"{NAME}: ")
            raise InstrumentError(NAME, f"setting up the run: {why}{tail}") from None

    def restore(self) -> None:
        """Write the user's values back, newest change first, each read back."""
        for s in reversed(self.setup.changed):
            if s.register in self.setup.restored:
                continue
            try:
                self.write_register(s.register, s.previous)
                self.setup.restored.append(s.register)
            except InstrumentError:
                # a unit that dropped the write being undone may still hold the user's value
                try:
                    unchanged = _same(self.read_register(s.register), s.previous)
                except InstrumentError:
                    unchanged = False
                (self.setup.restored if unchanged else self.setup.restore_failed).append(
                    s.register
                )

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self.restore()
        finally:
            try:
                self.ser.close()
            except Exception:
                pass
        if self.setup.restore_failed:
            raise InstrumentError(
                NAME,
                f"the user's settings could not all be put back: registers "
                f"{self.setup.restore_failed} still changed",
            )

    # ---------------------------------------------------------------- streaming
    def read(self, timeout_s: float) -> AdcRead:
        """Packets received so far as gap-free blocks (lost packets: gaps)."""
        self._io(timeout_s)
        got, self._pending = self._pending, []
        self.stamped.counts["frames_bad"] = self.decoder.stats.crc_errors
        t = np.array([s.time_ns for s in got], dtype=np.float64) * 1e-9
        gyro = np.array([s.gyro_rad_s for s in got], dtype=np.float64).reshape(-1, 3)
        counts = np.rint(gyro * COUNTS_PER_RAD_S).astype(np.int32)
        temp = np.array([s.temperature_c for s in got], dtype=float)
        return AdcRead(blocks=self.stamped.blocks(t, counts, temp))

    def counters(self) -> dict[str, int]:
        return dict(self.stamped.counts)

    def reports(self) -> list[InstrumentReport]:
        return []

    def describe(self) -> dict[str, Any]:
        c = self.config
        return {
            "driver": c.driver,
            "port": self.port_name,
            **self.identity,
            "serial": c.serial or self.identity.get("serial", ""),
            "sample_rate_hz": c.sample_rate_hz,
            "axes": 3,
            "counts": "1e-7 rad/s (UncompGyro, float32 rad/s)",
            "calibration_mode": c.calibration,
            "reference_frame_rotation": self.reference_frame,
            "registers_changed": {
                str(s.register): [s.previous, s.written] for s in self.setup.changed
            },
            "internal_temperature": True,
        }


def _int(s: str) -> int:
    try:
        return int(s)
    except ValueError:
        return -1


def _same(a: str, b: str) -> bool:
    """Register values equal as the unit writes them: numbers compared as numbers (``05`` is
    hex 5 in an output group, ``1.0`` is ``1``), words as words."""
    fa, fb = a.split(","), b.split(",")
    if len(fa) != len(fb):
        return False
    for x, y in zip(fa, fb, strict=True):
        if x == y:
            continue
        try:
            if float(x) != float(y):
                return False
        except ValueError:
            try:
                if int(x, 16) != int(y, 16):
                    return False
            except ValueError:
                return False
    return True


def _drop_input(ser: Any) -> None:
    """Drop whatever the unit sent before we spoke (a stream already running)."""
    try:
        ser.reset_input_buffer()
    except (serial.SerialException, OSError, AttributeError):
        pass


def open_vectornav(c: VectorNavConfig, ctx: OpenContext) -> VectorNavStream:
    stream = VectorNavStream(
        ctx.address, config=c, timeout_s=ctx.timeout(c.timeout_s), clock=ctx.clock
    )
    try:
        stream.connect()
    except BaseException:
        stream._closed = True  # connect put back what it wrote; nothing left to restore
        try:
            stream.ser.close()
        except Exception:
            pass
        raise
    return stream


SPEC = register(
    DriverSpec(
        name="vectornav",
        role="rate_stream",
        config=VectorNavConfig,
        open=open_vectornav,
        address_key="port",
        sim_backend="VN100",
        sim_address="vn_port",
        description="a VectorNav VN-100 IMU's binary output (UncompGyro, Temp)",
    )
)
