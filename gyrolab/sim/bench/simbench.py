"""The simulated bench: the three instruments on real wires, driven by one Physics and
one simulated clock.

``SimBench.start()`` opens three pseudo-terminals (the ADC stream, the oven's Modbus
line, the multimeter's RS-232) and a TCP socket (the multimeter's LAN port) and starts a
tick thread that advances the clock and the physics by a whole number of ADC frames per
tick, streams the frames, and fires scheduled faults. Drivers connect to
``bench.adc_port``, ``bench.oven_port``, ``bench.dmm_serial_resource`` /
``bench.dmm_tcp_resource`` exactly as they would to hardware. The runner uses
``bench.clock`` (``now()``, ``sleep()``) as its time base so that it runs at the bench's
speed.

A multi-unit bench (``unit_physics``: one Physics per unit, e.g. from
:func:`gyrolab.sim.family.unit_family`) streams every unit's frames on its own pty
(``bench.unit_adc_ports``, in unit order) and serves a 34970A scanner on TCP
(``bench.scanner_tcp_resource``) reading unit *k*'s PT100 on channel 101 + *k* (a unit
flagged in ``unit_internal_temperature`` sends its die sensor's reading in every frame
instead; its scanner channel is unwired). The chamber is shared: every unit follows the
oven's setpoint, and the controller's process value is the first unit's chamber air (a
family shares the chamber's parameters).

``bench.lock`` guards the physics; the instruments' replies take it, so the tick thread
holds it only for a tick's :meth:`Physics.advance` (well under a millisecond). The costly
part of advancing — a flicker-noise chunk, 0.1–0.3 s every 3.6 simulated hours — is made
ahead of need by a prefetch thread, outside the lock (:meth:`Physics.prefetch`), so
neither a Modbus/SCPI reply nor the simulated clock waits for it.
"""

from __future__ import annotations

import copy
import heapq
import itertools
import shutil
import tempfile
import threading
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

from gyrolab.sampling import DEFAULT_RATE_HZ
from gyrolab.sim.bench.adc_source import AdcSource, AdcTruth
from gyrolab.sim.bench.clock import SimClock
from gyrolab.sim.bench.dmm_scpi import Scpi34401A, Scpi34465A, ScpiSerialServer, ScpiTcpServer
from gyrolab.sim.bench.espec_p300 import ChamberHooks, EspecP300
from gyrolab.sim.bench.faults import FaultEvent, FaultPlan
from gyrolab.sim.bench.oven_modbus import ModbusRtuServer, OvenHooks, WatlowF4Slave
from gyrolab.sim.bench.scanner_scpi import Scpi34970A
from gyrolab.sim.bench.serial_pty import PtyPort

# Simulated seconds of costly physics (flicker-noise chunks) made ahead of the tick thread,
# and how often (wall seconds) the prefetch thread looks. An hour ahead is seconds of wall
# time even when free-running, against 0.1-0.3 s to make a chunk.
PREFETCH_LEAD_S = 3600.0
PREFETCH_POLL_S = 0.05

# Paced, how long a tick's write waits for a full port before the rest is lost (wall s): a
# UART transmits on its schedule and a receiver nobody drains overruns.
PACED_WRITE_WAIT_S = 0.05


class SimBench:
    """Simulated multimeter, oven and gyro ADC (see module doc).

    ``physics`` is a :class:`gyrolab.sim.physics.Physics` (built from ``model``/``seed``/
    ``rate_hz`` when omitted). ``speed``: simulated seconds per wall second (None: as
    fast as the ADC reader drains its port). ``tick_s``: simulated time per tick (rounded
    to whole frames). ``keep_truth`` keeps every ADC frame produced, for tests.
    """

    def __init__(
        self,
        physics: Any | None = None,
        *,
        model: Any | None = None,
        seed: int = 0,
        rate_hz: float = DEFAULT_RATE_HZ,
        samples_per_frame: int = 10,
        speed: float | None = 1.0,
        faults: FaultPlan | None = None,
        workdir: str | Path | None = None,
        tcp: bool = True,
        keep_truth: bool = False,
        tick_s: float = 0.1,
        ambient_c: float = 25.0,
        oven_decimals: int = 1,
        oven_units_c: bool = True,
        dmm_model: str = "34401A",
        chamber_model: str = "F4",
        oven_control_event: int | None = None,
        oven_alarm_input: int | None = None,
        adc_write_timeout_s: float | None = None,
        axis_physics: list[Any] | None = None,
        unit_physics: list[Any] | None = None,
        unit_internal_temperature: list[bool] | None = None,
        device: Any | None = None,
        device_backpressure_s: float = 0.5,
    ) -> None:
        # dmm_model: "34401A" | "34465A"; chamber_model: "F4" (Modbus RTU on a pty, always
        # served) | "P300" (an ESPEC P-300 on TCP as well). The driver registry names the
        # model each driver needs (gyrolab.instruments.registry, DriverSpec.sim_backend).
        if dmm_model not in ("34401A", "34465A") or chamber_model not in ("F4", "P300"):
            raise ValueError(f"unknown simulated instrument {dmm_model!r} / {chamber_model!r}")
        # unit_physics: a multi-unit bench (one Physics per unit, the first one's air being the
        # chamber's): each unit streams on its own pty and the scanner (a 34970A on TCP)
        # reads unit k's PT100 on channel 101 + k.
        if unit_physics is not None:
            if not unit_physics or axis_physics or physics is not None:
                raise ValueError("unit_physics: one or more units, single-axis, no physics=")
            physics = unit_physics[0]
        # device (a FcSpec or VnSpec): a flight controller or an IMU with its own serial
        # protocol in the chamber instead of a gyro on the ADC; its first IMU's air is the
        # chamber's (every IMU axis shares the thermal model)
        if device is not None:
            if unit_physics is not None or axis_physics or physics is not None:
                raise ValueError("device: a device bench has no ADC units")
            physics = device.imus[0][0]
        if physics is None:
            from gyrolab.sim.model import nominal_model
            from gyrolab.sim.physics import Physics

            physics = Physics(
                model or nominal_model(), rate_hz=rate_hz, seed=seed, ambient_c=ambient_c
            )
        self.physics = physics
        # Axes y (and z) of a multi-axis unit (gyrolab.sim.simulate.axis_physics): they
        # follow the same setpoint and are framed with axis x, interleaved, by one ADC.
        self.axis_physics = list(axis_physics or [])
        self.rate_hz = float(physics.rate_hz)
        self.samples_per_frame = int(samples_per_frame)
        if physics.index % self.samples_per_frame:
            raise ValueError("physics must start on a frame boundary")
        self.frames_per_tick = max(1, round(tick_s * self.rate_hz / self.samples_per_frame))
        # A starved tick thread may catch up at most two ticks in a burst; beyond that the
        # clock slips (clock.py): the runner must never find the world seconds ahead of
        # where it last looked just because the process did not get the CPU.
        tick_sim_s = self.frames_per_tick * self.samples_per_frame / self.rate_hz
        self.clock = SimClock(speed, start_s=physics.t, max_catch_up_s=2.0 * tick_sim_s)
        self.faults = faults or FaultPlan()
        self.lock = threading.RLock()  # guards the physics (tick thread vs. responders)
        self._own_dir = workdir is None
        self.workdir = Path(workdir or tempfile.mkdtemp(prefix="gyrolab-bench-"))
        self.workdir.mkdir(parents=True, exist_ok=True)

        self.unit_physics = list(unit_physics or [physics])
        self.multi_unit = unit_physics is not None
        # Units whose ADC frames carry their internal (die) temperature sensor's word
        # (Physics.die_sensor_codes, one per frame; gyrolab.framing).
        self.unit_internal = list(unit_internal_temperature or [False] * len(self.unit_physics))
        if len(self.unit_internal) != len(self.unit_physics):
            raise ValueError("unit_internal_temperature: one flag per unit")
        # One ADC port and source per unit (a single-unit bench: the one "adc" port).
        self.unit_ptys = [
            PtyPort(self.workdir / (f"adc{k + 1}" if self.multi_unit else "adc"))
            for k in range(len(self.unit_physics))
        ]
        self.oven_pty = PtyPort(self.workdir / "oven")
        self.dmm_pty = PtyPort(self.workdir / "dmm")
        self.unit_adcs = [
            AdcSource(
                pty,
                samples_per_frame=self.samples_per_frame,
                rate_hz=self.rate_hz,
                axes=1 + len(self.axis_physics),
                temperature=internal,
                faults=self.faults.adc,
                keep_truth=keep_truth,
                # Back-pressure only when running as fast as possible; paced, a slow reader
                # overruns like a real UART receiver would.
                write_timeout_s=(
                    adc_write_timeout_s
                    if adc_write_timeout_s is not None
                    else 0.5
                    if speed is None
                    else 0.05
                ),
            )
            for pty, internal in zip(self.unit_ptys, self.unit_internal, strict=True)
        ]
        self.adc_pty, self.adc = self.unit_ptys[0], self.unit_adcs[0]
        self.device: Any = None
        self.device_pty: PtyPort | None = None
        self.device_kind = ""
        # device_backpressure_s: free-running, how long the device's stream waits (wall s)
        # for its reader to drain the port before data are lost; see _device_wait_s.
        self.device_backpressure_s = float(device_backpressure_s)
        if device is not None:
            self.device_kind = device.port_name
            self.device_pty = PtyPort(self.workdir / device.port_name)
            self.device = device.build(self.device_pty, self._device_wait_s())
        self.oven = WatlowF4Slave(
            OvenHooks(self._chamber_c, self._setpoint_c, self._set_setpoint, ambient_c),
            control_event=oven_control_event,
            alarm_input=oven_alarm_input,
            decimals=oven_decimals,
            units_c=oven_units_c,
            faults=self.faults.oven,
        )
        # (t_sim, noise-free Ω, Ω as read) of every reading the meter took, for tests
        self.dmm_truth: deque[tuple[float, float, float]] = deque(maxlen=100_000)
        dmm_cls = Scpi34465A if dmm_model == "34465A" else Scpi34401A
        self.dmm = dmm_cls(self._read_ohm, self.clock)
        self._servers: list[Any] = [
            ModbusRtuServer(self.oven, self.oven_pty),
            ScpiSerialServer(self.dmm, self.dmm_pty),
        ]
        self.dmm_tcp: ScpiTcpServer | None = ScpiTcpServer(self.dmm) if tcp else None
        if self.dmm_tcp is not None:
            self._servers.append(self.dmm_tcp)
        self.scanner: Scpi34970A | None = None
        self.scanner_tcp: ScpiTcpServer | None = None
        if self.multi_unit:
            self.scanner = Scpi34970A(self._read_channel_ohm, self.clock)
            self.scanner_tcp = ScpiTcpServer(self.scanner)
            self._servers.append(self.scanner_tcp)
        self.espec: EspecP300 | None = None
        self.chamber_tcp: ScpiTcpServer | None = None
        if chamber_model == "P300":
            hooks = ChamberHooks(self._chamber_c, self._set_setpoint, ambient_c)
            self.espec = EspecP300(hooks, setpoint_c=float(self.physics.setpoint_c))
            self.chamber_tcp = ScpiTcpServer(self.espec, eol=b"\r\n")
            self._servers.append(self.chamber_tcp)
        self._events: list[tuple[float, int, str, FaultEvent]] = []
        self._tie = itertools.count()
        for ev in self.faults.events:
            if ev.unit >= len(self.unit_adcs):
                n_units = len(self.unit_adcs)
                raise ValueError(f"fault {ev.kind}: no unit {ev.unit} on a {n_units}-unit bench")
            if ev.kind == "open_channel" and not self.multi_unit:
                raise ValueError("fault open_channel: a scanner channel (multi-unit bench only)")
        for ev in self.faults.events:  # t_s None here means: at the first tick
            t = self.clock.now() if ev.t_s is None else float(ev.t_s)
            heapq.heappush(self._events, (t, next(self._tie), "start", ev))
        self.log: list[tuple[float, str, str]] = []  # (t_sim, kind, detail) of faults fired
        self._thread: threading.Thread | None = None
        self._prefetcher: threading.Thread | None = None
        self._stop = threading.Event()
        self.error: BaseException | None = None

    @property
    def thermometer(self) -> Scpi34401A:
        """The instrument that reads the PT100s (what ``outage`` and ``scpi_error`` faults
        hit): the scanner on a multi-unit bench, else the multimeter."""
        return self.scanner if self.scanner is not None else self.dmm

    # ---------------------------------------------------------------- physics hooks
    def _chamber_c(self) -> float:
        with self.lock:
            return float(self.physics.chamber_c())

    def _setpoint_c(self) -> float:
        with self.lock:
            return float(self.physics.setpoint_c)

    def _set_setpoint(self, value_c: float) -> None:
        with self.lock:
            if self.device is not None:
                self.device.set_setpoint(value_c)  # its IMUs' physics, the chamber's among them
                return
            self.physics.set_setpoint(value_c)
            for p in self.axis_physics + self.unit_physics[1:]:
                p.set_setpoint(value_c)

    def _read_ohm(self) -> float:
        with self.lock:
            r = float(self.physics.pt100_ohm())
            self.dmm_truth.append((self.physics.t, float(self.physics.pt100_true_ohm()), r))
            return r

    def _read_channel_ohm(self, channel: int) -> float | None:
        """The scanner's channel 101 + k: unit k's PT100 (None: nothing wired there, or the
        unit is read by its internal sensor)."""
        k = channel - 101
        if not 0 <= k < len(self.unit_physics) or self.unit_internal[k]:
            return None
        with self.lock:
            return float(self.unit_physics[k].pt100_ohm())

    # ---------------------------------------------------------------- addresses
    @property
    def adc_port(self) -> str:
        """Serial device path of the ADC stream."""
        return self.adc_pty.path

    @property
    def oven_port(self) -> str:
        """Serial device path of the oven's Modbus RTU line."""
        return self.oven_pty.path

    @property
    def dmm_serial_resource(self) -> str:
        """VISA resource of the multimeter's RS-232 port."""
        return f"ASRL{self.dmm_pty.path}::INSTR"

    @property
    def dmm_tcp_resource(self) -> str | None:
        """VISA resource of the multimeter's LAN socket (None without ``tcp``)."""
        return None if self.dmm_tcp is None else self.dmm_tcp.resource

    @property
    def scanner_tcp_resource(self) -> str | None:
        """VISA resource of the scanner's socket (None unless multi-unit)."""
        return None if self.scanner_tcp is None else self.scanner_tcp.resource

    @property
    def unit_adc_ports(self) -> list[str]:
        """Serial device path of each unit's ADC stream, in unit order."""
        return [p.path for p in self.unit_ptys]

    @property
    def device_port(self) -> str | None:
        """Serial device path of the device's port (None without one)."""
        return None if self.device_pty is None else self.device_pty.path

    @property
    def chamber_tcp_resource(self) -> str | None:
        """VISA resource of the ESPEC chamber's socket (None unless ``chamber_model="P300"``)."""
        return None if self.chamber_tcp is None else self.chamber_tcp.resource

    def resources(self) -> dict[str, Any]:
        """Everything a bench configuration needs to reach the simulated instruments."""
        return {
            "dmm_resource": self.dmm_tcp_resource or self.dmm_serial_resource,
            "dmm_serial_resource": self.dmm_serial_resource,
            "dmm_tcp_resource": self.dmm_tcp_resource,
            "oven_port": self.oven_port,
            "chamber_tcp_resource": self.chamber_tcp_resource,
            "scanner_tcp_resource": self.scanner_tcp_resource,
            "unit_adc_ports": self.unit_adc_ports,
            "adc_port": self.adc_port,
            "fc_port": self.device_port if self.device_kind == "fc" else None,
            "vn_port": self.device_port if self.device_kind == "vn" else None,
            "rate_hz": self.rate_hz,
            "samples_per_frame": self.samples_per_frame,
        }

    @property
    def truth(self) -> AdcTruth:
        return self.adc.truth

    # ---------------------------------------------------------------- faults
    def inject(self, event: FaultEvent) -> None:
        """Fire ``event`` now if its ``t_s`` is None (before returning), else schedule it
        at simulated time ``t_s``."""
        if event.t_s is None:
            self._fire(self.clock.now(), "start", event)
            return
        with self.lock:
            heapq.heappush(self._events, (float(event.t_s), next(self._tie), "start", event))

    def _fire_due(self) -> None:
        now = self.clock.now()
        while True:
            with self.lock:
                if not self._events or self._events[0][0] > now:
                    return
                t, _, phase, ev = heapq.heappop(self._events)
            self._fire(now, phase, ev)

    def _fire(self, now: float, phase: str, ev: FaultEvent) -> None:
        self.log.append((now, f"{ev.kind}:{phase}", ev.detail))
        end = now + ev.duration_s
        adc = self.unit_adcs[ev.unit] if ev.kind in ("disconnect", "stall") else None
        if ev.kind == "disconnect":
            assert adc is not None
            if phase == "start":
                adc.unplug()
                with self.lock:
                    heapq.heappush(self._events, (end, next(self._tie), "end", ev))
            else:
                adc.replug()
        elif ev.kind == "stall":
            assert adc is not None
            if phase == "start":
                adc.start_stall()
                with self.lock:
                    heapq.heappush(self._events, (end, next(self._tie), "end", ev))
            else:
                adc.end_stall()
        elif ev.kind == "outage":
            self.thermometer.start_outage(end)
        elif ev.kind == "scpi_error":
            self.thermometer.push_error(ev.detail or '-310,"System error"')
        elif ev.kind == "open_channel":
            assert self.scanner is not None
            self.scanner.open_channel(101 + ev.unit, end)
        elif ev.kind == "chamber_alarm":
            # The chamber in use: the ESPEC when there is one, else the F4 (its limit
            # controller on its alarm input).
            # Not under self.lock: the ESPEC's own lock is taken before it in its replies.
            chamber = self.espec if self.espec is not None else self.oven
            chamber.set_alarm(phase == "start")
            if phase == "start":
                with self.lock:
                    heapq.heappush(self._events, (end, next(self._tie), "end", ev))
        else:  # modbus_exception | modbus_crc | modbus_no_reply
            self.faults.oven.burst(ev.kind, ev.count)

    # ---------------------------------------------------------------- running
    def start(self) -> SimBench:
        """Plug in the ports, start the servers and the tick thread."""
        n = self.frames_per_tick * self.samples_per_frame
        # The first tick's noise chunk now, before anything waits on the lock; the copy
        # below then reuses it.
        for p in (*self.unit_physics, *self.axis_physics):
            p.prefetch(n)
        if self.device is not None:
            self.device.prefetch(n)
        # Compile the physics' JIT kernels on a throwaway copy first (about 1 s, once per
        # process), so the first tick does not hold the physics lock while responders wait.
        copy.deepcopy(self.physics).advance(n)
        for p in (*self.unit_ptys, self.oven_pty, self.dmm_pty):
            p.connect()
        if self.device is not None:
            assert self.device_pty is not None
            self.device_pty.connect()
            self.adc.port.disconnect()  # no gyro ADC on a device bench
            self.device.start()
        for s in self._servers:
            s.start()
        self.clock.speed = self.clock.speed  # re-anchor pacing: construction time is not run time
        self._thread = threading.Thread(target=self._run, name="sim-bench-tick", daemon=True)
        self._thread.start()
        self._prefetcher = threading.Thread(
            target=self._prefetch, name="sim-bench-prefetch", daemon=True
        )
        self._prefetcher.start()
        return self

    def _prefetch(self) -> None:
        """Keep the costly physics work ``PREFETCH_LEAD_S`` ahead of the tick thread."""
        lead = round(PREFETCH_LEAD_S * self.rate_hz)
        try:
            while not self._stop.is_set():
                for p in (*self.unit_physics, *self.axis_physics):
                    p.prefetch(lead)  # no lock: see Physics.prefetch
                if self.device is not None:
                    self.device.prefetch(lead)
                self._stop.wait(PREFETCH_POLL_S)
        except BaseException as e:  # surfaced like the tick thread's; ticks still work
            self.error = e
            raise

    def _device_wait_s(self) -> float:
        """How long the device's next stream write waits for room in its port (wall s),
        from the clock's speed NOW: free-running, the reader is the bench's only pace
        (back-pressure, ``device_backpressure_s``); paced, ``PACED_WRITE_WAIT_S`` (a UART
        overruns). Asked at every tick, because a bench is built at its connect speed and
        set free-running afterwards (``gyrolab.app.sim_bench.SimHandle.go``): a wait fixed
        at construction was the paced 50 ms for the whole free-running run, and a reader
        starved for 0.1 s on a loaded machine lost a tick of samples."""
        return self.device_backpressure_s if self.clock.speed is None else PACED_WRITE_WAIT_S

    def _run(self) -> None:
        n = self.frames_per_tick * self.samples_per_frame
        try:
            while not self._stop.is_set():
                t_next = (self.physics.index + n) / self.rate_hz
                if not self.clock.advance_to(t_next):
                    break
                if self.device is not None:
                    with self.lock:
                        data = self.device.advance(n)
                    self.device.send(data, self._device_wait_s())
                    self._fire_due()
                    continue
                with self.lock:
                    block = self.physics.advance(n)
                    counts = block.counts
                    if self.axis_physics:
                        cols = [counts] + [p.advance(n).counts for p in self.axis_physics]
                        counts = np.stack(cols, axis=1)
                    blocks = [block] + [p.advance(n) for p in self.unit_physics[1:]]
                    # Internal sensors: the die at each frame's first sample, as read.
                    words = [
                        p.die_sensor_codes(b.die_trace[:: self.samples_per_frame])
                        if internal
                        else None
                        for p, b, internal in zip(
                            self.unit_physics, blocks, self.unit_internal, strict=True
                        )
                    ]
                self.adc.emit(block.first_index, counts, words[0])
                for src, b, w in zip(self.unit_adcs[1:], blocks[1:], words[1:], strict=True):
                    src.emit(block.first_index, b.counts, w)
                self._fire_due()
        except BaseException as e:  # surfaced by stop() / tests; never silent
            self.error = e
            raise

    def stop(self) -> None:
        """Stop the tick thread and servers, unplug every port, remove the links."""
        self._stop.set()
        self.clock.stop()
        if self.device is not None:
            self.device.stop()  # first: it ends a tick's wait for room in the device's port
        for th in (self._thread, self._prefetcher):
            if th is not None:
                th.join(timeout=5.0)
        for s in self._servers:
            s.stop()
        if self.device is not None:
            assert self.device_pty is not None
            self.device_pty.disconnect()
        for p in (*self.unit_ptys, self.oven_pty, self.dmm_pty):
            p.disconnect()
        if self._own_dir:
            shutil.rmtree(self.workdir, ignore_errors=True)

    def __enter__(self) -> SimBench:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
