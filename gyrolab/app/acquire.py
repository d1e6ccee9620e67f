"""Acquire one run on a configured bench: typed options in, :class:`RunResult` out.

``bench="sim"`` first starts the simulated bench (:mod:`gyrolab.app.sim_bench`: the same
wire protocols over pseudo-terminals, one simulated clock) and then does exactly the same
as for a BENCH.toml: the drivers, the run engine and the recorder cannot tell the
difference. Each role's instrument is opened at an address (``addresses``, keyed by the
registry's role names), so a bench with more instruments adds addresses, not code paths.

The recording is written directly to ``out`` (never over an existing file unless
``force``), so that a crash leaves a recoverable file at the named path
(docs/reliability.md); :func:`recover` repairs it.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import math
import os
import sys
import time
import uuid
from collections.abc import Callable, Iterator, Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

from gyrolab.acquisition import interrupts
from gyrolab.acquisition.bench_config import (
    BenchConfig,
    check_bench_for_profile,
    load_bench,
)
from gyrolab.acquisition.resume import ResumePoint, bench_differences
from gyrolab.acquisition.runner import (
    Acquisition,
    RunResult,
    Status,
    UnitDevices,
)
from gyrolab.app.options import AcquireOptions, RecoverOptions
from gyrolab.app.sim_bench import SimHandle, sim_bench_config, sim_drivers, start_sim_bench
from gyrolab.clock import Clock, WallClock
from gyrolab.errors import GyrolabError, InputError
from gyrolab.instruments import registry
from gyrolab.instruments.roles import Chamber, MultiThermometer, RateStream, Thermometer
from gyrolab.outputs import check_output
from gyrolab.profiles.plan import check_profile_limits
from gyrolab.profiles.profile import Profile, load_profile, profile_from_dict
from gyrolab.record.metadata import BenchMetadata, RunMetadata
from gyrolab.record.reader import segments
from gyrolab.record.writer import RecordingWriter

# --------------------------------------------------------------------- instruments


class Instruments:
    """The three connected drivers (each implements its role, gyrolab.instruments.roles)
    and their identities."""

    def __init__(self) -> None:
        self.closers: list[Callable[[], None]] = []
        self.identity: dict[str, Any] = {}
        self.thermometer: Thermometer | None = None
        self.chamber: Chamber | None = None
        self.gyro: RateStream | None = None
        # A multi-unit bench: the scanner and (serial, stream) per unit, in bench order.
        self.scanner: MultiThermometer | None = None
        self.units: list[tuple[str, RateStream]] = []

    def close(self) -> None:
        for c in reversed(self.closers):
            with contextlib.suppress(Exception):
                c()
        self.closers.clear()


def as_configured(timeout_s: float) -> float:
    """The lab's driver-timeout rule: the configured timeout (docs/bench-config.md)."""
    return timeout_s


def lab_addresses(cfg: BenchConfig) -> dict[str, str]:
    """Each role's instrument address as BENCH.toml gives it; on a multi-unit bench the
    chamber's, the scanner's (``multi_thermometer``) and each unit's stream's
    (``unit/<serial>``)."""
    if cfg.units:
        scanner = (
            {"multi_thermometer": registry.address(cfg.scanner, "multi_thermometer")}
            if cfg.scanner is not None  # none when every unit is on its internal sensor
            else {}
        )
        return {
            "chamber": registry.address(cfg.chamber, "chamber"),
            **scanner,
            **{
                f"unit/{u.serial}": registry.address(u.rate_stream, "rate_stream")
                for u in cfg.units
            },
        }
    return {
        "thermometer": registry.address(cfg.thermometer, "thermometer"),
        "chamber": registry.address(cfg.chamber, "chamber"),
        "rate_stream": registry.address(cfg.rate_stream, "rate_stream"),
    }


def connect_instruments(
    cfg: BenchConfig,
    addresses: Mapping[str, str],
    *,
    timeout: Callable[[float], float] = as_configured,
    visa_library: Any = "@py",
    clock: Callable[[], float] = time.monotonic,
) -> Instruments:
    """Open and identify the bench's drivers (``driver`` of each role's table,
    gyrolab.instruments.registry) at ``addresses`` (role → address); raises InputError
    naming what failed.

    ``timeout`` maps each configured driver timeout to the one used: as configured on a lab
    bench (the engineer's choice, docs/bench-config.md); the simulated bench supplies its
    own rule (:func:`gyrolab.app.sim_bench.scaled_timeouts`). A multi-unit bench
    (``cfg.units``) opens the chamber, the scanner and every unit's rate stream, each
    stream named ``unit/<serial>`` in the recording (its address ``addresses["unit/<serial>"]``).
    """
    inst = Instruments()
    src = cfg.source
    limits = (cfg.limits.setpoint_min_c, cfg.limits.setpoint_max_c)
    # (attribute, role, driver config, address key, table in BENCH.toml)
    opening: list[tuple[str, str, Any, str, str]]
    if cfg.units:
        opening = [("chamber", "chamber", cfg.chamber, "chamber", "[chamber]")]
        if cfg.scanner is not None:
            opening.append(
                ("scanner", "multi_thermometer", cfg.scanner, "multi_thermometer", "[scanner]")
            )
        opening += [
            ("units", "rate_stream", u.rate_stream, f"unit/{u.serial}", f"[[unit]] {u.serial}")
            for u in cfg.units
        ]
    else:
        opening = [
            ("thermometer", "thermometer", cfg.thermometer, "thermometer", "[thermometer]"),
            ("chamber", "chamber", cfg.chamber, "chamber", "[chamber]"),
            ("gyro", "rate_stream", cfg.rate_stream, "rate_stream", "[rate_stream]"),
        ]
    try:
        for attr, role, sub, key, table in opening:
            address = addresses[key]
            ctx = registry.OpenContext(address, timeout, limits, clock, visa_library)
            try:
                dev = registry.open_driver(sub, role, ctx)
            except Exception as e:
                raise InputError(src, f"{table} {sub.driver} at {address}: {e}") from None
            inst.closers.append(dev.close)
            if attr == "units":
                dev.name = key  # unit/<serial>: a unit's stream, named for its unit
                serial = key.split("/", 1)[1]
                inst.units.append((serial, dev))
                inst.identity.setdefault("units", {})[serial] = {"adc": dev.describe()}
                continue
            setattr(inst, attr, dev)
            inst.identity[dev.name] = dev.describe()
        for u in cfg.units:  # where each unit's temperature comes from
            unit = inst.identity["units"][u.serial]
            unit["temperature_source"] = u.temperature
            if u.temperature_channel is not None:
                unit["temperature_channel"] = u.temperature_channel
    except BaseException:
        inst.close()
        raise
    return inst


# --------------------------------------------------------------------------- acquire


def _progress(profile: Profile, speed_note: str) -> tuple[Callable[[Status], None], Any]:
    """The run's progress bar: run seconds done of the profile's, and one ETA — the run
    time still to go (the plan's, which knows a step held by its stability rule) at the
    pace the run keeps (run seconds per wall second, as tqdm measures it)."""
    from gyrolab.progress import progress

    bar = progress(
        total=round(profile.duration_s),
        desc="acquire",
        unit="s",
        # tqdm's own "<remaining" is left out: it would be a second ETA, from the profile's
        # nominal duration rather than the plan's
        bar_format="{l_bar}{bar}| {n_fmt}/{total_fmt} s [{elapsed}, {rate_fmt}{postfix}]",
    )
    state = {"t": 0}

    def show(st: Status) -> None:
        if bar.disable:  # GYROLAB_NO_PROGRESS: nothing to draw
            return
        t = int(min(st.t, profile.duration_s))
        if t > state["t"]:
            bar.update(t - state["t"])
            state["t"] = t
        units = ""
        if st.units:  # a multi-unit run: how many units are fully recorded
            ok = sum(u.state == "recording" for u in st.units)
            units = f" units {ok}/{len(st.units)} ok"
        if st.suspended:
            units += f" SUSPENDED ({', '.join(st.suspended)})"
        pace = bar.format_dict.get("rate") or 0.0  # run s per wall s; 0 before it is known
        eta = st.remaining_s / pace if pace > 0 else math.nan
        bar.set_postfix_str(
            f"step {st.step + 1}/{st.n_steps} SP {st.setpoint_c:.1f} "
            f"oven {st.chamber_c:.2f} {_SENSOR[st.temperature_source]} {st.temperature_c:.2f} °C "
            f"ETA {_hms(eta)} lost {st.frames_lost} bad {st.frames_bad}"
            f"{units}{speed_note}",
            refresh=False,
        )

    return show, bar


_SENSOR = {"pt100": "PT100", "internal": "internal"}  # the progress line's name for it


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
    """The recording file, created in place, always as a new file (``O_EXCL``): with
    ``force`` the existing name is removed first — a symbolic link is replaced, not written
    through to its target, and a hard link's other names keep their data."""
    check_output(path, force)
    if force and (path.is_symlink() or path.is_file()):
        path.unlink()
    try:
        fh = open(path, "xb")  # noqa: SIM115 - closed below, after the writer
    except FileExistsError:
        raise InputError(path, "already exists (use --force to overwrite)") from None
    except OSError as e:
        raise InputError(path, f"cannot be written ({e.strerror})") from None
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
    on_status: Callable[[Status], None] | None = None,
    on_samples: Callable[[float], None] | None = None,
    live: Any = None,
    resume: ResumePoint | None = None,
) -> RunResult:
    """Connect, record one run to ``out`` and end cleanly; returns how it ended.

    ``sim``: the simulated bench to run against (its addresses, clock and policies), or
    None for the instruments BENCH.toml names, in real time. ``live``: a
    :class:`~gyrolab.acquisition.live.LiveServer` fed every recorded message. ``resume``:
    the run continues an interrupted one (a continuation: its next segment, on the same
    bench — checked once connected, before anything is written)."""
    check_profile_limits(profile, cfg.limits, str(cfg.run.profile))
    check_output(out, force)
    clock: Clock
    if sim is not None:
        clock = sim.clock
        inst = connect_instruments(cfg, sim.addresses, timeout=sim.timeout)
    else:
        clock = WallClock()
        inst = connect_instruments(cfg, lab_addresses(cfg))
    try:
        run_meta = RunMetadata(
            source="acquire",
            start_time=_dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            profile=profile.to_dict(),
            operator=cfg.run.operator,
            unit_serial=cfg.run.unit_serial,
            unit_model=cfg.run.unit_model,
            notes=cfg.run.notes,
            bench_name=cfg.name,
            seed=seed if sim is not None else None,
            speed=(sim.speed if sim.speed is not None else "max") if sim is not None else None,
            axes=cfg.rate_stream.axes,
            run_id=uuid.uuid4().hex if resume is None else resume.run_id,
            segment=1 if resume is None else resume.segment,
            previous_segment=None if resume is None else resume.previous_segment,
            resumed=None if resume is None else resume.resumed,
        )
        tables = cfg.to_dict()
        ident = dict(inst.identity)  # each instrument's describe(), by role name
        bench_meta = BenchMetadata(
            name=cfg.name,
            simulated=sim is not None,
            multimeter=ident.pop("multimeter", None),
            oven=ident.pop("oven", None),
            adc=ident.pop("adc", None),
            limits=tables["limits"],
            safe_state=tables["safe_state"],
            recorder=tables["recorder"],
            units=ident.pop("units", None),  # multi-unit: each unit's ADC
            extra={**ident, "suspend": tables["suspend"]},  # e.g. a multi-unit bench's scanner
        )
        if resume is not None:
            differ = bench_differences(resume.bench, bench_meta.to_dict())
            if differ:
                raise InputError(
                    resume.previous, "not the bench the run was on: " + "; ".join(differ)
                )
        r = cfg.recorder
        with _open_output(out, force) as fh:
            writer = RecordingWriter(
                fh,
                # a continuation's log times count from the run's origin: one run clock
                start_time_ns=time.time_ns() if resume is None else resume.start_time_ns,
                run=run_meta,
                bench=bench_meta,
                chunk_size=r.chunk_size,
                flush_every_s=r.flush_every_s,
                fsync_every_s=r.fsync_every_s,
                units=[u.serial for u in cfg.units] if cfg.units else None,
                internal_temperature=[u.serial for u in cfg.units if u.internal],
            )
            if live is not None:
                live.attach(writer)
            try:
                for name, record in (sim.metadata if sim is not None else {}).items():
                    if record:
                        writer.write_metadata(name, record)
                fh.flush()  # header + metadata on disk before the first reading
                assert inst.chamber is not None
                devices: dict[str, Any]
                if cfg.units:  # the scanner reads the PT100s; a unit's own sensor, its stream
                    devices = {
                        "thermometer": inst.scanner,
                        "units": [
                            UnitDevices(u.serial, stream, u.rate_stream, u.temperature_channel)
                            for u, (_, stream) in zip(cfg.units, inst.units, strict=True)
                        ],
                    }
                    if cfg.scanner is not None:
                        devices["pt100_period_s"] = cfg.scanner.period_s
                else:
                    assert inst.thermometer and inst.gyro
                    devices = {
                        "thermometer": inst.thermometer,
                        "gyro": inst.gyro,
                        "rate_stream": cfg.rate_stream,
                        "pt100_period_s": cfg.thermometer.period_s,
                    }
                acq = Acquisition(
                    profile=profile,
                    writer=writer,
                    clock=clock,
                    chamber=inst.chamber,
                    limits=cfg.limits,
                    safe_state=cfg.safe_state,
                    **devices,
                    chamber_period_s=cfg.chamber.period_s,
                    on_status=on_status,
                    on_samples=on_samples,
                    silence=None if sim is None else sim.silence,
                    hold_silence=None if sim is None else sim.hold_silence,
                    suspend=cfg.suspend,
                    resume=resume,
                )
                if sim is not None:
                    sim.go()  # connected: now run at the asked speed
                interrupts.check()  # a stop signal while connecting: end before the run
                print(
                    f"gyrolab acquire: pid {os.getpid()} (kill -USR1 pauses the run, -USR2 "
                    "resumes it)",
                    file=sys.stderr,
                )
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
def acquire(opts: AcquireOptions) -> RunResult:
    """Check every input, run the bench (starting the simulated one for ``bench="sim"``),
    record to ``opts.out`` and print the one-line summary on stderr; returns how the run
    ended (``RunResult.exit_code``). Bad input raises GyrolabError before anything starts.
    ``opts.resume``: continue that interrupted run instead (:func:`_resumed`)."""
    resume: ResumePoint | None = None
    resumed_axes: tuple[str, ...] = ()  # a resumed multi-axis run's other axes' models
    if opts.resume is not None:
        opts, resume, resumed_axes = _resumed(opts)
    if opts.out is None:
        raise GyrolabError("--out RUN.mcap is required")
    out = Path(opts.out)
    sim_only = opts.bench == "sim"  # the options' own rules are checked (AcquireOptions)
    if sim_only:
        base = sim_bench_config(opts.seed, opts.units, opts.internal_temperature)
        cfg = sim_drivers(base, opts.drivers)
    else:
        cfg = load_bench(opts.bench)
    axis_models = []
    if opts.axis_models:
        from gyrolab.sim.model import load_sim_model

        axis_models = [load_sim_model(m) for m in opts.axis_models]
    elif resumed_axes:
        from gyrolab.sim.model import SimModel
        from gyrolab.tomlfile import tomllib

        axis_models = [SimModel.from_dict(tomllib.loads(t)) for t in resumed_axes]
    faults = None
    if opts.faults is not None:
        from gyrolab.sim.bench.fault_file import check_plan_for_bench, load_faults

        faults = load_faults(opts.faults)
        # the F4 reports its alarm through [chamber] alarm_input, the ESPEC always
        alarm = cfg.chamber.driver != "watlowf4" or bool(getattr(cfg.chamber, "alarm_input", 0))
        check_plan_for_bench(
            faults, opts.units, str(opts.faults), opts.internal_temperature, chamber_alarm=alarm
        )
    profile_spec = opts.profile or cfg.profile_path()
    if resume is not None:
        profile_spec = str(resume.previous)
        profile = profile_from_dict(resume.run["profile"], profile_spec)
    else:
        profile = load_profile(profile_spec)
    if opts.profile:
        cfg = replace(cfg, run=replace(cfg.run, profile=str(opts.profile)))
    check_profile_limits(profile, cfg.limits, str(opts.profile or cfg.run.profile))
    check_bench_for_profile(cfg, profile, str(profile_spec))
    inputs = (None if sim_only else opts.bench, profile_spec, opts.faults, *opts.axis_models)
    if resume is not None:  # every segment of the run is an input: none is written over
        inputs += tuple(str(p) for p in segments(resume.previous))
    check_output(out, opts.force, inputs=inputs, kind="file")

    sim: SimHandle | None = None
    from gyrolab.acquisition.simdir import sim_workdir

    interrupts.check()  # a stop signal while the inputs were read: end before the bench

    old_switch = sys.getswitchinterval()
    if sim_only:
        # The drivers' threads (a reader per unit, the pollers) share this process's GIL:
        # hand it over sooner so that a waiting driver thread is not held 5 ms per switch
        # by the busy ones (a Modbus transaction needs several switches).
        sys.setswitchinterval(0.0005)

    with sim_workdir() as work:
        if sim_only:
            sim, cfg = start_sim_bench(
                cfg,
                profile,
                seed=opts.seed,
                speed=opts.speed,
                workdir=Path(work),
                faults=faults,
                axis_models=axis_models,
                # Several units: the instruments on a core of their own (one process
                # reached 233x of 300x with 8 units). One unit: in this process, where a
                # reply crosses no process boundary (docs/performance.md).
                own_process=bool(cfg.units),
            )
        speed_note = "" if sim is None else f" ×{opts.speed or 'max'}"
        t0 = time.monotonic()
        live = bar = None
        try:
            interrupts.check()  # a stop signal while the bench started: end here
            if opts.live_port is not None:
                # before the progress bar starts: the URL gets a line of its own
                live = _start_live(opts.live_port, opts.live_host)
            show, bar = _progress(profile, speed_note)
            if live is not None:
                show = live.status_hook(show)
            result = run_acquisition(
                cfg=cfg,
                profile=profile,
                out=out,
                force=opts.force,
                sim=sim,
                seed=opts.seed,
                on_status=show,
                on_samples=_trace_writer(),
                live=live,
                resume=resume,
            )
        finally:
            if bar is not None:
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
        f"({result.samples_missing} samples missing), {result.faults} fault(s), "
        f"{result.suspensions} suspension(s); "
        f"oven safe state {'verified' if result.safe_state_ok else 'NOT verified'}; {out}"
    )
    if cfg.units:
        dropped = ", ".join(result.units_dropped) or "none"
        msg += f" ({len(cfg.units)} units; dropped: {dropped})"
    if resume is not None:
        msg += (
            f"; segment {resume.segment} of run {resume.run_id}, resumed at step "
            f"{resume.step + 1} after {resume.previous.name} (read the run from {out.name})"
        )
    print(msg, file=sys.stderr)
    return result


def _resumed(opts: AcquireOptions) -> tuple[AcquireOptions, ResumePoint, tuple[str, ...]]:
    """``--resume``: the options of the continuation, from the run (gyrolab/app/resume.py),
    where it starts, and a simulated multi-axis run's other axes' models (TOML texts).
    What the run fixed — its profile, and on the simulated bench its seed, units, axes and
    drivers — cannot be given again; a lab bench needs its BENCH.toml."""
    from gyrolab.app.resume import continuation_path, resume_settings

    fixed = {
        "--profile": opts.profile,
        "--units": opts.units,
        "--internal-temperature": opts.internal_temperature,
        "--driver": opts.drivers,
        "--axis-model": opts.axis_models,
        "--seed": opts.seed,
    }
    given = [k for k, v in fixed.items() if v]
    if given:
        raise GyrolabError(f"--resume continues the run as it was: {', '.join(given)} not allowed")
    rs = resume_settings(opts.resume, opts.force)  # type: ignore[arg-type]
    bench = opts.bench or ("sim" if rs.simulated else "")
    if not bench:
        raise GyrolabError("--resume of a run on a lab bench: give its --bench BENCH.toml")
    if bench == "sim" and not rs.simulated:
        raise GyrolabError("--resume: the run was on a lab bench, not --bench sim")
    out = opts.out if opts.out is not None else continuation_path(rs.point)
    sim_kw: dict[str, Any] = {}
    if bench == "sim":
        speed = opts.speed if opts.speed is not None else rs.speed
        sim_kw = dict(
            seed=rs.seed,
            units=rs.units,
            internal_temperature=rs.internal,
            drivers=rs.drivers,
            speed=speed,
        )
    axes = rs.axis_models if bench == "sim" else ()
    return replace(opts, bench=bench, out=Path(out), resume=None, **sim_kw), rs.point, axes


# --------------------------------------------------------------------------- recover


def recover(broken: str | Path, out: str | Path, force: bool = False) -> str:
    """Salvage every complete record of ``broken`` into ``out``; returns the summary of
    what was kept and what was lost."""
    from gyrolab.record.recover import recover_recording

    return str(recover_recording(broken, out, force=force).summary())


def acquire_command(opts: AcquireOptions) -> int:
    """The ``gyrolab acquire`` command: :func:`acquire`, its exit code (docs/cli.md)."""
    return acquire(opts).exit_code


def recover_command(opts: RecoverOptions) -> int:
    """The ``gyrolab recover`` command: :func:`recover`, its summary printed."""
    print(recover(opts.broken, opts.out, force=opts.force))
    return 0
