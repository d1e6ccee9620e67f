"""``mavlink``: one IMU of a PX4 or ArduPilot flight controller as the bench's rate stream.

A flight controller in the chamber is a multi-unit bench whose units are its IMUs
(docs/bench-config.md, "A flight controller"): each ``[[unit]]`` names the same port and
its ``imu`` (0, 1, 2), ``temperature = "internal"`` (the IMU's own sensor, in the same
message). The units share one connection (:class:`~gyrolab.instruments.mavlink_link.MavlinkLink`,
opened with the first unit and closed with the last).

Per IMU the firmware streams RAW_IMU / SCALED_IMU2 / SCALED_IMU3 (ArduPilot) or SCALED_IMU /
SCALED_IMU2 / SCALED_IMU3 (PX4) at ``sample_rate_hz`` (MAV_CMD_SET_MESSAGE_INTERVAL):
gyro int16 mrad/s, accelerometer int16 mG, temperature cdegC
(:mod:`gyrolab.autopilot.mavlink` for the definitions and rate limits). The counts the
recording keeps (``/gyro/adc``) are those mrad/s; ``to_dps`` converts them. Samples are
indexed by the controller's time stamp on the ``sample_rate_hz`` grid, so a lost message
is a gap and a repeated one is dropped.

**Calibration data are the sensor's own output** (``calibration = true``, the default).
At connect the driver reads, then sets for the whole run: PX4 ``TC_G_ENABLE`` = 0, every
IMU's ``CAL_GYROn_{X,Y,Z}OFF`` = 0, ``SENS_BOARD_ROT`` = 0 and ``SENS_BOARD_{X,Y,Z}_OFF`` = 0
— and, when the thermal compensation was on or the board rotated, reboots the controller,
because PX4 keeps the last published thermal offsets until then (``TC_G_ENABLE`` and
``SENS_BOARD_ROT`` are ``@reboot_required``), and again after putting the user's values back;
ArduPilot ``INS_TCALn_ENABLE`` = 0, ``INS_GYROFFS_*``/``INS_GYR2OFFS_*``/``INS_GYR3OFFS_*``
= 0, ``AHRS_ORIENTATION`` = 0 (which ArduPilot takes into use within a second: samples are
kept from 2 s of controller time after the change). Each write is read back; a failed one
puts back what was written and refuses the bench. When the last unit closes — the run's
end, a fault, Ctrl-C — the user's values are written back and read back. What was changed
is in the recording's ``bench`` metadata (``parameters_changed``: name → [user's, run's])
even if the process dies. ``calibration = false`` leaves the parameters alone: the
firmware's compensation stays on (a verification run).
"""

from __future__ import annotations

import math
import threading
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from gyrolab.autopilot import ardupilot as ap
from gyrolab.autopilot import mavlink as ml
from gyrolab.autopilot import px4
from gyrolab.instruments.mavlink_link import MavlinkLink, WriteReport, write_parameters
from gyrolab.instruments.registry import DriverSpec, OpenContext, register
from gyrolab.instruments.roles import (
    AdcRead,
    InstrumentError,
    InstrumentReport,
)
from gyrolab.instruments.stamped import StampedBlocks

NAME = "flight controller"
ORIENTATION_SETTLE_S = 2.0  # ArduPilot applies AHRS_ORIENTATION at most once a second


@dataclass(frozen=True)
class MavlinkFcConfig:
    """``driver = "mavlink"``: one IMU of a flight controller (module doc)."""

    driver: str = "mavlink"
    port: str = ""  # "/dev/ttyACM0" (USB), a telemetry UART, or "tcp:HOST:PORT" (SITL)
    baud_rate: int = 921600  # ignored by USB CDC-ACM
    imu: int = 0  # the IMU instance: 0, 1, 2
    firmware: str = "auto"  # "auto" (from the HEARTBEAT), "px4" or "ardupilot"
    sample_rate_hz: float = 50.0  # requested message rate (MAV_CMD_SET_MESSAGE_INTERVAL)
    block_s: float = 0.5
    axes: int = 3
    calibration: bool = True  # sensor frame, compensation and offsets off during the run
    timeout_s: float = 1.0  # per MAVLink request (retried 3 times)
    serial: str = ""
    internal_temperature: bool = True  # the IMU's own sensor, in every message

    def to_dps(self, counts: Any) -> Any:
        """int16 mrad/s → °/s."""
        return counts * (1e-3 * 180.0 / math.pi)

    def check(self, safe_state_mode: str) -> None:
        if self.firmware not in ("auto", *ml.FIRMWARES):
            raise ValueError("firmware must be auto, px4 or ardupilot")
        if not 0 <= self.imu <= 2:
            raise ValueError("imu must be 0, 1 or 2 (the IMU instance)")
        if self.axes != 3:
            raise ValueError("a flight controller's IMU has 3 axes")
        hi = max(ml.MAX_RATE_HZ.values())
        if not 0 < self.sample_rate_hz <= hi:
            raise ValueError(f"sample_rate_hz must be in (0, {hi:g}] (docs/instruments.md)")


class _Shared:
    """The connection the units of one controller share, and its calibration setup."""

    def __init__(self, link: MavlinkLink, calibration: bool) -> None:
        self.link = link
        self.calibration = calibration
        self.users = 0
        self.setup: WriteReport | None = None
        self.valid_from = -math.inf  # controller time from which samples are kept
        self.restore: WriteReport | None = None
        self.rebooted = False  # calibration mode rebooted a PX4: closing reboots it again
        self.device_ids: dict[int, int] = {}
        self.parameters: dict[str, float] = {}
        self.lock = threading.Lock()


_LINKS: dict[str, _Shared] = {}
_LINKS_LOCK = threading.Lock()


def calibration_settings(firmware: str, link: MavlinkLink) -> list[tuple[str, float, int]]:
    """What calibration mode sets (module doc): ``(name, value, type)`` for the parameters
    this vehicle has (each read first; absent ones, e.g. a third IMU's, skipped)."""
    want: list[str] = []
    if firmware == "px4":
        want += ["TC_G_ENABLE", px4.BOARD_ROTATION, *px4.BOARD_LEVEL_OFFSETS]
        for s in range(px4.TC_SLOTS):
            want += px4.cal_offset_names(s)
    else:
        want += [f"INS_TCAL{k + 1}_ENABLE" for k in range(ap.IMUS)]
        for k in range(ap.IMUS):
            want += ap.gyro_offset_names(k)
        want.append(ap.BOARD_ORIENTATION)
    out = []
    for name in want:
        try:
            _v, ptype = link.param_read(name)
        except InstrumentError:
            continue  # the vehicle has no such parameter (fewer IMUs)
        out.append((name, 0.0, ptype))
    return out


def tc_parameters(firmware: str, link: MavlinkLink, instance: int) -> dict[str, float]:
    """The compensation parameters in force for IMU ``instance`` (for the recording)."""
    names = (
        [n for s in range(px4.TC_SLOTS) for n in px4.tc_names(s)[:5]] + [px4.BOARD_ROTATION]
        if firmware == "px4"
        else ap.tcal_names(instance)
        + ap.gyro_offset_names(instance)
        + [ap.caltemp_name(instance), ap.BOARD_ORIENTATION]
    )
    out = {}
    for n in dict.fromkeys(names):
        try:
            out[n] = link.param_read(n)[0]
        except InstrumentError:
            continue
    return out


class MavlinkImuStream:
    """One IMU of the shared connection in the rate-stream role."""

    name = "adc"

    def __init__(self, shared: _Shared, config: MavlinkFcConfig) -> None:
        self.shared = shared
        self.link = shared.link
        self.config = config
        self.stamped = StampedBlocks(1.0 / config.sample_rate_hz)
        self._closed = False

    @property
    def firmware(self) -> str:
        return self.link.firmware

    def read(self, timeout_s: float) -> AdcRead:
        """IMU messages received so far as gap-free blocks (lost messages: gaps)."""
        self.link.pump(timeout_s)
        q = self.link.imu.setdefault(self.config.imu, deque())
        got: list[Any] = []
        while q:
            got.append(q.popleft())
        valid = [s for s in got if s.t >= self.shared.valid_from]
        t = np.array([s.t for s in valid], dtype=np.float64)
        gyro = np.array([s.gyro for s in valid], dtype=np.int32).reshape(-1, 3)
        temp = np.array([s.temperature_c for s in valid], dtype=float)
        return AdcRead(blocks=self.stamped.blocks(t, gyro, temp))

    def counters(self) -> dict[str, int]:
        return dict(self.stamped.counts)

    def reports(self) -> list[InstrumentReport]:
        return []

    def describe(self) -> dict[str, Any]:
        s = self.shared
        changed = {}
        if s.setup is not None:
            changed = {n: [s.setup.previous[n], v] for n, v in s.setup.written.items()}
        return {
            "driver": self.config.driver,
            "port": self.link.address,
            "firmware": self.firmware,
            "imu": self.config.imu,
            "message": ml.message_for(self.firmware, self.config.imu),
            "device_id": s.device_ids.get(self.config.imu, 0),
            "sample_rate_hz": self.config.sample_rate_hz,
            "serial": self.config.serial,
            "axes": 3,
            "counts": "mrad/s (int16 of the MAVLink message)",
            "calibration_mode": s.calibration,
            "parameters_changed": changed,
            "parameters": s.parameters.get(self.config.imu, {}),
            "internal_temperature": True,
        }

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        release(self.shared, self.config)


def _setup_calibration(shared: _Shared) -> None:
    link = shared.link
    settings = calibration_settings(link.firmware, link)
    rep = write_parameters(link, settings)
    shared.setup = rep
    if not rep.ok:
        name, why = rep.failed or ("?", "?")
        left = f"; NOT restored: {', '.join(rep.restore_failed)}" if rep.restore_failed else ""
        raise InstrumentError(
            NAME, f"calibration settings: {name}: {why}; previous values put back{left}"
        )
    # PX4 keeps published thermal offsets until a reboot; TC_G_ENABLE and SENS_BOARD_ROT
    # are @reboot_required
    if link.firmware == "px4" and (
        rep.previous.get("TC_G_ENABLE", 0) == 1 or rep.previous.get(px4.BOARD_ROTATION, 0) != 0
    ):
        link.reboot()
        shared.rebooted = True
    # keep samples only once every change is in use (ArduPilot: orientation within 1 s)
    link.pump(0.2)
    latest = max((q[-1].t for q in link.imu.values() if q), default=-math.inf)
    shared.valid_from = latest + ORIENTATION_SETTLE_S if link.firmware == "ardupilot" else latest


def release(shared: _Shared, config: MavlinkFcConfig) -> None:
    """A unit closes: stop its stream; the last one puts the user's parameters back and
    closes the connection."""
    with _LINKS_LOCK:
        shared.users -= 1
        last = shared.users <= 0
        if last:
            _LINKS.pop(shared.link.address, None)
    link = shared.link
    try:
        if link.firmware:
            link.set_imu_rate(config.imu, 0)
    except (InstrumentError, OSError):
        pass
    if not last:
        return
    try:
        setup = shared.setup
        if setup is not None and setup.written:
            back = [(n, setup.previous[n], setup.types[n]) for n in reversed(setup.written)]
            shared.restore = write_parameters(link, back)
            if not shared.restore.ok:
                name, why = shared.restore.failed or ("?", "?")
                left = [n for n, _v, _t in back if n not in shared.restore.written]
                raise InstrumentError(
                    NAME,
                    f"the user's parameters could not all be put back ({name}: {why}); "
                    f"still changed: {', '.join(left)}",
                )
            if shared.rebooted:
                link.reboot()  # the user's compensation and rotation in use again
    finally:
        link.close()


def open_mavlink(c: MavlinkFcConfig, ctx: OpenContext) -> MavlinkImuStream:
    """Open (or join) the controller's connection at ``ctx.address``, set it up for the
    run once (calibration mode) and stream IMU ``c.imu``."""
    with _LINKS_LOCK:
        shared = _LINKS.get(ctx.address)
        if shared is None:
            link = MavlinkLink(
                ctx.address, baudrate=c.baud_rate, timeout_s=ctx.timeout(c.timeout_s)
            )
            shared = _Shared(link, c.calibration)
            _LINKS[ctx.address] = shared
        elif shared.calibration != c.calibration:
            raise InstrumentError(NAME, "the IMUs of one controller differ in `calibration`")
        shared.users += 1
    stream = MavlinkImuStream(shared, c)
    try:
        with shared.lock:
            link = shared.link
            if not link.firmware:
                fw = link.connect(ctx.timeout(10.0) * 5)
                if c.firmware not in ("auto", fw):
                    raise InstrumentError(
                        NAME, f"{ctx.address} runs {fw}, the bench says {c.firmware}"
                    )
                if c.calibration:
                    _setup_calibration(shared)
            if c.imu not in shared.parameters:
                shared.parameters[c.imu] = tc_parameters(link.firmware, link, c.imu)
                if link.firmware == "px4":  # calibration slot k is IMU k's (docs)
                    try:
                        dev = link.param_read(px4.cal_id_name(c.imu))[0]
                    except InstrumentError:
                        dev = 0
                    shared.device_ids[c.imu] = int(dev)
            link.set_imu_rate(c.imu, c.sample_rate_hz)
    except BaseException:
        stream.close()
        raise
    return stream


SPEC = register(
    DriverSpec(
        name="mavlink",
        role="rate_stream",
        config=MavlinkFcConfig,
        open=open_mavlink,
        address_key="port",
        sim_backend="FC",
        sim_address="fc_port",
        description="one IMU of a PX4/ArduPilot flight controller over MAVLink",
    )
)
