"""A simulated VectorNav VN-100 on a pseudo-terminal: the protocol of
:mod:`gyrolab.vectornav` on the wire, its IMU from gyrolab's simulator.

* **Registers** (UM001 §5.2, §6.2): model, serial number, firmware (read-only: a write is
  ``$VNERR,09``), baud rate, asynchronous ASCII output type and rate (6, 7), reference frame
  rotation (26), the Binary Output Registers 75-77 and the gyro compensation (84). Reads and
  writes answer as the manual's examples do (a write echoes the command); a bad checksum is
  ``$VNERR,03``, an unknown command ``04``, an unknown register ``08``, a wrong number of
  values ``05``/``06``, a value out of range ``07``. Nothing is kept over a restart.
* **Output**: with register 6 ≠ 0, ``$VNYMR`` lines at register 7's rate (yaw, pitch, roll
  zero; magnetometer zero; acceleration and angular rate) — the ASCII stream a unit sends
  out of the box; with a Binary Output Register's AsyncMode 1 or 3 (this pty is serial
  port 1) and this project's field selection, binary packets at 800 Hz / RateDivisor (every
  ``m``-th simulated sample, ``m`` = rate·divisor/800; other selections are not streamed).
* **The IMU**: three axes of :class:`gyrolab.sim.physics.Physics`
  (:func:`gyrolab.sim.fc_imus.imu_physics`: a MEMS IMU on a self-heated board) in the
  bench's chamber; ``UncompGyro`` = C·(G − B) with register 84's C and B (UM001 does not say
  whether the user's compensation reaches ``UncompGyro``; here it does, which is why the
  driver's calibration mode turns it off), ``Temp`` the die sensor's reading, ``UncompAccel``
  gravity on −Z with white noise, ``TimeStartup`` the bench time in ns.
* **Faults**: ``refuse_writes`` — register → error code (answered ``$VNERR,<code>``) or
  None (never answered, as a unit that dropped the command).

Driven by the bench's tick thread like the simulated flight controller (:meth:`advance`
under the bench lock, :meth:`send` outside it); answers commands on its own thread.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gyrolab import vectornav as vn
from gyrolab.sim.bench.serial_pty import PtyDevice, PtyPort

DEG2RAD = np.pi / 180.0
GRAVITY_M_S2 = 9.80665

REGISTERS = {  # register → (values, writable); UM001 factory defaults where it gives them
    vn.REG_MODEL: ("VN-100 (simulated)", False),
    2: ("2", False),  # hardware revision
    vn.REG_SERIAL: ("0100000001", False),
    vn.REG_FIRMWARE: ("2.1.0.0", False),
    5: ("115200", True),
    vn.REG_ASYNC_OUTPUT: ("14", True),  # VNYMR
    7: ("40", True),
    vn.REG_REFERENCE_FRAME: ("1,0,0,0,1,0,0,0,1", True),
    75: ("0,1,00", True),
    76: ("0,1,00", True),
    77: ("0,1,00", True),
    # a user's own compensation, from a field calibration: a small bias per axis
    vn.REG_GYRO_COMPENSATION: ("1,0,0,0,1,0,0,0,1,0.0012,-0.0008,0.0005", True),
}
VALUE_COUNTS = {5: 1, 6: 1, 7: 1, 26: 9, 84: 12}


@dataclass
class VnSpec:
    """A VN-100 for :class:`gyrolab.sim.bench.SimBench` (``device=``): the bench makes its pty
    (``bench.device_port``, link ``vn`` in its work directory, resource ``vn_port``)."""

    imus: list[list[Any]]  # one IMU: its x, y, z Physics
    seed: int = 0
    registers: dict[int, str] = field(default_factory=dict)
    refuse_writes: dict[int, int | None] = field(default_factory=dict)
    port_name: str = "vn"

    def build(self, port: PtyPort, write_timeout_s: float) -> SimVectorNav:
        return SimVectorNav(
            self.imus[0],
            port,
            seed=self.seed,
            registers=dict(self.registers),
            refuse_writes=dict(self.refuse_writes),
            write_timeout_s=write_timeout_s,
        )


@dataclass
class VnStats:
    packets: int = 0
    ascii_lines: int = 0
    commands: int = 0
    errors: int = 0
    refused: int = 0


class SimVectorNav(PtyDevice):
    """See the module doc."""

    thread_name = "sim-vn100"

    def __init__(
        self,
        axes: list[Any],
        port: PtyPort,
        *,
        seed: int = 0,
        registers: dict[int, str] | None = None,
        refuse_writes: dict[int, int | None] | None = None,
        accel_noise_m_s2: float = 0.01,
        write_timeout_s: float = 0.5,
    ) -> None:
        if len(axes) != 3 or len({p.rate_hz for p in axes}) != 1:
            raise ValueError("a VN-100 is three axes at one rate")
        self.axes = axes
        self.rate_hz = float(axes[0].rate_hz)
        self.init_device(port, write_timeout_s)
        self.reg = {k: v for k, (v, _w) in REGISTERS.items()}
        self.writable = {k for k, (_v, w) in REGISTERS.items() if w}
        self.reg.update(registers or {})
        self.refuse_writes = dict(refuse_writes or {})
        self.accel_sd = accel_noise_m_s2
        self.rng = np.random.default_rng([int(seed), 3301])
        self.stats = VnStats()
        self._lock = threading.Lock()  # registers
        self._rx = b""
        self.last_temperature_c = float("nan")

    # ------------------------------------------------------------------ world
    @property
    def chamber_physics(self) -> Any:
        return self.axes[0]

    def set_setpoint(self, setpoint_c: float) -> None:
        for p in self.axes:
            p.set_setpoint(setpoint_c)

    def prefetch(self, n: int) -> None:
        for p in self.axes:
            p.prefetch(n)

    def _compensation(self) -> tuple[np.ndarray, np.ndarray]:
        v = [float(x) for x in self.reg[vn.REG_GYRO_COMPENSATION].split(",")]
        return np.asarray(v[:9]).reshape(3, 3), np.asarray(v[9:12])

    def _binary_every(self) -> int:
        """Samples between packets (0: no binary output on this port)."""
        for r in vn.REG_BINARY_OUTPUTS:
            f = self.reg[r].split(",")
            try:
                mode, div = int(f[0]), int(f[1])
                sel = (int(f[2], 16), *(int(x, 16) for x in f[3:]))
            except (ValueError, IndexError):
                continue
            if mode in (1, 3) and sel == (vn.GROUPS, *vn.FIELDS):
                return max(1, round(self.rate_hz * div / vn.IMU_RATE_HZ))
        return 0

    def advance(self, n: int) -> bytes:
        """Advance the IMU by ``n`` samples; the bytes due on the wire."""
        blocks = [p.advance(n) for p in self.axes]
        x = self.axes[0]
        t = blocks[0].first_index / self.rate_hz + np.arange(n) / self.rate_hz
        raw = np.column_stack([b.rate_dps for b in blocks]) * DEG2RAD
        temps = x.die_sensor.zero_c + x.die_sensor_codes(blocks[0].die_trace) * (
            x.die_sensor.c_per_lsb
        )
        acc = np.tile([0.0, 0.0, -GRAVITY_M_S2], (n, 1)) + self.accel_sd * (
            self.rng.standard_normal((n, 3))
        )
        with self._lock:
            c, b = self._compensation()
            every = self._binary_every()
            ador = self.reg[vn.REG_ASYNC_OUTPUT]
            adof = float(self.reg[7])
        gyro = (raw - b) @ c.T
        self.last_temperature_c = float(temps[-1])
        first = int(blocks[0].first_index)
        out: list[bytes] = []
        if every:
            for i in np.flatnonzero((first + np.arange(n)) % every == 0):
                s = vn.Sample(
                    int(round(t[i] * 1e9)),
                    tuple(float(v) for v in acc[i]),
                    tuple(float(v) for v in gyro[i]),
                    float(temps[i]),
                )
                out.append(vn.packet(s))
                self.stats.packets += 1
        if ador != "0" and adof > 0:
            m = max(1, round(self.rate_hz / adof))
            for i in np.flatnonzero((first + np.arange(n)) % m == 0):
                a, g = acc[i], gyro[i]
                out.append(
                    vn.line(
                        "VNYMR,+000.000,+000.000,+000.000,+0.0000,+0.0000,+0.0000,"
                        f"{a[0]:+07.3f},{a[1]:+07.3f},{a[2]:+07.3f},"
                        f"{g[0]:+.6f},{g[1]:+.6f},{g[2]:+.6f}"
                    )
                )
                self.stats.ascii_lines += 1
        return b"".join(out)

    def send(self, data: bytes, timeout_s: float | None = None) -> None:
        if data:
            self.write(data, timeout_s)

    # ------------------------------------------------------------------ commands
    def on_bytes(self, data: bytes) -> None:
        self._rx += data
        while b"\n" in self._rx:
            raw, _, self._rx = self._rx.partition(b"\n")
            reply = self.handle(raw.rstrip(b"\r"))
            if reply:
                self.send(reply)
        self._rx = self._rx[-512:]

    def handle(self, raw: bytes) -> bytes:
        """The reply to one command line (b"": none)."""
        if not raw.startswith(b"$"):
            return b""
        self.stats.commands += 1
        body, _, cs = raw[1:].rpartition(b"*")
        if cs.upper() not in (b"XX", b"XXXX") and vn.parse_line(raw) is None:
            return self._error(3)
        f = body.decode("ascii", "replace").split(",")
        if f[0] not in ("VNRRG", "VNWRG"):
            return self._error(4)
        if len(f) < 2:
            return self._error(5)
        try:
            reg = int(f[1])
        except ValueError:
            return self._error(7)
        with self._lock:
            if reg not in self.reg:
                return self._error(8)
            if f[0] == "VNRRG":
                return vn.line(f"VNRRG,{f[1]},{self.reg[reg]}")
            if reg in self.refuse_writes:
                self.stats.refused += 1
                code = self.refuse_writes[reg]
                return b"" if code is None else self._error(code)
            if reg not in self.writable:
                return self._error(9)
            values = f[2:]
            problem = _check_values(reg, values)
            if problem:
                return self._error(problem)
            self.reg[reg] = ",".join(values)
        return vn.line(body.decode("ascii"))

    def _error(self, code: int) -> bytes:
        self.stats.errors += 1
        return vn.line(f"VNERR,{code:02d}")


def _check_values(reg: int, values: list[str]) -> int:
    """The error code a write of ``values`` to ``reg`` gets (0: accepted)."""
    if reg in vn.REG_BINARY_OUTPUTS:
        if len(values) < 3:
            return 5
        try:
            mode, div, groups = int(values[0]), int(values[1]), int(values[2], 16)
            masks = [int(v, 16) for v in values[3:]]
        except ValueError:
            return 7
        if not (0 <= mode <= 3 and 1 <= div <= 65535) or groups & 0x80:
            return 7
        active = bin(groups).count("1")
        return 0 if len(masks) == active else (5 if len(masks) < active else 6)
    want = VALUE_COUNTS.get(reg, 1)
    if len(values) != want:
        return 5 if len(values) < want else 6
    try:
        [float(v) for v in values]
    except ValueError:
        return 7
    return 0
