"""The ``gyrolab`` command line (the contract in docs/cli.md).

Thin: it parses the arguments into the command's typed options
(:mod:`gyrolab.app.options`, which check themselves: inputs exist, options that one choice
requires are given) and hands them to the command's call in :mod:`gyrolab.app`
(``HANDLERS``: ``module:function(options) -> int``). That module is imported only after the
options are made, so ``--help`` and a typing mistake are answered before any numerical
library is imported, and a broken layer cannot break the rest.

After the command, what it wrote is registered in the catalogue
(:func:`gyrolab.app.register.register_command`, which never changes the exit code).

Errors: a :class:`~gyrolab.errors.GyrolabError` becomes one line on stderr and exit 2;
SIGINT, SIGTERM and SIGHUP exit 130, through the same clean-up. Anything else is a bug and
shows its traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import importlib
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence

from gyrolab import __version__
from gyrolab.app import options as o
from gyrolab.errors import GyrolabError
from gyrolab.sampling import DEFAULT_RATE_HZ

HANDLERS: dict[str, str] = {
    "simulate": "gyrolab.app.simulate:simulate",
    "acquire": "gyrolab.app.acquire:acquire_command",
    "compensate": "gyrolab.app.compensate:compensate",
    "apply": "gyrolab.app.compensate:apply",
    "report": "gyrolab.app.report:report",
    "discrepancy": "gyrolab.app.simulate:discrepancy",
    "recover": "gyrolab.app.acquire:recover_command",
    "demo": "gyrolab.app.demo:demo",
    "convert": "gyrolab.app.export:convert",
    "export": "gyrolab.app.export:export",
    "batch": "gyrolab.app.batch:batch",
    "fleet": "gyrolab.app.report:fleet",
    "runs": "gyrolab.app.runs:runs",
    "profile": "gyrolab.app.profile:profile",
}


class _Parser(argparse.ArgumentParser):
    """argparse whose errors are one line and exit 2 (argparse prints usage too)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise GyrolabError(f"{self.prog}: {message}")


def _effect_spec(text: str) -> str:
    if not text or text.startswith(":"):
        raise argparse.ArgumentTypeError(f"bad --effect {text!r} (NAME[:k=v,...])")
    return text


def _unit_numbers(text: str) -> str:
    """``--internal-temperature``: 'all' or 1-based unit numbers, comma separated."""
    parts = text.split(",")
    if text != "all" and not all(p.strip().isdigit() and int(p) >= 1 for p in parts):
        raise argparse.ArgumentTypeError(f"bad --internal-temperature {text!r} (K[,K...]|all)")
    return text


def _int_in(lo: int, hi: int | None = None, span: str = "") -> Callable[[str], int]:
    """An argparse type: an integer ≥ ``lo`` (and ≤ ``hi``; ``span`` says the range)."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, not {text!r}") from None
        if v < lo or (hi is not None and v > hi):
            raise argparse.ArgumentTypeError(
                f"must be {f'in {span}' if span else f'at least {lo}'}, not {v}"
            )
        return v

    return parse


#: A count (--units, --workers, --threads): ≥ 1. Upper bounds belong to the layer that
#: knows them (``gyrolab.sim.commands.MAX_UNITS``, the simulated scanner's 10 units,
#: ``gyrolab.batch.MAX_WORKERS``).
_positive_int = _int_in(1)
#: A random seed: numpy's generators take none below 0.
_seed = _int_in(0, 2**63 - 1, "[0, 2**63)")


def _positive_float(text: str) -> float:
    """A rate or a speed: a finite number > 0."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, not {text!r}") from None
    if not (v > 0 and v != float("inf")):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, not {text}")
    return v


UNIT_HELP = "the unit of a multi-unit run (required when the run holds several)"
# The built-in profiles (gyrolab/profiles/profile.py BUILTIN, docs/profiles.md); not
# imported from there so that --help needs no library import.
_PROFILES = "paper | short | quick | paper_ramps | cold_start | FILE.toml"


def _log_options(sp: argparse.ArgumentParser) -> None:
    """Options for runs that are users' logs (gyrolab/logs, docs/export.md)."""
    g = sp.add_argument_group("users' logs (ROS 2 MCAP, PX4 ULog, ArduPilot DataFlash)")
    g.add_argument(
        "--temperature-topic", metavar="TOPIC", help="ROS 2: the sensor_msgs/msg/Temperature topic"
    )
    g.add_argument("--imu-topic", metavar="TOPIC", help="ROS 2: the sensor_msgs/msg/Imu topic")
    g.add_argument(
        "--log-instance", type=int, default=0, help="ULog/DataFlash: gyro (IMU) instance (0)"
    )


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="gyrolab", description=__doc__.splitlines()[0])
    p.add_argument("--version", action="version", version=f"gyrolab {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    def cmd(name: str, help_: str) -> argparse.ArgumentParser:
        sp = sub.add_parser(name, help=help_, description=help_)
        return sp

    s = cmd("simulate", "simulate an oven run of the gyro and record it to MCAP")
    s.add_argument("--out", required=True, help="output RUN.mcap")
    s.add_argument("--profile", default="paper", help=f"{_PROFILES} (default paper)")
    s.add_argument("--model", help="SIM_MODEL.toml (default: the nominal model)")
    s.add_argument(
        "--axis-model",
        dest="axis_models",
        action="append",
        default=[],
        metavar="SIM_MODEL.toml",
        help="model of the next axis (y, then z): makes a 2- or 3-axis unit (repeatable)",
    )
    s.add_argument(
        "--rate",
        dest="rate_hz",
        type=_positive_float,
        default=DEFAULT_RATE_HZ,
        help=f"ADC sample rate, Hz (default {DEFAULT_RATE_HZ:g})",
    )
    s.add_argument("--seed", type=_seed, default=0, help="random seed (default 0)")
    s.add_argument(
        "--units",
        type=_positive_int,
        default=1,
        help="units in the chamber, dispersed as a unit family (default 1: single-unit layout)",
    )
    s.add_argument(
        "--effect",
        dest="effects",
        action="append",
        default=[],
        type=_effect_spec,
        metavar="NAME[:k=v,...]",
        help="add an effect to the model (repeatable)",
    )
    s.add_argument("--force", action="store_true", help="overwrite an existing output")

    a = cmd("acquire", "run an oven profile on a bench (real or simulated) and record it")
    a.add_argument("--bench", help="sim | BENCH.toml (with --resume: the run's sim by default)")
    a.add_argument(
        "--out", help="output RUN.mcap (with --resume: default <run>.seg<N>.mcap beside it)"
    )
    a.add_argument(
        "--resume",
        metavar="RUN.mcap",
        help="continue this interrupted run (its last segment, or the file a kill left) from "
        "its last completed step, in a new segment (docs/reliability.md)",
    )
    a.add_argument("--profile", default=None, help=f"{_PROFILES} (default: bench's)")
    a.add_argument(
        "--speed",
        type=_positive_float,
        default=None,
        help="simulated-bench speed-up over real time (default: as fast as it goes)",
    )
    a.add_argument("--seed", type=_seed, default=0, help="simulated bench seed (default 0)")
    a.add_argument(
        "--units",
        type=_positive_int,  # absent: 0, the single-unit layout; --units 0 is refused
        default=0,
        metavar="N",
        help="--bench sim only: N units of a seeded family in the chamber, read by a scanner "
        "(1-10; docs/fleet.md)",
    )
    a.add_argument(
        "--internal-temperature",
        type=_unit_numbers,
        default=None,
        metavar="K[,K...]|all",
        help="--bench sim --units N only: these units (1-based) are read by their internal "
        "temperature sensor instead of a PT100 on the scanner (docs/fleet.md)",
    )
    a.add_argument(
        "--driver",
        dest="drivers",
        action="append",
        default=[],
        metavar="NAME",
        help="--bench sim only: use this driver for its role (repeatable; docs/instruments.md)",
    )
    a.add_argument(
        "--faults",
        metavar="FAULTS.toml",
        help="--bench sim only: inject faults into the simulated bench (docs/instruments.md)",
    )
    a.add_argument(
        "--axis-model",
        dest="axis_models",
        action="append",
        default=[],
        metavar="SIM_MODEL.toml",
        help="--bench sim only: model of the next axis (y, then z), as simulate (repeatable)",
    )
    a.add_argument("--force", action="store_true", help="overwrite an existing output")
    a.add_argument(
        "--live",
        dest="live_port",
        type=int,
        nargs="?",
        const=8765,
        default=None,
        metavar="PORT",
        help="serve the run to Foxglove over WebSocket (default port 8765; 0: any free port)",
    )
    a.add_argument(
        "--live-host",
        default="127.0.0.1",
        metavar="ADDR",
        help="interface for --live (default 127.0.0.1; 0.0.0.0 exposes it to the network)",
    )

    c = cmd("compensate", "fit the temperature-compensation model on a calibration run")
    c.add_argument("run", metavar="RUN.mcap")
    c.add_argument("--out", required=True, help="output MODEL_DIR")
    c.add_argument("--validate", metavar="OTHER.mcap", help="held-out run for metrics")
    c.add_argument(
        "--also",
        metavar="RUN2.mcap",
        action="append",
        default=[],
        help="another calibration run of the unit from its own power-on (a cold start: "
        "profile cold_start); the causal model is fitted on both (repeatable)",
    )
    c.add_argument(
        "--seed", type=_seed, default=None, help="random seed (default: the config's, 0)"
    )
    c.add_argument(
        "--config", metavar="FILE.toml", help="model settings (keys: docs/compensation.md)"
    )
    c.add_argument(
        "--prior",
        metavar="DIR_OR_QUERY",
        help="fit with a fleet prior learned from earlier units: a directory of their model "
        "directories, or part-number:PN (the catalogue's latest model of each unit)",
    )
    _log_options(c)
    c.add_argument("--unit", metavar="SERIAL", help="one unit of a multi-unit run (default: all)")
    c.add_argument(
        "--workers", type=_positive_int, help="multi-unit run: parallel fits (default: CPUs)"
    )
    c.add_argument("--force", action="store_true", help="overwrite an existing output")

    ap = cmd("apply", "apply a fitted model to a run and write the compensated recording")
    ap.add_argument("model", metavar="MODEL_DIR")
    ap.add_argument("run", metavar="RUN.mcap")
    ap.add_argument("--out", required=True, help="output COMPENSATED.mcap")
    ap.add_argument(
        "--unit",
        metavar="SERIAL",
        help="the unit of a multi-unit run to compensate (default: every unit, by the model "
        "of each in MODEL_DIR, the DIR compensate wrote: DIR/SERIAL)",
    )
    ap.add_argument("--force", action="store_true", help="overwrite an existing output")

    r = cmd("report", "write the temperature-test report of a run")
    r.add_argument("run", metavar="RUN.mcap")
    r.add_argument("--model", metavar="MODEL_DIR", help="fitted model to show and apply")
    r.add_argument("--spec", metavar="SPEC.toml", help="spec limits: per-line pass/fail, verdict")
    r.add_argument("--operator", help="operator for the sign-off (default: the recording's)")
    r.add_argument("--unit-serial", help="unit serial (default: the recording's)")
    r.add_argument("--unit", metavar="SERIAL", help=UNIT_HELP)
    r.add_argument("--out", required=True, help="output REPORT_DIR")
    _log_options(r)
    r.add_argument("--force", action="store_true", help="overwrite an existing output")

    d = cmd("discrepancy", "find where the simulator and a recording disagree, and fix the model")
    d.add_argument("run", metavar="RUN.mcap")
    d.add_argument("--model", metavar="SIM_MODEL.toml", help="starting model (default nominal)")
    d.add_argument("--unit", metavar="SERIAL", help=UNIT_HELP)
    d.add_argument("--out", required=True, help="output DIR")
    d.add_argument("--force", action="store_true", help="overwrite an existing output")

    rc = cmd("recover", "salvage every complete record of a truncated recording")
    rc.add_argument("broken", metavar="BROKEN.mcap")
    rc.add_argument("--out", required=True, help="output FIXED.mcap")
    rc.add_argument("--force", action="store_true", help="overwrite an existing output")

    cv = cmd("convert", "export a recording or a user's log to CSV, HDF5, Parquet or NetCDF")
    cv.add_argument("run", metavar="RUN", help="gyrolab MCAP, PX4 ULog, DataFlash .bin, ROS 2 MCAP")
    cv.add_argument("--to", required=True, choices=["csv", "hdf5", "parquet", "netcdf"])
    cv.add_argument("--out", required=True, help="output FILE")
    cv.add_argument("--unit", metavar="SERIAL", help=UNIT_HELP)
    _log_options(cv)
    cv.add_argument("--force", action="store_true", help="overwrite an existing output")
    ex = cmd("export", "write a fitted model in a firmware's or another tool's format")
    ex.add_argument("model", metavar="MODEL_DIR")
    ex.add_argument("--format", required=True, choices=["px4", "ardupilot", "c", "json", "kalibr"])
    ex.add_argument("--out", required=True, help="output FILE (c: NAME.c, NAME.h beside it)")
    ex.add_argument(
        "--kind",
        default="chosen",
        choices=["chosen", "causal", "gabp", "bp", "poly", "poly3"],
        help="c/json: which fitted drift model (default chosen: causal if fitted, else gabp)",
    )
    ex.add_argument(
        "--instance", type=_int_in(0), default=0, help="px4 (0..3), ardupilot (0..2) gyro instance"
    )
    req = ex.add_argument_group("required by one format")
    req.add_argument(
        "--device-id",
        type=int,
        metavar="ID",
        help="required with --format px4: the gyro's device id (TC_Gi_ID)",
    )
    req.add_argument(
        "--run", metavar="RUN", help="required with --format kalibr: the run to analyse"
    )
    ex.add_argument("--rostopic", default="/imu0", help="kalibr: IMU topic (default /imu0)")
    _log_options(ex)
    ex.add_argument("--force", action="store_true", help="overwrite an existing output")

    dm = cmd("demo", "simulated bench -> recording -> compensation -> report, in one go")
    dm.add_argument("--out", required=True, help="output DIR")
    dm.add_argument(
        "--fc",
        choices=["px4", "ardupilot"],
        help="a simulated flight controller through the loop: calibration run, compensate, "
        "export, flash, verification run (docs/instruments.md)",
    )
    dm.add_argument("--profile", default="paper", help=_PROFILES)
    dm.add_argument("--seed", type=_seed, default=1, help="seed of the calibration run (default 1)")
    dm.add_argument(
        "--catalogue",
        metavar="URL",
        help="register the demo here (default: $GYROLAB_CATALOGUE if set, else "
        "DIR/catalogue.sqlite; docs/catalogue.md)",
    )
    dm.add_argument("--force", action="store_true", help="overwrite an existing output")

    b = cmd("batch", "run compensate, report or discrepancy on many recordings (Dask)")
    b.add_argument("task", choices=["compensate", "report", "discrepancy"])
    b.add_argument("runs", nargs="+", metavar="RUNS", help="recordings or quoted glob patterns")
    b.add_argument("--out", required=True, help="output DIR (one directory per recording)")
    b.add_argument("--scheduler", metavar="ADDRESS", help="Dask scheduler (default: local)")
    b.add_argument("--workers", type=_positive_int, help="local cluster size (default: CPUs)")
    b.add_argument("--threads", type=_positive_int, default=1, help="threads per item (default 1)")
    b.add_argument("--seed", type=_seed, help="compensate: seed (default: CONFIG.toml's, else 0)")
    b.add_argument("--config", metavar="CONFIG.toml", help="compensate: pipeline settings")
    b.add_argument("--models", metavar="MODELS_DIR", help="report: MODELS_DIR/<stem> per run")
    b.add_argument("--sim-model", metavar="SIM_MODEL.toml", help="discrepancy: start model")
    b.add_argument("--force", action="store_true", help="redo items whose outputs exist")

    f = cmd("fleet", "fleet record of many units' models: tables, distributions, outliers, yield")
    f.add_argument("models", nargs="*", metavar="MODEL_DIR", help="model dirs or dirs of them")
    f.add_argument("--out", required=True, help="output REPORT_DIR")
    f.add_argument("--spec", metavar="SPEC.toml", help="spec limits: yield against them")
    f.add_argument(
        "--part-number",
        metavar="PN",
        help="take the units of this part number from the catalogue (each one's latest model)",
    )
    f.add_argument(
        "--since",
        metavar="DATE",
        help="take the units with a run since DATE (ISO 8601, UTC) from the catalogue",
    )
    _catalogue_option(f)
    f.add_argument("--force", action="store_true", help="overwrite an existing output")

    ru = cmd("runs", "the catalogue of units, runs, models, exports and verdicts")
    rsub = ru.add_subparsers(dest="action", metavar="ACTION", parser_class=_Parser, required=True)
    rl = rsub.add_parser("list", help="the runs, newest first, with their units")
    rl.add_argument("--unit", metavar="SERIAL", help="only the runs of this unit")
    rl.add_argument("--part-number", metavar="PN", help="only runs of units of this part number")
    rl.add_argument("--since", metavar="DATE", help="only runs started since (ISO 8601, UTC)")
    for name, help_ in (
        ("show", "everything registered about one unit"),
        ("trace", "unit -> runs -> model -> exported or flashed parameters -> verdict"),
    ):
        rs = rsub.add_parser(name, help=help_)
        rs.add_argument("serial", metavar="SERIAL")
    for sp in rsub.choices.values():
        sp.add_argument("--json", action="store_true", help="print JSON")
        _catalogue_option(sp)
    rr = rsub.add_parser("rebuild", help="register every file under the directories again")
    rr.add_argument("dirs", nargs="+", metavar="DIR")
    _catalogue_option(rr)

    pr = cmd("profile", "temperature profiles: design a short calibration profile")
    psub = pr.add_subparsers(dest="action", metavar="ACTION", parser_class=_Parser, required=True)
    pd = psub.add_parser(
        "design", help="the profile of H hours that shows the drift model best (docs/profiles.md)"
    )
    pd.add_argument("--hours", type=float, required=True, help="chamber time, h")
    pd.add_argument("--out", required=True, help="output PROFILE.toml")
    pd.add_argument(
        "--prior", metavar="DIR_OR_QUERY", help="score against this fleet prior (as compensate)"
    )
    pd.add_argument(
        "--sim-model",
        metavar="SIM_MODEL.toml",
        help="the chamber's heating/cooling limits from this model's [thermal] (default: nominal)",
    )
    pd.add_argument("--setpoint-min", type=float, default=-40.0, help="lowest setpoint, °C (-40)")
    pd.add_argument("--setpoint-max", type=float, default=60.0, help="highest setpoint, °C (60)")
    pd.add_argument("--ambient", type=float, default=25.0, help="room temperature, °C (25)")
    pd.add_argument("--name", help="profile name (default design-<H>h)")
    pd.add_argument("--force", action="store_true", help="overwrite an existing output")
    return p


def _catalogue_option(sp: argparse.ArgumentParser) -> None:
    sp.add_argument(
        "--catalogue",
        metavar="URL",
        help="the catalogue: an SQLite file or a database URL (default: $GYROLAB_CATALOGUE, "
        "else ~/.local/share/gyrolab/catalogue.sqlite; docs/catalogue.md)",
    )


def _internal_units(args: argparse.Namespace) -> tuple[int, ...]:
    if args.internal_temperature == "all":
        return tuple(range(1, args.units + 1))
    return tuple(int(k) for k in (args.internal_temperature or "").split(",") if k)


OPTIONS: dict[str, type] = {
    "simulate": o.SimulateOptions,
    "acquire": o.AcquireOptions,
    "compensate": o.CompensateOptions,
    "apply": o.ApplyOptions,
    "report": o.ReportOptions,
    "discrepancy": o.DiscrepancyOptions,
    "recover": o.RecoverOptions,
    "demo": o.DemoOptions,
    "convert": o.ConvertOptions,
    "export": o.ExportOptions,
    "batch": o.BatchCommandOptions,
    "fleet": o.FleetOptions,
    "runs": o.RunsOptions,
    "profile": o.ProfileDesignOptions,
}


def options(args: argparse.Namespace) -> object:
    """The typed options of ``args.command`` (:mod:`gyrolab.app.options`), checked as they
    are made: each field from the argument of the same name (repeated ones as tuples)."""
    kw: dict[str, object] = {}
    for f in dataclasses.fields(OPTIONS[args.command]):
        if f.name == "log":
            kw["log"] = o.LogOptions(args.temperature_topic, args.imu_topic, args.log_instance)
        elif f.name == "internal_temperature":
            kw[f.name] = _internal_units(args)
        elif hasattr(args, f.name):
            v = getattr(args, f.name)
            kw[f.name] = tuple(v) if isinstance(v, list) else v
    return OPTIONS[args.command](**kw)


def _handler(command: str):  # type: ignore[no-untyped-def]
    module, func = HANDLERS[command].split(":")
    return getattr(importlib.import_module(module), func)


def _input_paths(args: argparse.Namespace) -> list[str]:
    """Every argument but ``--out`` that names an existing file or directory: the
    command's inputs, which no output may overwrite (gyrolab/outputs.py)."""
    return [
        v
        for k, v in vars(args).items()
        if k not in ("out", "command") and isinstance(v, str) and v and os.path.exists(v)
    ]


def _raise_interrupt(signum: int, _frame: object) -> None:
    raise KeyboardInterrupt(signal.Signals(signum).name)


@contextlib.contextmanager
def _stop_signals_like_sigint() -> Iterator[None]:
    """SIGTERM and SIGHUP raise ``KeyboardInterrupt`` where they land, as Python's SIGINT
    does: every command then ends through the same clean-up (an atomic output's temporary
    ``.NAME.*.part`` removed, exit 130) instead of dying at once. A signal the process was
    told to ignore (``nohup``: SIGHUP) stays ignored; ``acquire`` defers all three to its own
    safe points inside (gyrolab/acquisition/interrupts.py). Handlers are put back on exit."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {}
    for name in ("SIGTERM", "SIGHUP"):
        sig = getattr(signal, name, None)
        if sig is not None and signal.getsignal(sig) == signal.SIG_DFL:
            old[sig] = signal.signal(sig, _raise_interrupt)
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


def _forget_interrupt_in_exec() -> None:
    """Clear CPython's note that a ``KeyboardInterrupt`` escaped an ``exec`` of a string.

    A stop signal that lands while a library runs ``exec(source)`` (scipy, dask and numba do,
    at import) makes CPython 3.11 remember an "unhandled" interrupt even though ``_main``
    handled it; under ``python -m gyrolab`` the interpreter then ends itself by SIGINT (exit
    status -2) instead of the 130 ``main`` returned. Each ``exec`` of a string resets that
    note before it runs (Python/pythonrun.c ``run_eval_code_obj``), so one empty one does."""
    exec("pass")  # noqa: S102 - an empty constant, run only for its reset


def main(argv: Sequence[str] | None = None) -> int:
    with _stop_signals_like_sigint():
        return _main(argv)


def _main(argv: Sequence[str] | None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        if not args.command:
            parser.print_help()
            return 2
        opts = options(args)  # checked here, before any numerical import
        from gyrolab.outputs import command_inputs

        with command_inputs(_input_paths(args)):
            rc = int(_handler(args.command)(opts) or 0)
        from gyrolab.app.register import register_command

        register_command(opts, rc)  # never fails the command (docs/catalogue.md)
        return rc
    except GyrolabError as e:
        print(f"gyrolab: error: {e}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt as e:
        by = f" by {e.args[0]}" if e.args and str(e.args[0]).startswith("SIG") else ""
        print(f"gyrolab: interrupted{by}", file=sys.stderr)
        _forget_interrupt_in_exec()
        return 130
    except BrokenPipeError:
        # the reader went away (`gyrolab runs list --json | head`): stop quietly, as a
        # shell tool does; stdout to /dev/null so the interpreter's flush at exit is silent
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
