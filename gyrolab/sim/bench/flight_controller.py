"""A simulated flight controller (PX4 or ArduPilot) speaking MAVLink on a pseudo-terminal.

What it models, each from the firmware's source (docs/instruments.md, "Flight controllers";
the rules themselves are :mod:`gyrolab.autopilot`):

* **IMUs.** Each IMU is three axes of :class:`gyrolab.sim.physics.Physics` (one per axis,
  its own effects and noise) in the same chamber as the bench: the board's own heating
  (``gyro_power_w`` through ``case_resistance_k_per_w``) warms the IMU package above the
  chamber air, and the die follows it with its lag; the IMU's temperature sensor reads the
  die (:class:`gyrolab.sim.sensors.DieThermometer`: offset, noise, quantisation). The
  accelerometer reads gravity on the sensor's −Z with white noise.
* **The firmware's thermal compensation, exactly as its source applies it.** PX4:
  ``TC_G*`` offsets computed by the ``temperature_compensation`` module once a second and
  republished only when a gyro's temperature moved more than 1 °C (any gyro's move
  republishes every gyro's current offsets), ``Correct = R_board · (raw − thermal −
  CAL_GYROn_OFF)`` with ``SENS_BOARD_ROT``; device ids matched by ``TC_Gi_ID``. ArduPilot:
  ``INS_TCALn`` (35 °C, ×1e6, ``INS_GYRn_CALTEMP``) only while ENABLE is 1, then the offsets,
  then ``AHRS_ORIENTATION``. Parameter changes act at once, as they do on the vehicle
  (PX4 ``parameter_update``; ArduPilot reads the values live).
* **MAVLink** (pymavlink's ``common`` dialect, MAVLink 2): HEARTBEAT once a second
  (``autopilot`` = MAV_AUTOPILOT_PX4 or ARDUPILOTMEGA); the IMU messages of
  :data:`gyrolab.autopilot.mavlink.IMU_MESSAGES` at the interval a
  ``MAV_CMD_SET_MESSAGE_INTERVAL`` asked for (the latest sample at each send, no more often
  than the IMU rate; int16 mrad/s and mG truncated toward zero as the C code converts,
  temperature cdegC as each firmware rounds it); the parameter protocol (PARAM_REQUEST_READ,
  PARAM_REQUEST_LIST, PARAM_SET answered with PARAM_VALUE, integers encoded bytewise by
  PX4 and C-cast by ArduPilot); COMMAND_ACK.
* **Faults.** ``fail_param_sets`` (names): a PARAM_SET of such a name is never answered and
  not applied — what a vehicle that drops or refuses a write looks like to a ground station.

The controller is driven by the bench's tick thread (:meth:`advance`, under the bench lock)
and answers requests on its own thread.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gyrolab.autopilot import ardupilot as ap
from gyrolab.autopilot import mavlink as ml
from gyrolab.autopilot import px4
from gyrolab.autopilot.rotation import rotate
from gyrolab.sim.bench.serial_pty import PtyDevice, PtyPort

DEG2RAD = math.pi / 180.0
HEARTBEAT_PERIOD_S = 1.0
MAV_TYPE_QUADROTOR = 2
MAV_AUTOPILOT_ID = {"px4": 12, "ardupilot": 3}
PX4_DEVICE_IDS = (2490378, 3735562, 2228234)  # bus/address/devtype of three SPI IMUs


@dataclass
class FcStats:
    """What the controller did (tests read it)."""

    messages_out: int = 0
    imu_messages: int = 0
    params_set: int = 0
    params_refused: int = 0
    write_overruns: int = 0
    publications: int = 0  # PX4 sensor_correction publications
    reboots: int = 0


def default_parameters(firmware: str, imus: int) -> dict[str, tuple[float, int]]:
    """A vehicle as delivered and calibrated once by its user: name → (value, type). PX4:
    no thermal compensation yet (``TC_G_ENABLE`` 0, ``TC_Gi_TREF`` 25 as its defaults),
    gyro offsets from a gyro calibration, the board mounted as is. ArduPilot: INS_TCAL off
    (TMIN 0, TMAX 70 defaults), offsets and ``INS_GYRn_CALTEMP`` from the boot-time gyro
    calibration, the board mounted upside down (``AHRS_ORIENTATION`` 8, roll 180°)."""
    i32, i8, f = ml.MAV_PARAM_TYPE_INT32, ml.MAV_PARAM_TYPE_INT8, ml.MAV_PARAM_TYPE_REAL32
    p: dict[str, tuple[float, int]] = {}
    if firmware == "px4":
        p["TC_G_ENABLE"] = (0.0, i32)
        for s in range(px4.TC_SLOTS):
            for name in px4.tc_names(s)[1:]:
                value = 25.0 if name.endswith("TREF") else 0.0
                p[name] = (value, i32 if name.endswith("_ID") else f)
        for k in range(px4.TC_SLOTS):
            dev = PX4_DEVICE_IDS[k] if k < imus else 0
            p[px4.cal_id_name(k)] = (float(dev), i32)
            for j, name in enumerate(px4.cal_offset_names(k)):
                p[name] = ((0.004, -0.007, 0.002)[j] * (k + 1) if k < imus else 0.0, f)
        p[px4.BOARD_ROTATION] = (0.0, i32)
        for name in px4.BOARD_LEVEL_OFFSETS:
            p[name] = (0.0, f)
        p["IMU_INTEG_RATE"] = (200.0, i32)
        return p
    for k in range(ap.IMUS):
        n = k + 1
        p[f"INS_TCAL{n}_ENABLE"] = (0.0, i8)
        p[f"INS_TCAL{n}_TMIN"] = (0.0, f)
        p[f"INS_TCAL{n}_TMAX"] = (70.0, f)
        for name in ap.tcal_names(k)[3:]:
            p[name] = (0.0, f)
        for j, name in enumerate(ap.gyro_offset_names(k)):
            p[name] = ((-0.006, 0.003, 0.005)[j] * (k + 1) if k < imus else 0.0, f)
        p[ap.caltemp_name(k)] = (31.0 if k < imus else -300.0, f)
    p[ap.BOARD_ORIENTATION] = (8.0, i8)
    p["INS_GYR_CAL"] = (1.0, i8)
    p["SR0_RAW_SENS"] = (0.0, i8)
    return p


@dataclass
class FcSpec:
    """A flight controller for :class:`gyrolab.sim.bench.SimBench` (``device=``): the bench
    makes its pty (``bench.device_port``, link ``fc`` in its work directory, resource
    ``fc_port``) and drives it."""

    firmware: str
    imus: list[list[Any]]  # per IMU its x, y, z Physics
    seed: int = 0
    params: dict[str, tuple[float, int]] = field(default_factory=dict)
    fail_param_sets: set[str] = field(default_factory=set)
    port_name: str = "fc"

    def build(self, port: PtyPort, write_timeout_s: float) -> SimFlightController:
        return SimFlightController(
            self.firmware,
            self.imus,
            port,
            seed=self.seed,
            params=dict(self.params),
            fail_param_sets=set(self.fail_param_sets),
            write_timeout_s=write_timeout_s,
        )


@dataclass
class _Imu:
    axes: list[Any]  # three Physics: x, y, z
    accel_sd: float
    rng: np.random.Generator
    device_id: int
    send_every: int = 0  # samples between messages (0: not streamed)
    last_temp: float = float("nan")


@dataclass
class SimFlightController(PtyDevice):
    """See the module doc. ``imus``: per IMU its three axis Physics (same rate and chamber as
    the bench's); ``firmware``: ``"px4"`` | ``"ardupilot"``; ``port``: the pty the driver
    opens; ``params``: overrides of :func:`default_parameters`."""

    firmware: str
    imus: list[list[Any]]
    port: PtyPort
    seed: int = 0
    params: dict[str, tuple[float, int]] = field(default_factory=dict)
    accel_noise_m_s2: float = 0.02
    write_timeout_s: float = 0.5
    fail_param_sets: set[str] = field(default_factory=set)
    system_id: int = 1
    component_id: int = 1
    thread_name = "sim-fc"

    def __post_init__(self) -> None:
        from pymavlink.dialects.v20 import common

        if self.firmware not in MAV_AUTOPILOT_ID:
            raise ValueError(f"unknown firmware {self.firmware!r} (px4 or ardupilot)")
        if not 1 <= len(self.imus) <= 3 or any(len(i) != 3 for i in self.imus):
            raise ValueError("a flight controller has 1 to 3 IMUs of 3 axes each")
        rates = {p.rate_hz for imu in self.imus for p in imu}
        if len(rates) != 1:
            raise ValueError("every IMU axis must run at one rate")
        self.rate_hz = rates.pop()
        self.common = common
        # a vehicle stores every parameter as float32 (or an integer)
        self.param = {
            k: (float(np.float32(v)), t)
            for k, (v, t) in {
                **default_parameters(self.firmware, len(self.imus)),
                **self.params,
            }.items()
        }
        self._imus = [
            _Imu(
                axes,
                self.accel_noise_m_s2,
                np.random.default_rng([self.seed, 7, k]),
                PX4_DEVICE_IDS[k] if self.firmware == "px4" else 0,
            )
            for k, axes in enumerate(self.imus)
        ]
        self._mav = common.MAVLink(None, srcSystem=self.system_id, srcComponent=self.component_id)
        self._parser = common.MAVLink(None)
        self._parser.robust_parsing = True
        self.init_device(self.port, self.write_timeout_s)
        self._state_lock = threading.Lock()  # parameters and the PX4 module
        self._module = px4.TemperatureCompensationModule(self._values(), self.device_ids)
        self._next_poll_s = 0.0  # the module's next run (bench time)
        self._thermal = [np.zeros(3, dtype=np.float32) for _ in self._imus]
        self._next_heartbeat_s = 0.0
        self._boot_s = 0.0  # bench time of the last boot: MAVLink times count from it
        # ArduPilot takes AHRS_ORIENTATION into use at most once a second, while disarmed
        # (AP_AHRS::update_orientation)
        self._orientation = int(self.param.get(ap.BOARD_ORIENTATION, (0.0, 0))[0])
        self._next_orientation_s = 0.0
        self._accel_rotation = 0
        self.stats = FcStats()

    # ------------------------------------------------------------------ parameters
    @property
    def device_ids(self) -> list[int]:
        return [i.device_id for i in self._imus]

    def _values(self) -> dict[str, float]:
        return {k: v for k, (v, _t) in self.param.items()}

    def values(self) -> dict[str, float]:
        """The parameters now (name → value)."""
        with self._state_lock:
            return self._values()

    def _parameters_changed(self) -> None:
        """PX4's ``parameter_update``: the TC module re-reads its parameters (and so
        republishes at its next poll); ArduPilot reads its parameters live."""
        if self.firmware == "px4":
            self._module.parameters_update(self._values())

    # ------------------------------------------------------------------ world
    def set_setpoint(self, setpoint_c: float) -> None:
        for imu in self._imus:
            for p in imu.axes:
                p.set_setpoint(setpoint_c)

    @property
    def chamber_physics(self) -> Any:
        """The physics whose air is the chamber's (the controller's process value)."""
        return self._imus[0].axes[0]

    def prefetch(self, n: int) -> None:
        for imu in self._imus:
            for p in imu.axes:
                p.prefetch(n)

    def advance(self, n: int) -> bytes:
        """Advance every IMU by ``n`` samples and run the firmware on them; returns the
        MAVLink bytes due (the bench's tick thread: this under the bench lock, then
        :meth:`send` outside it)."""
        raw, temps, accel = [], [], []
        t0 = self._imus[0].axes[0].t
        for imu in self._imus:
            blocks = [p.advance(n) for p in imu.axes]
            raw.append(np.column_stack([b.rate_dps for b in blocks]) * DEG2RAD)
            x = imu.axes[0]
            codes = x.die_sensor_codes(blocks[0].die_trace)
            temps.append(x.die_sensor.zero_c + codes * x.die_sensor.c_per_lsb)
            g = np.tile([0.0, 0.0, -ml.GRAVITY_MSS], (n, 1))
            accel.append(g + imu.accel_sd * imu.rng.standard_normal((n, 3)))
        t = t0 + np.arange(n) / self.rate_hz
        with self._state_lock:
            out = self._run_firmware(t, raw, temps)
            # the accelerometer in the same (body) frame; its calibration is not modelled
            accel = [rotate(a, self._accel_rotation) for a in accel]
            streams = [imu.send_every for imu in self._imus]
            boot = self._boot_s
        chunks: list[bytes] = []
        first = int(round(t[0] * self.rate_hz))
        for k, imu in enumerate(self._imus):
            imu.last_temp = float(temps[k][-1])
            m = streams[k]
            if m <= 0:
                continue
            for i in np.flatnonzero((first + np.arange(n)) % m == 0):
                tb = float(t[i]) - boot
                chunks.append(self._imu_message(k, tb, out[k][i], accel[k][i], temps[k][i]))
                self.stats.imu_messages += 1
        while self._next_heartbeat_s <= t[-1]:
            chunks.append(self._heartbeat())
            self._next_heartbeat_s += HEARTBEAT_PERIOD_S
        return b"".join(chunks)

    def send(self, data: bytes, timeout_s: float | None = None) -> None:
        """Write ``data`` to the port, waiting up to ``timeout_s`` for room (back-pressure
        or overrun as a UART; see :meth:`PtyDevice.write`)."""
        self._send(data, timeout_s)

    def _run_firmware(self, t: np.ndarray, raw: list[np.ndarray], temps: list[np.ndarray]) -> list:
        """Each IMU's corrected output, float32 rad/s, as the firmware computes it."""
        p = self._values()
        if self.firmware == "ardupilot":
            if self._next_orientation_s <= t[-1]:
                self._orientation = int(p.get(ap.BOARD_ORIENTATION, 0))
                self._next_orientation_s = math.floor(t[-1]) + 1.0
            p[ap.BOARD_ORIENTATION] = float(self._orientation)
            self._accel_rotation = self._orientation
            return [ap.correct(raw[k], temps[k], p, k) for k in range(len(self._imus))]
        self._accel_rotation = int(p.get(px4.BOARD_ROTATION, 0))
        # PX4: the module's polls inside this block, then Correct() per sample
        offsets = [np.zeros((t.size, 3), dtype=np.float32) for _ in self._imus]
        cuts = []
        while self._next_poll_s <= t[-1]:
            i = int(np.searchsorted(t, self._next_poll_s, side="right")) - 1
            latest = [float(tk[i]) if i >= 0 else None for tk in temps]
            pub = self._module.poll(latest)
            if pub is not None:
                self.stats.publications += 1
                cuts.append((max(i, 0), pub))
            self._next_poll_s += px4.MODULE_PERIOD_S
        for k in range(len(self._imus)):
            offsets[k][:] = self._thermal[k]
        for i, pub in cuts:  # a publication acts from the next sample on
            for k, imu in enumerate(self._imus):
                new = pub.get(imu.device_id, np.zeros(3, dtype=np.float32))
                offsets[k][i + 1 :] = new
                self._thermal[k] = new
        rot = int(p.get(px4.BOARD_ROTATION, 0))
        out = []
        for k in range(len(self._imus)):
            slot = next(
                (
                    s
                    for s in range(px4.TC_SLOTS)
                    if p.get(px4.cal_id_name(s)) == self._imus[k].device_id
                ),
                None,
            )
            cal = np.zeros(3) if slot is None else [p[n] for n in px4.cal_offset_names(slot)]
            out.append(px4.correct(raw[k], offsets[k], np.asarray(cal), rot))
        return out

    # ------------------------------------------------------------------ MAVLink out
    def _imu_message(
        self, k: int, t: float, gyro: np.ndarray, acc: np.ndarray, temp: float
    ) -> bytes:
        name = ml.message_for(self.firmware, k)
        g = ml.encode_mrad_s(gyro)
        a = ml.encode_mg(acc)
        tc = ml.encode_temperature(temp, self.firmware)
        if name == "RAW_IMU":
            msg = self.common.MAVLink_raw_imu_message(int(t * 1e6), *a, *g, 0, 0, 0, 0, tc)
        else:
            cls = {
                "SCALED_IMU": self.common.MAVLink_scaled_imu_message,
                "SCALED_IMU2": self.common.MAVLink_scaled_imu2_message,
                "SCALED_IMU3": self.common.MAVLink_scaled_imu3_message,
            }[name]
            msg = cls(int(t * 1e3), *a, *g, 0, 0, 0, tc)
        return msg.pack(self._mav)

    def _heartbeat(self) -> bytes:
        msg = self.common.MAVLink_heartbeat_message(
            MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_ID[self.firmware], 0, 0, 3, 3
        )
        return msg.pack(self._mav)

    def _send(self, data: bytes, timeout_s: float | None = None) -> None:
        if not data:
            return
        done = self.write(data, timeout_s)
        if done is None:
            return
        self.stats.messages_out += 1
        if done < len(data):
            self.stats.write_overruns += 1

    # ------------------------------------------------------------------ MAVLink in
    def on_bytes(self, data: bytes) -> None:
        for msg in self._parser.parse_buffer(data) or []:
            self._handle(msg)

    def _for_us(self, msg: Any) -> bool:
        return getattr(msg, "target_system", self.system_id) in (0, self.system_id)

    def _handle(self, msg: Any) -> None:
        kind = msg.get_type()
        if kind == "PARAM_REQUEST_READ" and self._for_us(msg):
            self._reply_params([msg.param_id] if msg.param_index < 0 else [msg.param_index])
        elif kind == "PARAM_REQUEST_LIST" and self._for_us(msg):
            self._reply_params(range(len(self.param)))
        elif kind == "PARAM_SET" and self._for_us(msg):
            self._param_set(msg)
        elif kind == "COMMAND_LONG" and self._for_us(msg):
            self._command(msg)

    def _reply_params(self, which: Iterable[Any]) -> None:
        names = list(self.param)
        out = []
        with self._state_lock:
            for w in which:
                name = names[w] if isinstance(w, int) else str(w)
                if isinstance(w, int) and not 0 <= w < len(names):
                    continue
                if name not in self.param:
                    continue  # unknown: no reply, as both firmwares do
                out.append(self._param_value(name, names.index(name)))
        self._send(b"".join(out))

    def _param_value(self, name: str, index: int) -> bytes:
        value, ptype = self.param[name]
        wire = ml.param_to_wire(value, ptype, self.firmware)
        msg = self.common.MAVLink_param_value_message(
            name.encode(), wire, ptype, len(self.param), index
        )
        return msg.pack(self._mav)

    def _param_set(self, msg: Any) -> None:
        name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()
        name = name.rstrip("\0")
        with self._state_lock:
            if name not in self.param or name in self.fail_param_sets:
                self.stats.params_refused += 1
                return  # never acknowledged: the ground station times out
            _old, ptype = self.param[name]
            value = ml.param_from_wire(msg.param_value, ptype, self.firmware)
            self.param[name] = (value, ptype)
            self.stats.params_set += 1
            self._parameters_changed()
            reply = self._param_value(name, list(self.param).index(name))
        self._send(reply)

    def reboot(self, now_s: float) -> None:
        """What a reboot does to the state the firmware keeps at run time: streams stop,
        MAVLink times restart at 0, PX4's published thermal offsets are gone and its
        module starts again (``last_temperature`` −100), ArduPilot re-reads the board
        orientation; parameters persist."""
        with self._state_lock:
            self._boot_s = now_s
            for imu in self._imus:
                imu.send_every = 0
            self._thermal = [np.zeros(3, dtype=np.float32) for _ in self._imus]
            self._module = px4.TemperatureCompensationModule(self._values(), self.device_ids)
            self._next_poll_s = now_s
            self._next_orientation_s = 0.0
        self.stats.reboots += 1

    def _command(self, msg: Any) -> None:
        result = 3  # MAV_RESULT_UNSUPPORTED
        if msg.command == ml.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN and int(msg.param1) == 1:
            ack = self.common.MAVLink_command_ack_message(msg.command, 0)
            self._send(ack.pack(self._mav))
            self.reboot(self._imus[0].axes[0].t)
            return
        if msg.command == ml.MAV_CMD_SET_MESSAGE_INTERVAL:
            ids = {ml.MESSAGE_IDS[n]: k for k, n in enumerate(ml.IMU_MESSAGES[self.firmware])}
            k = ids.get(int(msg.param1))
            if k is not None and k < len(self._imus):
                interval_us = float(msg.param2)
                with self._state_lock:
                    if interval_us <= 0:  # -1: stop (0: the default rate, here off too)
                        self._imus[k].send_every = 0
                    else:
                        m = max(1, int(round(interval_us * 1e-6 * self.rate_hz)))
                        self._imus[k].send_every = m
                result = 0  # MAV_RESULT_ACCEPTED
        ack = self.common.MAVLink_command_ack_message(msg.command, result)
        self._send(ack.pack(self._mav))

    # ------------------------------------------------------------------ tests
    def imu_temperature(self, k: int) -> float:
        return self._imus[k].last_temp
