"""The typed options of every ``gyrolab`` command (the contract in docs/cli.md).

``gyrolab.cli`` parses the command line into one of these dataclasses and hands it to the
command's call in :mod:`gyrolab.app`; nothing below ``cli.py`` sees an argparse namespace.
A library caller builds the same dataclass.

Each options object checks itself when it is made: the rules that need no more than the
arguments and the file system (an input that does not exist, an option that one choice
of another requires, a count out of range) raise :class:`~gyrolab.errors.InputError`
there — one line, exit 2 — so a typing mistake is answered before any numerical library
is imported. This module therefore imports nothing heavy (standard library only).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any

from gyrolab.errors import GyrolabError, InputError
from gyrolab.export.commands import check_request
from gyrolab.sampling import DEFAULT_RATE_HZ

PathArg = str | os.PathLike[str]


def need_file(path: PathArg | None) -> None:
    """``path`` (when given) names an existing file or directory, else ``file not found``."""
    if path is not None and not os.path.exists(path):
        raise InputError(path, "file not found")


PRIOR_QUERY = "part-number:"


def need_prior(spec: str | None) -> None:
    """``--prior``: a directory (of model directories) or ``part-number:PN``."""
    if spec is None or spec.startswith(PRIOR_QUERY) and spec[len(PRIOR_QUERY) :]:
        return
    need_model_dir(spec)


def need_model_dir(path: PathArg | None) -> None:
    """``path`` (when given) is an existing directory (a model directory, or one of them)."""
    if path is None:
        return
    if not os.path.exists(path):
        raise InputError(path, "model directory not found")
    if not os.path.isdir(path):
        raise InputError(path, "not a directory (a model directory is expected)")


@dataclass(frozen=True)
class LogOptions:
    """How to read a user's log (ROS 2 MCAP, PX4 ULog, ArduPilot DataFlash; docs/export.md):
    ``--temperature-topic``, ``--imu-topic``, ``--log-instance``."""

    temperature_topic: str | None = None
    imu_topic: str | None = None
    instance: int = 0

    def read_log_kwargs(self) -> dict[str, Any]:
        """The keywords of :func:`gyrolab.logs.read_log`."""
        return {
            "temperature_topic": self.temperature_topic,
            "imu_topic": self.imu_topic,
            "instance": int(self.instance),
        }


@dataclass(frozen=True)
class SimulateOptions:
    """``gyrolab simulate`` (docs/sim-model.md): ``profile`` paper | short | FILE.toml."""

    out: PathArg
    profile: str = "paper"
    model: str | None = None
    axis_models: tuple[str, ...] = ()
    rate_hz: float = DEFAULT_RATE_HZ
    seed: int = 0
    units: int = 1
    effects: tuple[str, ...] = ()
    force: bool = False

    def __post_init__(self) -> None:
        for p in (self.model, *self.axis_models):
            need_file(p)
        if len(self.axis_models) > 2:
            raise InputError("--axis-model", "a unit has at most 3 axes (give it at most twice)")
        # The profile and the effects are read here, before the simulator and its
        # recording stack are imported: a mistyped name or a bad file is answered in
        # ~0.2 s (the profile needs numpy only), ~0.6 s with --effect (the vocabulary's
        # module brings numba), not after the ~2 s of imports a run needs (issue 27).
        from gyrolab.profiles.profile import load_profile

        load_profile(self.profile)
        if self.effects:
            check_effects(self.effects)


def check_effects(effects: tuple[str, ...]) -> None:
    """``--effect NAME[:k=v,...]``: known names, known parameters, values in range — as
    :func:`gyrolab.sim.model.apply_effect_args` applies them to the nominal model."""
    from gyrolab.sim.model import apply_effect_args, nominal_model

    try:
        apply_effect_args(nominal_model(), list(effects))
    except (ValueError, TypeError) as e:
        raise InputError("--effect", str(e)) from None


@dataclass(frozen=True)
class AcquireOptions:
    """What ``gyrolab acquire`` is asked to do (docs/cli.md).

    ``bench``: ``"sim"`` or a BENCH.toml; ``profile``: paper | short | FILE.toml (None: the
    bench's); ``speed``/``seed``/``drivers``/``faults``/``axis_models``: the simulated bench
    only; ``live_port``: serve the run to Foxglove (0: any free port)."""

    bench: str | None = None
    out: PathArg | None = None
    profile: str | None = None
    speed: float | None = None
    seed: int = 0
    drivers: tuple[str, ...] = ()
    faults: str | None = None
    axis_models: tuple[str, ...] = ()
    force: bool = False
    live_port: int | None = None
    live_host: str = "127.0.0.1"
    units: int = 0  # the simulated bench only: N units of a seeded family (docs/fleet.md)
    # --units only: the units (1-based) read by their internal temperature sensor
    internal_temperature: tuple[int, ...] = ()
    # --resume RUN.mcap: continue that interrupted run (gyrolab/app/resume.py, docs/
    # reliability.md "Resume"); ``bench`` then defaults to the simulated bench that ran it,
    # ``out`` to ``<run>.seg<N>.mcap`` beside it
    resume: PathArg | None = None

    def __post_init__(self) -> None:
        if self.resume is None and (not self.bench or self.out is None):
            raise InputError(None, "acquire needs --bench and --out (or --resume RUN.mcap)")
        need_file(self.resume)
        sim = self.bench == "sim"
        if self.speed is not None and not (self.speed > 0 and math.isfinite(self.speed)):
            raise GyrolabError(f"--speed must be a positive number, not {self.speed}")
        only_sim = {  # option: (given, why a bench file does not take it)
            "--driver": (self.drivers, "a bench file names its drivers"),
            "--axis-model": (self.axis_models, "a bench file sets [rate_stream] axes"),
            "--units": (self.units, "a bench file lists [[unit]]s"),
            "--speed": (self.speed is not None, "real hardware runs in real time"),
            "--faults": (self.faults is not None, "it drives the simulator"),
        }
        for name, (given, why) in only_sim.items():
            # --resume without --bench: the run names its bench (the continuation's
            # options, built from it, are checked again)
            if given and not sim and self.bench:
                raise GyrolabError(f"{name} applies to --bench sim only ({why})")
        if self.internal_temperature and not self.units:
            raise GyrolabError(
                "--internal-temperature applies to --bench sim --units N only "
                '(a bench file says [[unit]] temperature = "internal")'
            )
        if len(self.axis_models) > 2:
            raise InputError("--axis-model", "a unit has at most 3 axes (give it at most twice)")
        for p in (None if sim else self.bench, self.faults, *self.axis_models):
            need_file(p)


@dataclass(frozen=True)
class RecoverOptions:
    """``gyrolab recover BROKEN.mcap --out FIXED.mcap`` (docs/reliability.md)."""

    broken: PathArg
    out: PathArg
    force: bool = False

    def __post_init__(self) -> None:
        need_file(self.broken)


@dataclass(frozen=True)
class CompensateOptions:
    """``gyrolab compensate`` (docs/compensation.md). ``run_label``/``validate_label``: how
    the outputs name the runs (default: the paths as given; the demo passes paths relative
    to its output directory); ``workers``: parallel fits of a multi-unit run."""

    run: PathArg
    out: PathArg
    validate: PathArg | None = None
    config: PathArg | None = None
    seed: int | None = None
    unit: str | None = None
    workers: int | None = None
    log: LogOptions = field(default_factory=LogOptions)
    force: bool = False
    run_label: str = ""
    validate_label: str = ""
    prior: str | None = None  # DIR of model directories, or part-number:PN
    also: tuple[PathArg, ...] = ()  # further calibration runs, each its own power-on

    def __post_init__(self) -> None:
        for p in (self.run, self.validate, self.config, *self.also):
            need_file(p)
        need_prior(self.prior)


@dataclass(frozen=True)
class ApplyOptions:
    """``gyrolab apply MODEL_DIR RUN.mcap --out COMPENSATED.mcap [--unit SERIAL]``
    (docs/compensation.md; a multi-unit run: docs/fleet.md)."""

    model: PathArg
    run: PathArg
    out: PathArg
    force: bool = False
    unit: str | None = None

    def __post_init__(self) -> None:
        need_model_dir(self.model)
        need_file(self.run)


@dataclass(frozen=True)
class ReportOptions:
    """``gyrolab report`` (docs/report.md). ``unit_serial``/``operator`` fill the sign-off
    block instead of the recording's; ``unit``: the unit of a multi-unit run."""

    run: PathArg
    out: PathArg
    model: PathArg | None = None
    spec: PathArg | None = None
    operator: str | None = None
    unit_serial: str | None = None
    unit: str | None = None
    log: LogOptions = field(default_factory=LogOptions)
    force: bool = False

    def __post_init__(self) -> None:
        need_file(self.run)
        need_model_dir(self.model)
        need_file(self.spec)


@dataclass(frozen=True)
class DiscrepancyOptions:
    """``gyrolab discrepancy RUN.mcap [--model SIM_MODEL.toml] --out DIR`` (docs/discrepancy.md)."""

    run: PathArg
    out: PathArg
    model: PathArg | None = None
    unit: str | None = None
    force: bool = False

    def __post_init__(self) -> None:
        need_file(self.run)
        need_file(self.model)


@dataclass(frozen=True)
class DemoOptions:
    """``gyrolab demo --out DIR`` (docs/report.md); ``fc`` (``px4`` | ``ardupilot``): a
    simulated flight controller through calibration, compensation, export, flash and an
    on-device verification run instead (docs/instruments.md)."""

    out: PathArg
    profile: str = "paper"
    seed: int = 1
    force: bool = False
    catalogue: str | None = None  # where it registers (docs/catalogue.md, "The demo")
    fc: str | None = None

    def __post_init__(self) -> None:
        if self.fc not in (None, "px4", "ardupilot"):
            raise InputError("--fc", f"px4 or ardupilot, not {self.fc!r}")


@dataclass(frozen=True)
class ConvertOptions:
    """``gyrolab convert RUN --to FORMAT --out FILE`` (docs/convert.md): a recording, or a
    user's log (``log``: which IMU or topics)."""

    run: PathArg
    to: str
    out: PathArg
    unit: str | None = None
    log: LogOptions = field(default_factory=LogOptions)  # a user's log (docs/convert.md)
    force: bool = False

    def __post_init__(self) -> None:
        need_file(self.run)


@dataclass(frozen=True)
class ExportOptions:
    """``gyrolab export MODEL_DIR --format FORMAT --out FILE`` (docs/export.md).

    Conditionally required (:data:`gyrolab.export.commands.REQUIRED_FOR`): ``device_id``
    for ``px4`` (PX4's ``TC_Gi_ID``), ``run`` for ``kalibr`` (the run whose noise it
    describes)."""

    model: PathArg
    format: str
    out: PathArg
    kind: str = "chosen"
    instance: int = 0
    device_id: int | None = None
    run: PathArg | None = None
    rostopic: str = "/imu0"
    log: LogOptions = field(default_factory=LogOptions)
    force: bool = False

    def __post_init__(self) -> None:
        check_request(self.format, device_id=self.device_id, run=self.run, instance=self.instance)
        need_model_dir(self.model)
        need_file(self.run)


@dataclass(frozen=True)
class BatchCommandOptions:
    """``gyrolab batch TASK RUNS... --out DIR`` (docs/fleet.md): ``runs`` are recordings
    or glob patterns; ``scheduler`` a Dask scheduler's address, else a local cluster of
    ``workers``; ``seed``/``config`` for compensate, ``models`` for report, ``sim_model``
    for discrepancy."""

    task: str
    runs: tuple[str, ...]
    out: PathArg
    scheduler: str | None = None
    workers: int | None = None
    threads: int = 1
    seed: int | None = None
    config: PathArg | None = None
    models: PathArg | None = None
    sim_model: PathArg | None = None
    force: bool = False

    def __post_init__(self) -> None:
        if self.scheduler and self.workers:
            raise InputError(
                "gyrolab batch",
                "--workers sizes the local cluster; with --scheduler the cluster's own "
                "workers run the items",
            )
        for name, n in (("--workers", self.workers), ("--threads", self.threads)):
            if n is not None and n < 1:
                raise InputError("gyrolab batch", f"{name} must be at least 1")
        for name, value, task in (
            ("--config", self.config, "compensate"),
            ("--models", self.models, "report"),
            ("--sim-model", self.sim_model, "discrepancy"),
        ):
            if value and self.task != task:
                raise InputError("gyrolab batch", f"{name} is for `batch {task}`")
            need_file(value)


@dataclass(frozen=True)
class FleetOptions:
    """``gyrolab fleet MODEL_DIR... --out REPORT_DIR [--spec SPEC.toml]`` (docs/fleet.md);
    with ``part_number``/``since`` the units (each one's latest model) come from the
    ``catalogue`` as well (docs/catalogue.md)."""

    models: tuple[PathArg, ...]
    out: PathArg
    spec: PathArg | None = None
    force: bool = False
    part_number: str | None = None
    since: str | None = None
    catalogue: str | None = None

    def __post_init__(self) -> None:
        if not self.models and self.part_number is None and self.since is None:
            raise InputError(
                "gyrolab fleet", "give MODEL_DIR... or --part-number/--since (the catalogue)"
            )
        for m in self.models:
            need_model_dir(m)
        need_file(self.spec)


@dataclass(frozen=True)
class RunsOptions:
    """``gyrolab runs list|show|trace|rebuild`` (docs/catalogue.md): ``action``; ``serial``
    for show and trace; ``unit``/``part_number``/``since`` filter list; ``dirs`` for
    rebuild; ``catalogue``: a URL or SQLite file (default: $GYROLAB_CATALOGUE, else the
    default file)."""

    action: str
    serial: str | None = None
    unit: str | None = None
    part_number: str | None = None
    since: str | None = None
    dirs: tuple[PathArg, ...] = ()
    json: bool = False
    catalogue: str | None = None


@dataclass(frozen=True)
class ProfileDesignOptions:
    """``gyrolab profile design`` (docs/profiles.md): the profile of ``hours`` that shows
    the drift model best, given the chamber's limits (``sim_model``'s ``[thermal]``) and
    optionally a fleet prior."""

    hours: float
    out: PathArg
    action: str = "design"
    prior: str | None = None
    sim_model: str | None = None
    setpoint_min: float = -40.0
    setpoint_max: float = 60.0
    ambient: float = 25.0
    name: str | None = None
    force: bool = False

    def __post_init__(self) -> None:
        need_file(self.sim_model)
        need_prior(self.prior)
        if not 0.9 <= self.hours <= 24.0:
            raise InputError("--hours", f"{self.hours:g}: a designed profile is 0.9 to 24 h")
        if not self.setpoint_min < self.ambient < self.setpoint_max:
            raise InputError(
                "--setpoint-min/--setpoint-max",
                "the ambient must lie between the lowest and the highest setpoint",
            )
