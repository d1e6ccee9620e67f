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

from gyrolab.acquisition.bench_config import (
    BenchConfig,
    RunInfo,
    check_bench_for_profile,
    load_bench,
)
from gyrolab.acquisition.runner import (
    Acquisition,
    InstrumentFault,
    RunResult,
    Status,
    WallClock,
    check_profile_limits,
)
from gyrolab.errors import GyrolabError, InputError
from gyrolab.outputs import check_output
from gyrolab.profile import Profile, load_profile
from gyrolab.recording import RecordingWriter

# ---------------------------------------------------------------- device adapters


class MultimeterDevice:
    """The runner's :class:`~gyrolab.acquisition.runner.Thermometer` on a 34401A."""

    name = "multimeter"

    def __init__(self, drv: Any) -> None:
        self.drv = drv
        self._reports: list[Any] = []

    def read(self) -> tuple[float, float]:
        from gyrolab.acquisition.multimeter import scpi_reports

        r = self.drv.read()
        # The error queue after every reading: an error the meter raises mid-run (e.g.
        # -310 system error) is logged as a fault and, by its class, stops the run.
        self._reports += scpi_reports(self.drv.errors, "after READ?")
        return float(r.resistance_ohm), float(r.temperature_c)

    def reports(self) -> list[Any]:
        """SCPI error-queue entries read since the last call (InstrumentReport)."""
        out, self._reports = self._reports, []
        return out


class OvenDevice:
    """The runner's :class:`~gyrolab.acquisition.runner.Oven` on a Watlow F4."""

    name = "oven"

    def __init__(self, drv: Any) -> None:
        self.drv = drv

    def set_setpoint(self, setpoint_c: float) -> None:
        self.drv.set_setpoint(setpoint_c)

    def read(self) -> tuple[float, float]:
        sp = self.drv.setpoint_c
        pv = self.drv.process_value_c
        st = self.drv.status
        if st.sensor_fault:
            # The controller cannot see the chamber: nothing it does can be trusted.
            raise InstrumentFault(f"oven controller reports a sensor fault (status {st.raw:#x})")
        return float(sp), float(pv)

    def reports(self) -> list[Any]:
        """Modbus exception responses since the last call (InstrumentReport)."""
        return list(self.drv.pop_reports())


class GyroDevice:
    """The runner's :class:`~gyrolab.acquisition.runner.GyroStream` on a GyroAdcReader."""

    name = "adc"

    def __init__(self, reader: Any) -> None:
        self.reader = reader

    def read(self, timeout_s: float) -> Any:
        return self.reader.read(timeout_s)

    def counters(self) -> dict[str, int]:
        d = self.reader.decoder.stats
        s = self.reader.stats
        return {
            "frames_ok": d.frames_ok,
            # Damaged frames: CRC failures, and CRC-passing frames whose timestamp
            # disagrees with their sequence number. (Length errors are mostly sync-word
            # look-alikes inside payloads, not frames.)
            "frames_bad": d.crc_errors + d.inconsistent_frames,
            "frames_lost": d.frames_lost,
            "frames_stale": d.stale_frames,
            "gaps": d.gaps,
            "disconnects": s.disconnects,
        }


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
    """The three connected drivers, their runner adapters and identities."""

    def __init__(self) -> None:
        self.closers: list[Callable[[], None]] = []
        self.identity: dict[str, Any] = {}
        self.thermometer: MultimeterDevice | None = None
        self.oven: OvenDevice | None = None
        self.gyro: GyroDevice | None = None

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
    visa_library: str = "@py",
    clock: Callable[[], float] = time.monotonic,
) -> Instruments:
    """Open and identify the three instruments; raises InputError naming what failed.

    ``time_scale`` divides the drivers' wall-clock timeouts (a simulated bench running
    X× faster than real time answers X× sooner, and a silent one must be noticed X×
    sooner too); when sped up it never takes them below ``timeout_floor_s`` wall
    seconds, which protects against scheduling jitter; in real time the configured
    timeouts are used as they are (``SIM_TIMEOUT_FLOOR_S`` for the simulated bench).
    The oven driver's ``silence_s`` (the quiet wait after a failed transaction) is its
    timeout, scaled the same way.
    """
    from gyrolab.acquisition.gyro_adc import GyroAdcReader
    from gyrolab.acquisition.multimeter import Agilent34401A
    from gyrolab.acquisition.oven import WatlowF4

    inst = Instruments()
    src = cfg.source

    def scaled(t: float) -> float:
        # Real time: the configured timeout is the engineer's choice (docs/bench-config.md);
        # the floor only guards a sped-up simulated bench against scheduling jitter.
        if time_scale <= 1.0:
            return t
        return max(timeout_floor_s, t / time_scale)

    try:
        try:
            dmm = Agilent34401A(
                dmm_resource,
                visa_library=visa_library,
                timeout_s=scaled(cfg.multimeter.timeout_s),
                range_ohm=cfg.multimeter.range_ohm,
                nplc=cfg.multimeter.nplc,
                r0_ohm=cfg.multimeter.r0_ohm,
                baud_rate=cfg.multimeter.baud_rate,
            )
            inst.closers.append(dmm.close)
            idn = dmm.connect()
        except Exception as e:
            raise InputError(src, f"[multimeter] {dmm_resource}: {e}") from None
        inst.thermometer = MultimeterDevice(dmm)
        inst.identity["multimeter"] = {
            "model": "34401A",
            "idn": idn,
            "resource": dmm_resource,
            "serial": cfg.multimeter.serial or _idn_field(idn, 2),
            "calibration_due": cfg.multimeter.calibration_due,
            "range_ohm": cfg.multimeter.range_ohm,
            "nplc": cfg.multimeter.nplc,
            "r0_ohm": cfg.multimeter.r0_ohm,
        }
        try:
            oven_timeout_s = scaled(cfg.oven.timeout_s)
            oven = WatlowF4(
                oven_port,
                address=cfg.oven.slave_address,
                baudrate=cfg.oven.baud_rate,
                timeout_s=oven_timeout_s,
                # A reply later than timeout + silence cannot be told from the next one's
                # (oven.py); the simulated slave is late by scheduling jitter at most.
                silence_s=oven_timeout_s,
                setpoint_limits_c=(cfg.limits.setpoint_min_c, cfg.limits.setpoint_max_c),
            )
            inst.closers.append(oven.close)
            regs = oven.connect()
        except Exception as e:
            raise InputError(src, f"[oven] {oven_port}: {e}") from None
        inst.oven = OvenDevice(oven)
        inst.identity["oven"] = {
            "model": "Watlow F4 (Modbus RTU)",
            "port": oven_port,
            "slave_address": cfg.oven.slave_address,
            "serial": cfg.oven.serial,
            "registers": regs,
        }
        try:
            reader = GyroAdcReader(
                adc_port,
                samples_per_frame=cfg.adc.samples_per_frame,
                rate_hz=cfg.adc.sample_rate_hz,
                baudrate=cfg.adc.baud_rate,
                clock=clock,
            )
            reader.open()
            inst.closers.append(reader.close)
        except Exception as e:
            raise InputError(src, f"[adc] {adc_port}: {e}") from None
        inst.gyro = GyroDevice(reader)
        a = cfg.adc
        inst.identity["adc"] = {
            "port": adc_port,
            "serial": a.serial,
            "sample_rate_hz": a.sample_rate_hz,
            "samples_per_frame": a.samples_per_frame,
            "bits": a.bits,
            "vref_v": a.vref_v,
            "gain_v_per_dps": a.gain_v_per_dps,
            "offset_v": a.offset_v,
            "dps_per_count": a.dps_per_count(),
        }
    except BaseException:
        inst.close()
        raise
    return inst


def _idn_field(idn: str, k: int) -> str:
    parts = [p.strip() for p in idn.split(",")]
    return parts[k] if len(parts) > k else ""


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
) -> tuple[SimHandle, BenchConfig]:
    """Start the wire-level simulated bench; returns it and the bench config to use.

    The config's ADC calibration is the simulated gyro's (what a lab takes from the
    unit's calibration sheet); the multimeter is reached over its simulated RS-232 port,
    the same path as ``examples/lab.toml``.
    """
    from gyrolab.sim.bench import SimBench
    from gyrolab.sim.simulate import provenance

    bench = SimBench(
        model=model,
        seed=seed,
        adc_rate_hz=cfg.adc.sample_rate_hz,
        samples_per_frame=cfg.adc.samples_per_frame,
        ambient_c=profile.ambient_c,
        workdir=workdir,
        faults=faults,
        keep_truth=keep_truth,
        tcp=False,
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
        ),
    )
    bench.start()
    handle = SimHandle(
        dmm_resource=bench.dmm_serial_resource,
        oven_port=bench.oven_port,
        adc_port=bench.adc_port,
        clock=bench.clock,
        stop=bench.stop,
        time_scale=speed if speed is not None else _SIM_FAST_SCALE,
        timeout_floor_s=SIM_TIMEOUT_FLOOR_S,
        speed=speed,
        bench=bench,
        provenance=provenance(bench.physics.model, seed),
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
            dmm_resource=cfg.multimeter.resource,
            oven_port=cfg.oven.port,
            adc_port=cfg.adc.port,
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


def acquire(args: argparse.Namespace) -> int:
    """``gyrolab acquire --bench sim|BENCH.toml --out RUN.mcap [--profile] [--speed]``."""
    out = Path(args.out)
    if args.speed is not None and not (args.speed > 0 and math.isfinite(args.speed)):
        raise GyrolabError(f"--speed must be a positive number, not {args.speed}")
    if args.bench == "sim":
        cfg = sim_bench_config(args.seed)
    else:
        cfg = load_bench(args.bench)
        if args.speed is not None:
            raise GyrolabError(
                "--speed applies to --bench sim only (real hardware runs in real time)"
            )
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
    inputs = (None if args.bench == "sim" else args.bench, profile_spec, faults_path)
    check_output(out, args.force, inputs=inputs, kind="file")

    sim: SimHandle | None = None
    from gyrolab.acquisition.simdir import sim_workdir

    old_switch = sys.getswitchinterval()
    if args.bench == "sim":
        # The simulated instruments share this process (and its GIL) with the drivers:
        # hand the GIL over sooner so that a waiting driver thread is not held 5 ms per
        # switch by the busy ones (a Modbus transaction needs several switches).
        sys.setswitchinterval(0.0005)

    with sim_workdir() as work:
        if args.bench == "sim":
            sim, cfg = start_sim_bench(
                cfg, profile, seed=args.seed, speed=args.speed, workdir=Path(work), faults=faults
            )
            if faults is not None:
                from gyrolab.sim.bench.fault_file import plan_to_dict

                sim.provenance["fault_injection"] = plan_to_dict(faults)
        speed_note = "" if sim is None else f" ×{args.speed or 'max'}"
        show, bar = _progress(profile, speed_note)
        t0 = time.monotonic()
        live = None
        try:
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
    from gyrolab.acquisition.recover import recover_recording

    rep = recover_recording(args.broken, args.out, force=args.force)
    print(rep.summary())
    return 0
