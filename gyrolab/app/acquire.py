"""``gyrolab acquire`` and ``gyrolab recover``: the lab acquisition entry points.

``acquire --bench BENCH.toml`` opens the three real instruments named in the bench file;
``acquire --bench sim`` first starts the simulated bench (``gyrolab.sim.bench``: the
same wire protocols over pseudo-terminals, one simulated clock) and then does exactly the
same: the drivers, the runner and the recorder cannot tell the difference. The two meet
only on the wire, which is why this module (and the tests) are the only places that
import both ``acquisition`` and ``sim``.

The recording is written directly to ``--out`` (never over an existing file unless
``--force``), so that a crash leaves a recoverable file at the named path
(docs/reliability.md); ``gyrolab recover`` repairs it.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as _dt
import math
import os
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

from gyrolab.acquisition import interrupts
from gyrolab.acquisition.bench_config import (
    BenchConfig,
    RunInfo,
    check_bench_for_profile,
    load_bench,
)
from gyrolab.acquisition.runner import (
    Acquisition,
    RunResult,
    Status,
    WallClock,
    check_profile_limits,
)
from gyrolab.errors import GyrolabError, InputError
from gyrolab.instruments import registry
from gyrolab.instruments.roles import Chamber, RateStream, Thermometer
from gyrolab.outputs import check_output
from gyrolab.profiles.profile import Profile, load_profile
from gyrolab.record.recording import RecordingWriter

# --------------------------------------------------------------------- instruments

# Driver timeouts never go below this many wall seconds. On the lab path (time_scale 1)
# it only raises the oven's 0.3 s (bench-config default) to 0.5 s, as it always has.
LAB_TIMEOUT_FLOOR_S = 0.5

# The simulated bench answers in milliseconds (measured on a 2-core machine with both
# cores busy with other work, at 200x: Modbus transactions max 35 ms, 34401A readings max
# 74 ms wall), so its drivers' timeouts may go lower than on the lab path. The floor is
# still wall time, and at speed X it costs X times as many simulated seconds per timeout:
# 2.5 s at 10x, where the 0.5 s floor cost 5 s, and an exception reply (shorter than the
# reply minimalmodbus waits for) costs a full timeout too. A burst of Modbus errors thus
# stays well inside the 60 s communication timeout.
SIM_TIMEOUT_FLOOR_S = 0.25


class Instruments:
    """The three connected drivers (each implements its role, gyrolab.instruments.roles)
    and their identities."""

    def __init__(self) -> None:
        self.closers: list[Callable[[], None]] = []
        self.identity: dict[str, Any] = {}
        self.thermometer: Thermometer | None = None
        self.oven: Chamber | None = None
        self.gyro: RateStream | None = None

    def close(self) -> None:
        for c in reversed(self.closers):
            with contextlib.suppress(Exception):
                c()
        self.closers.clear()


def connect_instruments(
    cfg: BenchConfig,
    *,
    dmm_resource: str,
    oven_port: str,
    adc_port: str,
    time_scale: float = 1.0,
    timeout_floor_s: float = LAB_TIMEOUT_FLOOR_S,
    visa_library: Any = "@py",
    clock: Callable[[], float] = time.monotonic,
) -> Instruments:
    """Open and identify the bench's three drivers (``driver`` of each role's table,
    gyrolab.instruments.registry) at the given addresses; raises InputError naming what
    failed.

    ``time_scale`` divides the drivers' wall-clock timeouts (a simulated bench running
    X× faster than real time answers X× sooner, and a silent one must be noticed X×
    sooner too); when sped up it never takes them below ``timeout_floor_s`` wall
    seconds, which protects against scheduling jitter; in real time the configured
    timeouts are used as they are (``SIM_TIMEOUT_FLOOR_S`` for the simulated bench).
    """
    inst = Instruments()
    src = cfg.source

    def scaled(t: float) -> float:
        # Real time: the configured timeout is the engineer's choice (docs/bench-config.md);
        # the floor only guards a sped-up simulated bench against scheduling jitter.
        if time_scale <= 1.0:
            return t
        return max(timeout_floor_s, t / time_scale)

    limits = (cfg.limits.setpoint_min_c, cfg.limits.setpoint_max_c)
    try:
        for attr, role, sub, address in (
            ("thermometer", "thermometer", cfg.multimeter, dmm_resource),
            ("oven", "chamber", cfg.oven, oven_port),
            ("gyro", "rate_stream", cfg.adc, adc_port),
        ):
            ctx = registry.OpenContext(address, scaled, limits, clock, visa_library)
            try:
                dev = registry.open_driver(sub, role, ctx)
            except Exception as e:
                table = "adc" if role == "rate_stream" else role
                raise InputError(src, f"[{table}] {sub.driver} at {address}: {e}") from None
            inst.closers.append(dev.close)
            setattr(inst, attr, dev)
            inst.identity[dev.name] = dev.describe()
    except BaseException:
        inst.close()
        raise
    return inst


# ------------------------------------------------------------------ simulated bench


class SimHandle:
    """A running simulated bench: its ports, clock and stop function."""

    def __init__(
        self,
        *,
        dmm_resource: str,
        oven_port: str,
        adc_port: str,
        clock: Any,
        stop: Callable[[], None],
        time_scale: float,
        timeout_floor_s: float = LAB_TIMEOUT_FLOOR_S,
        speed: float | None = None,
        bench: Any = None,
        provenance: dict[str, Any] | None = None,
        axes_provenance: dict[str, Any] | None = None,
    ) -> None:
        self.dmm_resource = dmm_resource
        self.oven_port = oven_port
        self.adc_port = adc_port
        self.clock = clock
        self.stop = stop
        self.time_scale = time_scale
        self.timeout_floor_s = timeout_floor_s
        self.speed = speed
        self.bench = bench
        self.provenance = provenance or {}
        self.axes_provenance = axes_provenance  # as simulate's sim_provenance_axes


def sim_bench_config(seed: int) -> BenchConfig:
    """The bench file ``--bench sim`` stands for: defaults, a simulated operator and unit."""
    return BenchConfig(
        name="sim",
        run=RunInfo(
            operator="simulated",
            unit_serial=f"SIM-{seed}",
            unit_model="simulated MEMS gyro",
            profile="paper",
            notes="gyrolab acquire --bench sim",
        ),
        source="sim",
    )


def sim_drivers(cfg: BenchConfig, names: list[str]) -> BenchConfig:
    """``acquire --bench sim --driver NAME …``: the simulated bench with these drivers (each
    name picks its role; the driver's default settings)."""
    fields = {"thermometer": "multimeter", "chamber": "oven", "rate_stream": "adc"}
    for name in names:
        spec = next((s for s in registry.drivers() if s.name == name), None)
        if spec is None:
            known = ", ".join(s.name for s in registry.drivers())
            raise GyrolabError(f"--driver {name}: no such driver (registered: {known})")
        cfg = replace(cfg, **{fields[spec.role]: spec.config()})
    return cfg


def start_sim_bench(
    cfg: BenchConfig,
    profile: Profile,
    *,
    seed: int,
    speed: float | None,
    workdir: Path | None = None,
    faults: Any = None,
    keep_truth: bool = False,
    model: Any = None,
    axis_models: Any = (),
) -> tuple[SimHandle, BenchConfig]:
    """Start the wire-level simulated bench; returns it and the bench config to use.

    The config's ADC calibration is the simulated gyro's (what a lab takes from the
    unit's calibration sheet); the multimeter is reached over its simulated RS-232 port,
    the same path as ``examples/lab.toml``. ``axis_models`` (0–2 SimModels) make a 2- or
    3-axis unit exactly as ``gyrolab simulate --axis-model`` does (one ADC, axes interleaved).
    """
    from gyrolab.sim.bench import SimBench
    from gyrolab.sim.model import nominal_model
    from gyrolab.sim.simulate import axis_physics, provenance

    specs = {
        "thermometer": registry.get(cfg.multimeter.driver, "thermometer"),
        "chamber": registry.get(cfg.oven.driver, "chamber"),
    }
    for role, spec in specs.items():
        if not spec.sim_backend:
            raise GyrolabError(f"{role} driver {spec.name!r} has no simulated back end")
    try:
        extra_axes = axis_physics(
            model or nominal_model(),
            list(axis_models),
            cfg.adc.sample_rate_hz,
            seed,
            profile.ambient_c,
        )
    except ValueError as e:
        raise InputError("--axis-model", str(e)) from None
    bench = SimBench(
        dmm_model=specs["thermometer"].sim_backend,
        chamber_model=specs["chamber"].sim_backend,
        oven_control_event=getattr(cfg.oven, "control_event", 0) or None,
        model=model,
        axis_physics=extra_axes,
        seed=seed,
        adc_rate_hz=cfg.adc.sample_rate_hz,
        samples_per_frame=cfg.adc.samples_per_frame,
        ambient_c=profile.ambient_c,
        workdir=workdir,
        faults=faults,
        keep_truth=keep_truth,
        tcp=specs["thermometer"].sim_address == "dmm_tcp_resource",
        tick_s=sim_tick_s(speed),
        # Slow while the drivers connect (imports, port set-up: wall seconds that would be
        # hundreds of simulated seconds at full speed), yet one tick per 0.1 s wall so
        # that the change to ``speed`` (run_acquisition) takes effect at once.
        speed=min(speed or CONNECT_SPEED, CONNECT_SPEED),
    )
    adc = bench.physics.adc
    cfg = replace(
        cfg,
        adc=replace(
            cfg.adc,
            bits=int(adc.bits),
            vref_v=float(adc.vref_v),
            gain_v_per_dps=float(adc.gain_v_per_dps),
            offset_v=float(adc.offset_v),
            axes=1 + len(axis_models),
        ),
    )
    bench.start()
    where = bench.resources()
    handle = SimHandle(
        dmm_resource=where[specs["thermometer"].sim_address],
        oven_port=where[specs["chamber"].sim_address],
        adc_port=bench.adc_port,
        clock=bench.clock,
        stop=bench.stop,
        time_scale=speed if speed is not None else _SIM_FAST_SCALE,
        timeout_floor_s=SIM_TIMEOUT_FLOOR_S,
        speed=speed,
        bench=bench,
        provenance=provenance(bench.physics.model, seed),
        axes_provenance=(
            {"axes": 1 + len(axis_models), "models_toml": [m.to_toml() for m in axis_models]}
            if axis_models
            else None
        ),
    )
    return handle, cfg


def sim_tick_s(speed: float | None) -> float:
    """Simulated seconds per bench tick: 0.1 s in real time (a smooth stream), up to 1 s
    when fast (about 100-300 ticks per wall second: each tick wakes every waiting thread,
    and fewer wake-ups leave the GIL to the drivers)."""
    if speed is None:
        return 1.0
    return float(min(1.0, max(0.1, speed / 100.0)))


# Simulated-bench speed while the drivers connect (see start_sim_bench).
CONNECT_SPEED = 10.0

# Lost communication with a simulated instrument also needs this much wall time of
# silence (see Acquisition._watchdog); a real bench runs in real time and needs none.
SIM_COMM_MIN_WALL_S = 1.0

# Timeouts of a free-running simulated bench are scaled as if it ran this much faster
# than real time (it is throttled by the ADC reader, ~ a few hundred times real time).
_SIM_FAST_SCALE = 200.0


class _SimClockAdapter:
    """The simulated bench's clock as the runner's Clock (sleep in simulated seconds)."""

    def __init__(self, clock: Any) -> None:
        self.c = clock

    def now(self) -> float:
        return float(self.c.now())

    def sleep(self, dt: float) -> None:
        if dt > 0:
            # Bounded wall wait so that a stopped clock cannot hang a thread.
            self.c.sleep(dt, 1.0)


# --------------------------------------------------------------------------- acquire


def _progress(profile: Profile, speed_note: str) -> tuple[Callable[[Status], None], Any]:
    from gyrolab.progress import progress

    bar = progress(total=round(profile.duration_s), desc="acquire", unit="s")
    state = {"t": 0}

    def show(st: Status) -> None:
        t = int(min(st.t, profile.duration_s))
        if t > state["t"]:
            bar.update(t - state["t"])
            state["t"] = t
        bar.set_postfix_str(
            f"step {st.step + 1}/{st.n_steps} SP {st.setpoint_c:.1f} "
            f"oven {st.chamber_c:.2f} PT100 {st.pt100_c:.2f} °C "
            f"ETA(run) {_hms(st.remaining_s)} lost {st.frames_lost} bad {st.frames_bad}"
            f"{speed_note}",
            refresh=False,
        )

    return show, bar


def _hms(s: float) -> str:
    if not math.isfinite(s):
        return "?"
    s = int(s)
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"


def _trace_writer() -> Callable[[float], None] | None:
    """``GYROLAB_TRACE_FD``: write the run time up to which ADC samples have been
    received there, as they arrive (the kill test's measure of what a crash lost)."""
    fd = os.environ.get("GYROLAB_TRACE_FD")
    if not fd:
        return None
    n = int(fd)

    def trace(t_end: float) -> None:
        # Unbuffered write: what reached the pipe survives the writer's kill -9.
        os.write(n, f"{t_end:.6f}\n".encode())

    return trace


@contextlib.contextmanager
def _open_output(path: Path, force: bool) -> Iterator[Any]:
    """The recording file, created in place: exclusive unless ``force``."""
    check_output(path, force)
    mode = "wb" if force else "xb"
    try:
        fh = open(path, mode)  # noqa: SIM115 - closed below, after the writer
    except FileExistsError:
        raise InputError(path, "already exists (use --force to overwrite)") from None
    try:
        yield fh
    finally:
        fh.close()


def run_acquisition(
    *,
    cfg: BenchConfig,
    profile: Profile,
    out: Path,
    force: bool,
    sim: SimHandle | None,
    seed: int | None = None,
    speed: float | None = None,
    on_status: Callable[[Status], None] | None = None,
    on_samples: Callable[[float], None] | None = None,
    acquisition_hook: Callable[[Acquisition], None] | None = None,
    live: Any = None,
) -> RunResult:
    """Connect, record one run to ``out`` and end cleanly; returns how it ended.

    ``live``: a :class:`~gyrolab.acquisition.live.LiveServer` fed every recorded message."""
    check_profile_limits(profile, cfg.limits, str(cfg.run.profile))
    check_output(out, force)
    if sim is not None:
        clock: Any = _SimClockAdapter(sim.clock)
        inst = connect_instruments(
            cfg,
            dmm_resource=sim.dmm_resource,
            oven_port=sim.oven_port,
            adc_port=sim.adc_port,
            time_scale=sim.time_scale,
            timeout_floor_s=sim.timeout_floor_s,
        )
    else:
        clock = WallClock()
        inst = connect_instruments(
            cfg,
            dmm_resource=registry.address(cfg.multimeter, "thermometer"),
            oven_port=registry.address(cfg.oven, "chamber"),
            adc_port=registry.address(cfg.adc, "rate_stream"),
        )
    try:
        run_meta: dict[str, Any] = {
            "operator": cfg.run.operator,
            "unit_serial": cfg.run.unit_serial,
            "unit_model": cfg.run.unit_model,
            "notes": cfg.run.notes,
            "start_time": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "profile": profile.to_dict(),
            "source": "acquire",
            "bench_name": cfg.name,
        }
        if sim is not None:
            run_meta.update(seed=seed, speed=speed if speed is not None else "max")
        if cfg.adc.axes > 1:
            run_meta["axes"] = cfg.adc.axes  # as simulate writes it (recording-format.md)
        bench_meta: dict[str, Any] = {
            "name": cfg.name,
            "simulated": sim is not None,
            **inst.identity,
            "limits": cfg.to_dict()["limits"],
            "safe_state": cfg.to_dict()["safe_state"],
            "recorder": cfg.to_dict()["recorder"],
        }
        r = cfg.recorder
        with _open_output(out, force) as fh:
            writer = RecordingWriter(
                fh,
                start_time_ns=time.time_ns(),
                run=run_meta,
                bench=bench_meta,
                chunk_size=r.chunk_size,
                flush_every_s=r.flush_every_s,
                fsync_every_s=r.fsync_every_s,
            )
            if live is not None:
                live.attach(writer)
            try:
                if sim is not None and sim.provenance:
                    writer.write_metadata("sim_provenance", sim.provenance)
                if sim is not None and sim.axes_provenance:
                    writer.write_metadata("sim_provenance_axes", sim.axes_provenance)
                fh.flush()  # header + metadata on disk before the first reading
                assert inst.thermometer and inst.oven and inst.gyro
                acq = Acquisition(
                    profile=profile,
                    writer=writer,
                    clock=clock,
                    thermometer=inst.thermometer,
                    oven=inst.oven,
                    gyro=inst.gyro,
                    adc=cfg.adc,
                    limits=cfg.limits,
                    safe_state=cfg.safe_state,
                    pt100_period_s=cfg.multimeter.period_s,
                    oven_period_s=cfg.oven.period_s,
                    on_status=on_status,
                    on_samples=on_samples,
                    comm_timeout_min_wall_s=0.0 if sim is None else SIM_COMM_MIN_WALL_S,
                )
                if acquisition_hook is not None:
                    acquisition_hook(acq)
                if sim is not None:
                    sim.clock.speed = sim.speed  # connected: now run at the asked speed
                interrupts.check()  # a stop signal while connecting: end before the run
                result = acq.run()
            finally:
                # Also on an interrupt before the run started: a finished, readable file.
                writer.close()
        return result
    finally:
        inst.close()


def _start_live(port: int, host: str) -> Any:
    """The live view's server (docs/live-view.md); a port in use is one line, exit 2."""
    from gyrolab.acquisition.live import LiveServer

    live = LiveServer(port=port, host=host)
    print(f"live view: {live.url} (Foxglove: Open connection)", file=sys.stderr)
    if host not in ("127.0.0.1", "localhost", "::1"):
        print(
            f"live view: listening on {host}, reachable from the network without "
            "authentication; an SSH tunnel to 127.0.0.1 is the safer way",
            file=sys.stderr,
        )
    return live


@interrupts.deferring_stop_signals
def acquire(args: argparse.Namespace) -> int:
    """``gyrolab acquire --bench sim|BENCH.toml --out RUN.mcap [--profile] [--speed]``."""
    out = Path(args.out)
    if args.speed is not None and not (args.speed > 0 and math.isfinite(args.speed)):
        raise GyrolabError(f"--speed must be a positive number, not {args.speed}")
    drivers = getattr(args, "driver", None) or []
    if drivers and args.bench != "sim":
        raise GyrolabError("--driver applies to --bench sim only (a bench file names its drivers)")
    axis_paths = getattr(args, "axis_model", None) or []
    if axis_paths and args.bench != "sim":
        raise GyrolabError(
            "--axis-model applies to --bench sim only (a bench file sets [adc] axes)"
        )
    if args.bench == "sim":
        cfg = sim_drivers(sim_bench_config(args.seed), drivers)
    else:
        cfg = load_bench(args.bench)
        if args.speed is not None:
            raise GyrolabError(
                "--speed applies to --bench sim only (real hardware runs in real time)"
            )
    axis_models = []
    if axis_paths:
        from gyrolab.sim.model import load_model

        if len(axis_paths) > 2:
            raise InputError("--axis-model", "a unit has at most 3 axes (give it at most twice)")
        axis_models = [load_model(m) for m in axis_paths]
    faults_path = getattr(args, "faults", None)
    faults = None
    if faults_path is not None:
        if args.bench != "sim":
            raise GyrolabError("--faults applies to --bench sim only (it drives the simulator)")
        from gyrolab.sim.bench.fault_file import load_faults

        faults = load_faults(faults_path)
    profile_spec = args.profile or cfg.profile_path()
    profile = load_profile(profile_spec)
    if args.profile:
        cfg = replace(cfg, run=replace(cfg.run, profile=str(args.profile)))
    check_profile_limits(profile, cfg.limits, str(args.profile or cfg.run.profile))
    check_bench_for_profile(cfg, profile, str(profile_spec))
    inputs = (None if args.bench == "sim" else args.bench, profile_spec, faults_path, *axis_paths)
    check_output(out, args.force, inputs=inputs, kind="file")

    sim: SimHandle | None = None
    from gyrolab.acquisition.simdir import sim_workdir

    interrupts.check()  # a stop signal while the inputs were read: end before the bench

    old_switch = sys.getswitchinterval()
    if args.bench == "sim":
        # The simulated instruments share this process (and its GIL) with the drivers:
        # hand the GIL over sooner so that a waiting driver thread is not held 5 ms per
        # switch by the busy ones (a Modbus transaction needs several switches).
        sys.setswitchinterval(0.0005)

    with sim_workdir() as work:
        if args.bench == "sim":
            sim, cfg = start_sim_bench(
                cfg,
                profile,
                seed=args.seed,
                speed=args.speed,
                workdir=Path(work),
                faults=faults,
                axis_models=axis_models,
            )
            if faults is not None:
                from gyrolab.sim.bench.fault_file import plan_to_dict

                sim.provenance["fault_injection"] = plan_to_dict(faults)
        speed_note = "" if sim is None else f" ×{args.speed or 'max'}"
        show, bar = _progress(profile, speed_note)
        t0 = time.monotonic()
        live = None
        try:
            interrupts.check()  # a stop signal while the bench started: end here
            if getattr(args, "live", None) is not None:
                live = _start_live(args.live, args.live_host)
                show = live.status_hook(show)
            result = run_acquisition(
                cfg=cfg,
                profile=profile,
                out=out,
                force=args.force,
                sim=sim,
                seed=args.seed,
                speed=args.speed,
                on_status=show,
                on_samples=_trace_writer(),
                live=live,
            )
        finally:
            bar.close()
            if live is not None:
                live.close()
                print(
                    f"live view: {live.published} messages published, {live.dropped} dropped",
                    file=sys.stderr,
                )
            if sim is not None:
                sim.stop()
            sys.setswitchinterval(old_switch)
    wall = time.monotonic() - t0
    msg = (
        f"gyrolab acquire: {result.outcome} ({result.reason}); {result.t_end:.0f} s recorded in "
        f"{wall:.1f} s wall, {result.samples} samples, {result.gaps} gap(s) "
        f"({result.samples_missing} samples missing), {result.faults} fault(s); "
        f"oven safe state {'verified' if result.safe_state_ok else 'NOT verified'}; {out}"
    )
    print(msg, file=sys.stderr)
    return result.exit_code


# --------------------------------------------------------------------------- recover


def recover(args: argparse.Namespace) -> int:
    """``gyrolab recover BROKEN.mcap --out FIXED.mcap``: salvage and report what was lost."""
    from gyrolab.record.recover import recover_recording

    rep = recover_recording(args.broken, args.out, force=args.force)
    print(rep.summary())
    return 0
