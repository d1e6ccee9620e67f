"""A simulated flight controller in the simulated chamber, composed for a run.

The bench: the simulated Watlow F4 chamber (Modbus RTU on a pty) and a simulated PX4 or
ArduPilot controller with three IMUs (MAVLink on a pty,
:mod:`gyrolab.sim.bench.flight_controller`), driven by one simulated clock. The bench
config is a multi-unit bench whose units are the IMUs — ``[[unit]] driver = "mavlink"``,
``imu = k``, ``temperature = "internal"`` — exactly what a lab writes for a real controller
(docs/bench-config.md). The controller keeps its parameters between runs on the same bench,
so a calibration run, a flash and a verification run can follow one another
(:mod:`gyrolab.app.fc_demo`).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

from gyrolab.acquisition.bench_config import BenchConfig, RunInfo, UnitConfig, validate
from gyrolab.app.sim_bench import (
    CONNECT_SPEED,
    SimHandle,
    SimRunClock,
    SimSilence,
    scaled_timeouts,
    sim_tick_s,
)
from gyrolab.instruments import registry

FC_RATE_HZ = 25.0  # IMU message rate of the simulated controller (and its IMU rate)
# Free-running, the bench covers a few hundred simulated seconds per wall second while the
# MAVLink streams keep the process busy: on a loaded machine the chamber's poller may get
# no reply for several wall seconds without the chamber being lost. The wall floors
# (SimSilence) are therefore longer than the ADC bench's (SIM_HOLD_MIN_WALL_S 1 s to hold,
# SIM_COMM_MIN_WALL_S 3 s to give a source up), in the same order and ratio: a silence is
# held (the milder answer) after 5 s of wall time and given up (or a hold past its limit
# ends the run) after 15 s, so that a stall is held before anything is given up.
FC_COMM_MIN_WALL_S = 15.0
FC_HOLD_MIN_WALL_S = 5.0


def fc_silence() -> tuple[SimSilence, SimSilence]:
    """The flight-controller bench's two rules on one record of when each source was last
    heard: the watchdog's (``FC_COMM_MIN_WALL_S``) and the holds' (``FC_HOLD_MIN_WALL_S``)."""
    silence = SimSilence(min_wall_s=FC_COMM_MIN_WALL_S)
    return silence, silence.sharing(FC_HOLD_MIN_WALL_S)


def fc_serials(firmware: str, imus: int = 3) -> list[str]:
    """The units' serials: ``PX4-IMU1`` … / ``ARDUPILOT-IMU1`` …."""
    return [f"{firmware.upper()}-IMU{k + 1}" for k in range(imus)]


def fc_bench_config(
    firmware: str, *, calibration: bool = True, imus: int = 3, rate_hz: float = FC_RATE_HZ
) -> BenchConfig:
    """The bench file a flight controller in the chamber stands for (module doc); its port
    is filled in by :func:`start_fc_bench`. ``calibration``: the driver's calibration mode
    (sensor frame, compensation off) or not (a verification run)."""
    spec = registry.get("mavlink", "rate_stream")
    units = tuple(
        UnitConfig(
            serial,
            spec.config(
                imu=k,
                firmware=firmware,
                sample_rate_hz=rate_hz,
                calibration=calibration,
                serial=serial,
            ),
            None,
            "internal",
        )
        for k, serial in enumerate(fc_serials(firmware, imus))
    )
    cfg = BenchConfig(
        name=f"sim-{firmware}",
        run=RunInfo(
            operator="simulated",
            unit_model=f"simulated {firmware} flight controller, {imus} IMUs",
            profile="short",
            notes="gyrolab demo --fc " + firmware + ("" if calibration else " (verification)"),
        ),
        units=units,
        source="sim",
    )
    validate(cfg)
    return cfg


def start_fc_bench(
    firmware: str,
    *,
    seed: int,
    speed: float | None,
    ambient_c: float = 25.0,
    workdir: Path | None = None,
    rate_hz: float = FC_RATE_HZ,
    fail_param_sets: set[str] | None = None,
) -> SimHandle:
    """Start the chamber and the controller; the handle's ``addresses`` has the chamber's
    port and the controller's under every IMU unit's key (``unit/<serial>``)."""
    from gyrolab.sim.bench import SimBench
    from gyrolab.sim.bench.flight_controller import FcSpec
    from gyrolab.sim.fc_imus import imu_physics
    from gyrolab.sim.simulate import provenance

    imus = imu_physics(seed, rate_hz, ambient_c)
    bench = SimBench(
        device=FcSpec(firmware, imus, seed=seed, fail_param_sets=set(fail_param_sets or ())),
        samples_per_frame=1,
        ambient_c=ambient_c,
        workdir=workdir,
        tcp=False,
        tick_s=sim_tick_s(speed),
        speed=min(speed or CONNECT_SPEED, CONNECT_SPEED),
        # Free-running, the controller waits for its reader as long as the run calls a
        # silence a hiccup (the hold floor): a stall of the driver's threads that the run
        # does not hold for loses no sample either.
        device_backpressure_s=FC_HOLD_MIN_WALL_S,
    )
    bench.start()
    fc_port = bench.device_port
    assert fc_port is not None
    serials = fc_serials(firmware, len(imus))
    metadata: dict[str, dict[str, Any]] = {
        "sim_provenance": {
            serial: {
                "flight_controller": firmware,
                "imu": k,
                "axes": [provenance(p.model, p.seed) for p in imus[k]],
            }
            for k, serial in enumerate(serials)
        }
    }
    silence, hold_silence = fc_silence()
    return SimHandle(
        addresses={"chamber": bench.oven_port, **{f"unit/{s}": fc_port for s in serials}},
        clock=SimRunClock(bench.clock),
        silence=silence,
        hold_silence=hold_silence,
        timeout=scaled_timeouts(speed),
        speed=speed,
        bench=bench,
        stop=bench.stop,
        metadata=metadata,
    )


def with_ports(cfg: BenchConfig, handle: SimHandle) -> BenchConfig:
    """``cfg`` with every unit's port the controller's (what a lab's bench file says)."""
    return replace(
        cfg,
        units=tuple(
            replace(
                u, rate_stream=replace(u.rate_stream, port=handle.addresses[f"unit/{u.serial}"])
            )
            for u in cfg.units
        ),
    )
