"""The simulated bench, composed for a run: ``gyrolab acquire --bench sim``.

Starts the wire-level simulated instruments (``gyrolab.sim.bench``: the same protocols over
pseudo-terminals and TCP, one simulated clock) and hands the lab path what it needs to run
against them: the address of each role's instrument, the run clock, the driver-timeout rule
and the watchdog's silence rule. Those last three are the simulator's policy — a sped-up
clock shared with the drivers in one process — and live here, so that the lab engine
(``gyrolab.acquisition.runner``) has no simulator knobs. The two sides meet only on the
wire, which is why this package (and the tests) are the only places that import both
``acquisition`` and ``sim``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from gyrolab.acquisition.bench_config import BenchConfig, RunInfo, UnitConfig
from gyrolab.errors import GyrolabError, InputError
from gyrolab.instruments import registry
from gyrolab.profiles.profile import Profile

# The simulated bench answers in milliseconds (measured on a 2-core machine with both
# cores busy with other work, at 200x: Modbus transactions max 35 ms, 34401A readings max
# 74 ms wall), so its drivers' timeouts may go lower than the configured ones. The floor is
# still wall time, and at speed X it costs X times as many simulated seconds per timeout:
# 2.5 s at 10x, where a 0.5 s floor cost 5 s, and an exception reply (shorter than the
# reply minimalmodbus waits for) costs a full timeout too. A burst of Modbus errors thus
# stays well inside the 60 s communication timeout.
SIM_TIMEOUT_FLOOR_S = 0.25

# Simulated-bench speed while the drivers connect (see start_sim_bench).
CONNECT_SPEED = 10.0

# Lost communication with a simulated instrument (and a hold that outlasts its limit) also
# needs this much wall time of silence (see SimSilence); a real bench runs in real time and
# needs none. It is longer than the hold's floor below for the reason comm_timeout_s is
# longer than hold_after_s on a lab bench: a silence is held (the milder answer) before it
# is given up, and a stalled unit holds the fleet before it is dropped.
SIM_COMM_MIN_WALL_S = 3.0

# A simulated bench in its own process: how long a unit's ADC waits for its reader to
# drain the port before frames are lost (wall s; see start_sim_bench).
SIM_ADC_BACKPRESSURE_S = 1.0

# A hold (a suspender: a stream or the temperature silent) on a simulated bench also needs
# this much wall time of silence (SimSilence): a hiccup of the run engine's process (a GC,
# a burst of other work) is hundreds of simulated seconds at 300x and must not hold the
# run as a stalled instrument would. Shorter than the loss floor above (see there).
SIM_HOLD_MIN_WALL_S = 1.0

# Timeouts of a free-running simulated bench are scaled as if it ran this much faster
# than real time (it is throttled by the ADC reader, ~ a few hundred times real time).
SIM_FAST_SCALE = 200.0


class SimRunClock:
    """The simulated bench's clock as the run engine's Clock (sleep in simulated seconds)."""

    def __init__(self, clock: Any) -> None:
        self.c = clock

    def now(self) -> float:
        return float(self.c.now())

    def sleep(self, dt: float) -> None:
        if dt > 0:
            # Bounded wall wait so that a stopped clock cannot hang a thread.
            self.c.sleep(dt, 1.0)


class SimSilence:
    """The watchdog's rule on a simulated bench (a ``SilencePolicy``,
    gyrolab/acquisition/watchdog.py): silent longer than ``comm_timeout_s`` simulated
    seconds AND ``min_wall_s`` wall seconds.

    The bench shares this process with the drivers: a hiccup of a few hundred ms wall (a
    GC, an import, a long physics step) is many simulated seconds at 200x, and must not pass
    for a lost instrument."""

    def __init__(
        self, min_wall_s: float = SIM_COMM_MIN_WALL_S, heard: dict[str, float] | None = None
    ) -> None:
        self.min_wall_s = min_wall_s
        self._heard: dict[str, float] = {} if heard is None else heard

    def sharing(self, min_wall_s: float) -> SimSilence:
        """The same rule with another wall floor, on this one's record of when each source
        was last heard: the watchdog tells only its own policy, so a hold rule that kept a
        record of its own would never hear anyone and its floor would always be passed."""
        return SimSilence(min_wall_s, self._heard)

    def heard(self, source: str) -> None:
        self._heard[source] = time.monotonic()

    def lost(self, source: str, silent_s: float, timeout_s: float) -> bool:
        wall = time.monotonic() - self._heard.get(source, -float("inf"))
        return silent_s > timeout_s and wall >= self.min_wall_s


def scaled_timeouts(speed: float | None) -> Callable[[float], float]:
    """The drivers' timeout rule at ``speed`` (None: free-running): a bench X times faster
    than real time answers X times sooner and a silent one must be noticed X times sooner,
    but never below ``SIM_TIMEOUT_FLOOR_S`` wall seconds (scheduling jitter); in real time
    the configured timeouts are used as they are."""
    scale = speed if speed is not None else SIM_FAST_SCALE

    def timeout(t: float) -> float:
        if scale <= 1.0:
            return t
        return max(SIM_TIMEOUT_FLOOR_S, t / scale)

    return timeout


@dataclass
class SimHandle:
    """A running simulated bench, as the lab path sees it.

    ``addresses``: the address of each role's instrument (``registry`` role names);
    ``clock``/``silence``/``timeout``: the run clock, the watchdog's silence rule and the
    drivers' timeout rule; ``metadata``: recording metadata records to add (name → dict);
    ``hold_silence``: when a silence holds the run (a suspender): by default
    ``SIM_HOLD_MIN_WALL_S`` on the watchdog rule's record (:meth:`SimSilence.sharing`)."""

    addresses: dict[str, str]
    clock: SimRunClock
    silence: SimSilence
    timeout: Callable[[float], float]
    speed: float | None
    bench: Any
    stop: Callable[[], None]
    metadata: dict[str, dict[str, Any]] = field(default_factory=dict)
    hold_silence: SimSilence | None = None

    def __post_init__(self) -> None:
        if self.hold_silence is None:
            self.hold_silence = self.silence.sharing(SIM_HOLD_MIN_WALL_S)

    @property
    def provenance(self) -> dict[str, Any]:
        """The ``sim_provenance`` record (model, seed; fault plan when injected)."""
        return self.metadata.setdefault("sim_provenance", {})

    def go(self) -> None:
        """Connected: from now on run at the asked speed."""
        self.bench.clock.speed = self.speed


def sim_bench_config(seed: int, units: int = 0, internal: tuple[int, ...] = ()) -> BenchConfig:
    """The bench file ``--bench sim`` stands for: defaults, a simulated operator and unit;
    with ``units`` (``--units N``), N units of the seeded family
    (:func:`gyrolab.sim.family.unit_family`, serials ``SIM<seed>-01`` …) on one scanner,
    unit k's PT100 on channel 101 + k (a 34901A holds ten). ``internal``
    (``--internal-temperature``): the units (1-based) read by their internal sensor
    instead (``[[unit]] temperature = "internal"``; no scanner when that is every unit)."""
    from gyrolab.sim.simulate import SIM_UNIT_MODEL, SIM_UNIT_SERIAL

    cfg = BenchConfig(
        name="sim",
        # The simulated F4's limit controller is wired to its digital input 1 (as ESPEC
        # wires an F4 chamber's), so the chamber_alarm fault reaches the driver.
        chamber=replace(registry.default_config("chamber"), alarm_input=1),
        run=RunInfo(
            operator="simulated",
            # the nominal unit, as `gyrolab simulate` names it (its runs of any seed are
            # one unit's: a model of one applied to another is not another unit's)
            unit_serial=SIM_UNIT_SERIAL if not units else "",
            unit_model=SIM_UNIT_MODEL,
            profile="paper",
            notes="gyrolab acquire --bench sim" + (f" --units {units}" if units else ""),
        ),
        source="sim",
    )
    if not units:
        return cfg
    from gyrolab.sim.family import unit_serial

    if not 1 <= units <= 10:
        raise InputError("--units", f"the simulated scanner reads 1 to 10 units, not {units}")
    bad = sorted(set(internal) - set(range(1, units + 1)))
    if bad:
        raise InputError("--internal-temperature", f"no unit {bad[0]} among units 1..{units}")
    unit_cfgs = tuple(
        UnitConfig(
            unit_serial(seed, k),
            replace(cfg.rate_stream, internal_temperature=True),
            None,
            "internal",
        )
        if k + 1 in internal
        else UnitConfig(unit_serial(seed, k), cfg.rate_stream, 101 + k)
        for k in range(units)
    )
    channels = tuple(u.temperature_channel for u in unit_cfgs if not u.internal)
    if not channels:  # every unit on its internal sensor: no scanner
        return replace(cfg, units=unit_cfgs)
    scanner = registry.default_config("multi_thermometer")
    return replace(cfg, units=unit_cfgs, scanner=replace(scanner, channels=channels))


def sim_drivers(cfg: BenchConfig, names: list[str] | tuple[str, ...]) -> BenchConfig:
    """``acquire --bench sim --driver NAME …``: the simulated bench with these drivers (each
    name picks its role; the driver's default settings)."""
    for name in names:
        spec = next((s for s in registry.drivers() if s.name == name), None)
        if spec is None:
            known = ", ".join(s.name for s in registry.drivers())
            raise GyrolabError(f"--driver {name}: no such driver (registered: {known})")
        if spec.role == "multi_thermometer":
            if cfg.scanner is None:
                raise GyrolabError(f"--driver {name}: a scanner is for --units only")
            cfg = replace(cfg, scanner=replace(spec.config(), channels=cfg.scanner.channels))
            continue
        cfg = replace(cfg, **{spec.role: spec.config()})  # each role's field is named for it
    return cfg


def sim_tick_s(speed: float | None) -> float:
    """Simulated seconds per bench tick: 0.1 s in real time (a smooth stream), up to 1 s
    when fast (about 100-300 ticks per wall second: each tick wakes every waiting thread,
    and fewer wake-ups leave the GIL to the drivers)."""
    if speed is None:
        return 1.0
    return float(min(1.0, max(0.1, speed / 100.0)))


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
    own_process: bool = False,
) -> tuple[SimHandle, BenchConfig]:
    """Start the wire-level simulated bench; returns it and the bench config to use.

    The config's ADC calibration is the simulated gyro's (what a lab takes from the
    unit's calibration sheet); the multimeter is reached over its simulated RS-232 port,
    the same path as ``examples/lab.toml``. ``axis_models`` (0–2 SimModels) make a 2- or
    3-axis unit exactly as ``gyrolab simulate --axis-model`` does (one ADC, axes interleaved).
    ``faults`` (a FaultPlan) is injected and recorded in the provenance. A multi-unit config
    (``cfg.units``, :func:`sim_bench_config` ``units``) gets one physics per unit of the
    seeded family drawn around ``model`` (as ``gyrolab simulate --units``), each unit's ADC
    on its own pty with its own calibration, and the simulated scanner. ``own_process``:
    the bench runs in a child process (gyrolab/sim/bench/process.py: what ``acquire``
    does, so that the instruments and the run engine each have a core; ``workdir``
    needed); else in this one (``SimHandle.bench`` is then the ``SimBench``, for tests).
    """
    from gyrolab.sim.bench.fault_file import plan_to_dict
    from gyrolab.sim.bench.process import BenchProcess, BenchRecipe, describe, device_axes
    from gyrolab.sim.model import nominal_model
    from gyrolab.sim.simulate import axis_physics, provenance

    specs = {
        "chamber": registry.get(cfg.chamber.driver, "chamber"),
        **(
            {"multi_thermometer": registry.get(cfg.scanner.driver, "multi_thermometer")}
            if cfg.scanner is not None
            else {}
            if cfg.units
            else {"thermometer": registry.get(cfg.thermometer.driver, "thermometer")}
        ),
    }
    for role, spec in specs.items():
        if not spec.sim_backend:
            raise GyrolabError(f"{role} driver {spec.name!r} has no simulated back end")
    rate_spec = registry.get(cfg.rate_stream.driver, "rate_stream")
    device = _sim_device(cfg, rate_spec, axis_models)
    if cfg.units and axis_models:
        raise InputError("--axis-model", "multi-axis units are single-unit only (not --units)")
    model = model or nominal_model()
    if axis_models:
        try:  # checked here: the bench may be built in another process
            axis_physics(
                model, list(axis_models), cfg.rate_stream.sample_rate_hz, seed, profile.ambient_c
            )
        except ValueError as e:
            raise InputError("--axis-model", str(e)) from None
    family = _sim_family(cfg, seed, model)
    dmm_spec = specs.get("thermometer")
    recipe = BenchRecipe(
        settings=dict(
            dmm_model=dmm_spec.sim_backend if dmm_spec is not None else "34401A",
            chamber_model=specs["chamber"].sim_backend,
            oven_control_event=getattr(cfg.chamber, "control_event", 0) or None,
            oven_alarm_input=getattr(cfg.chamber, "alarm_input", 0) or None,
            unit_internal_temperature=[u.internal for u in cfg.units] if cfg.units else None,
            samples_per_frame=getattr(cfg.rate_stream, "samples_per_frame", 1),  # a VN-100: none
            workdir=workdir,
            faults=faults,
            keep_truth=keep_truth,
            tcp=dmm_spec is not None and dmm_spec.sim_address == "dmm_tcp_resource",
            tick_s=sim_tick_s(speed),
            # In a process of its own the bench keeps producing while the run engine's
            # process waits for a core: a unit's ADC waits up to a wall second for its
            # reader to drain the port (the clock slips) before it overruns, as one
            # process, starved whole, never did (docs/performance.md).
            adc_write_timeout_s=SIM_ADC_BACKPRESSURE_S if own_process else None,
            # Slow while the drivers connect (imports, port set-up: wall seconds that would
            # be hundreds of simulated seconds at full speed), yet one tick per 0.1 s wall
            # so that the change to ``speed`` (SimHandle.go) takes effect at once.
            speed=min(speed or CONNECT_SPEED, CONNECT_SPEED),
        ),
        rate_hz=cfg.rate_stream.sample_rate_hz,
        seed=seed,
        ambient_c=profile.ambient_c,
        model=model,
        axis_models=list(axis_models),
        units=[(u.model, u.seed) for u in family] if family else None,
        device=device,
    )
    bench: Any
    if own_process:
        if workdir is None:
            raise ValueError("own_process needs the bench's workdir")
        bench = BenchProcess(recipe, Path(workdir))
        info = bench.info
    else:
        try:
            bench = recipe.build()
        except ValueError as e:
            raise InputError("--axis-model", str(e)) from None
        bench.start()
        info = describe(bench)

    def calibrated(a: Any, sheet: dict[str, Any]) -> Any:  # the unit's ADC calibration sheet
        return replace(a, **sheet)

    axes = 1 + len(axis_models)
    if device is None:  # a device (VN-100) reports in its own units
        stream = replace(calibrated(cfg.rate_stream, info["adc"]), axes=axes)
        cfg = replace(cfg, rate_stream=stream)
    if cfg.units:
        cfg = replace(
            cfg,
            units=tuple(
                replace(
                    u,
                    rate_stream=_with_die_sensor(
                        calibrated(u.rate_stream, d["adc"]), d, u.internal
                    ),
                )
                for u, d in zip(cfg.units, info["units"], strict=True)
            ),
        )
    where = info["resources"]
    metadata: dict[str, dict[str, Any]] = {
        "sim_provenance": (
            {
                "device": rate_spec.sim_backend,
                "axes": [provenance(m, p_seed) for m, p_seed in device_axes(device, seed)],
            }
            if device is not None
            else provenance(model, seed)
            if not family  # a family: keyed by serial, as simulate --units writes it
            else {
                u.serial: {**provenance(u.model, u.seed), "family_seed": int(seed)} for u in family
            }
        )
    }
    if faults is not None:
        metadata["sim_provenance"]["fault_injection"] = plan_to_dict(faults)
    if axis_models:  # as simulate's sim_provenance_axes
        metadata["sim_provenance_axes"] = {
            "axes": 1 + len(axis_models),
            "models_toml": [m.to_toml() for m in axis_models],
        }
    handle = SimHandle(
        addresses={role: where[spec.sim_address] for role, spec in specs.items()}
        | (
            {f"unit/{u.serial}": p for u, p in zip(cfg.units, where["unit_adc_ports"], strict=True)}
            if cfg.units
            else {"rate_stream": where[rate_spec.sim_address]}
        ),
        clock=SimRunClock(bench.clock),
        silence=SimSilence(),
        timeout=scaled_timeouts(speed),
        speed=speed,
        bench=bench,
        stop=bench.stop,
        metadata=metadata,
    )
    return handle, cfg


def _sim_device(cfg: BenchConfig, spec: registry.DriverSpec, axis_models: Any) -> str | None:
    """The simulated device a rate-stream driver speaks to, when it is not the gyro ADC
    (``BenchRecipe.device``): ``"VN100"`` → a simulated VN-100
    (:mod:`gyrolab.sim.bench.vectornav`); None for the ADC."""
    if spec.sim_backend == "ADC":
        return None
    if spec.sim_backend != "VN100":
        raise GyrolabError(f"rate_stream driver {spec.name!r}: no simulated back end here")
    if cfg.units or axis_models:
        raise InputError("--driver", f"{spec.name}: one simulated unit (no --units, --axis-model)")
    return spec.sim_backend


def _with_die_sensor(stream: Any, unit: dict[str, Any], internal: bool) -> Any:
    """A unit's stream config with its simulated internal sensor's register scale (the
    part's data sheet, as a lab takes it), for a unit read by that sensor."""
    if not internal:
        return stream
    return replace(
        stream, temperature_c_per_lsb=unit["c_per_lsb"], temperature_zero_c=unit["zero_c"]
    )


def _sim_family(cfg: BenchConfig, seed: int, model: Any) -> list[Any]:
    """A multi-unit config's family (as ``gyrolab simulate --units``); ``[]`` for a single
    unit."""
    if not cfg.units:
        return []
    from gyrolab.sim.family import unit_family

    family = unit_family(model, len(cfg.units), seed)
    if [u.serial for u in family] != [u.serial for u in cfg.units]:
        raise GyrolabError("the simulated units' serials are SIM<seed>-01 …")
    return family
