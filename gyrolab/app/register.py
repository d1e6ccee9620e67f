"""Registering what a command wrote, after it wrote it — never at the command's expense.

Each ``register_*`` takes the paths a command read and wrote, builds the catalogue entries
from the files (:mod:`gyrolab.app.index_files`) and adds them in the catalogue
(``--catalogue`` / ``$GYROLAB_CATALOGUE`` / the default SQLite file). Registration is an
index of files that already exist, so **nothing about it may fail a command**: a catalogue
that cannot be reached, a file it cannot read, any error at all, costs one warning line on
stderr (once per process) and the command's result is unchanged; ``gyrolab runs rebuild
DIR`` registers the files later. ``GYROLAB_CATALOGUE=off`` turns it off.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

from gyrolab.app.index_files import (
    application_entry,
    earlier_segments,
    export_entry,
    model_entry,
    record_entry,
    report_entry,
    run_entry,
)
from gyrolab.catalogue.entries import RunEntry, UnitRef

PathLike = str | Path
Builder = Callable[[], Iterable[Any]]
_warned: list[str] = []  # the process's one warning (kept for tests to read)


def warn_once(reason: str) -> None:
    """The one warning of the process about registration."""
    if _warned:
        return
    line = (
        f"gyrolab: warning: not registered in the catalogue: {reason} "
        "(the outputs are written; `gyrolab runs rebuild DIR` registers them later)"
    )
    _warned.append(line)
    print(line, file=sys.stderr)


def register(builders: Iterable[Builder], url: str | None = None) -> bool:
    """Build every entry and add it; False (after the warning) on any failure."""
    from gyrolab.catalogue import Catalogue
    from gyrolab.catalogue.store import CatalogueError, catalogue_url, shown

    target = None
    try:
        target = catalogue_url(url)
        if target is None:
            return False
        with Catalogue.open(target) as cat:
            for build in builders:
                for entry in build():
                    cat.add(entry)
        return True
    except CatalogueError as e:  # names the catalogue and the problem
        warn_once(str(e))
    except Exception as e:  # registration must never fail the command (module docstring)
        first = (str(e).splitlines() or [""])[0]
        warn_once(f"{shown(target) if target else 'catalogue'}: {type(e).__name__}: {first}")
    return False


def is_recording(path: PathLike | None) -> bool:
    """A gyrolab MCAP recording (not a ROS 2 bag or an autopilot log)."""
    if path is None or not Path(path).is_file():
        return False
    from gyrolab.logs import detect_format

    try:
        return detect_format(path) == "gyrolab"
    except Exception:  # unreadable: nothing to register
        return False


def _run(path: PathLike | None) -> RunEntry | None:
    return run_entry(path) if path is not None and is_recording(path) else None


def _part_number(run: RunEntry | None, serial: str | None) -> UnitRef | None:
    """The unit ``serial`` (default: the run's only unit) with the run's part number."""
    if run is None:
        return None
    units = {u.serial: u for u in run.units}
    if serial is None:
        return run.units[0] if len(run.units) == 1 else None
    return units.get(serial, UnitRef(serial))


def register_recording(path: PathLike, url: str | None = None) -> bool:
    """``simulate``, ``acquire``, ``recover``: the recording written (and, for the
    continuation of a resumed run, the segments before it)."""

    def build() -> list[Any]:
        files = [*earlier_segments(path), Path(path)] if is_recording(path) else []
        return [run_entry(f) for f in files]

    return register([build], url)


def register_models(
    model_dirs: list[PathLike],
    run: PathLike | None,
    validate: PathLike | None = None,
    url: str | None = None,
    also: Sequence[PathLike] = (),
) -> bool:
    """``compensate``: the calibration (and validation, and ``--also``) runs, and each
    model directory written (one per unit of a multi-unit run)."""

    def build() -> list[Any]:
        cal, val = _run(run), _run(validate)
        more = [_run(a) for a in also]
        out: list[Any] = [e for e in (cal, val, *more) if e is not None]
        also_files = [None if e is None else e.segment.file_hash for e in more]
        for d in model_dirs:
            out.append(
                model_entry(
                    d,
                    None if cal is None else cal.segment.file_hash,
                    None if val is None else val.segment.file_hash,
                    _part_number(cal, None),
                    also_files,
                )
            )
            if cal is not None and out[-1].unit is not None:  # the serial from model.json
                out[-1].unit = _part_number(cal, out[-1].unit.serial)
        return out

    return register([build], url)


def register_application(
    model_dirs: list[PathLike], run: PathLike, out: PathLike, url: str | None = None
) -> bool:
    """``apply``: the input run, the models (one, or one per unit of a multi-unit run) and
    the compensated recording."""

    def build() -> list[Any]:
        entry = _run(run)
        models = [model_entry(d, None, None, _part_number(entry, None)) for d in model_dirs]
        file = None if entry is None else entry.segment.file_hash
        return [e for e in (entry, *models) if e is not None] + [
            application_entry(out, [m.model_hash for m in models], file)
        ]

    return register([build], url)


def register_export(
    model_dir: PathLike,
    fmt: str,
    target: dict[str, Any],
    files: list[PathLike],
    url: str | None = None,
) -> bool:
    """``export``: the model and the files written."""

    def build() -> list[Any]:
        model = model_entry(model_dir)
        return [model, export_entry(model.model_hash, fmt, target, files)]

    return register([build], url)


def register_report(
    report_dir: PathLike,
    run: PathLike,
    model_dir: PathLike | None = None,
    unit: str | None = None,
    url: str | None = None,
) -> bool:
    """``report``: the run, the model shown, and the report's outcome and verdict."""

    def build() -> list[Any]:
        entry = _run(run)
        ref = _part_number(entry, unit)
        out: list[Any] = [] if entry is None else [entry]
        model_hash = None
        if model_dir is not None:
            model = model_entry(model_dir, None, None, ref)
            out.append(model)
            model_hash = model.model_hash
        file = None if entry is None else entry.segment.file_hash
        out.append(report_entry(report_dir, file, model_hash, ref))
        return out

    return register([build], url)


def register_record(path: PathLike, url: str | None = None) -> bool:
    """A flash or verification record file (the flight-controller commands)."""
    return register([lambda: [record_entry(path)]], url)


def register_tree(directory: PathLike, url: str | None = None) -> bool:
    """Every file under ``directory`` (``gyrolab batch``'s and ``gyrolab demo``'s outputs,
    registered once they are in place): :func:`gyrolab.app.rebuild.rebuild_entries`."""
    from gyrolab.app.rebuild import rebuild_entries

    return register([lambda: rebuild_entries(directory).entries], url)


def register_command(opts: object, rc: int) -> None:
    """After a command (its typed options, :mod:`gyrolab.app.options`, and its exit code):
    register what it wrote. A command that wrote nothing (exit 2) registers nothing;
    ``acquire`` registers its recording on a fault (1) and an interrupt (130) too.
    ``demo`` registers its directory itself; ``runs``, ``discrepancy``, ``convert`` and
    ``fleet`` write nothing the catalogue indexes."""
    from gyrolab.app import options as o

    if rc not in (0, 1, 130):
        return
    out = Path(str(getattr(opts, "out", "")))
    if isinstance(opts, o.AcquireOptions) and opts.out is None and opts.resume is not None:
        # --resume without --out: the continuation went beside the run it continues
        from gyrolab.app.resume import last_continuation

        cont = last_continuation(opts.resume)
        if cont is not None:
            register_recording(cont)
    elif isinstance(opts, (o.SimulateOptions, o.AcquireOptions, o.RecoverOptions)):
        if out.is_file():
            register_recording(out)
    elif isinstance(opts, o.CompensateOptions):
        # one model directory, or DIR/<serial> per unit of a multi-unit run
        from gyrolab.compensation.model_dir import ModelDir

        dirs = (
            [out]
            if ModelDir.is_model_dir(out)
            else sorted(d for d in out.glob("*") if ModelDir.is_model_dir(d))
        )
        if dirs:
            register_models(dirs, opts.run, opts.validate, also=opts.also)
    elif isinstance(opts, o.ApplyOptions) and out.is_file():
        from gyrolab.compensation.apply_command import resolve_models

        # the models applied: MODEL_DIR itself, or DIR/<serial> of compensate's DIR per unit
        dirs = [d for d, _serial in resolve_models(opts.model, opts.run, opts.unit)]
        register_application(dirs, opts.run, out)
    elif isinstance(opts, o.ExportOptions):
        from gyrolab.export.commands import target

        files = [out] + ([out.with_suffix(".h")] if opts.format == "c" else [])
        what = target(
            opts.format,
            kind=opts.kind,
            instance=opts.instance,
            device_id=opts.device_id,
            run=opts.run,
            rostopic=opts.rostopic,
        )
        if all(f.is_file() for f in files):
            register_export(opts.model, opts.format, what, files)
    elif isinstance(opts, o.ReportOptions) and (out / "metrics.json").is_file():
        register_report(out, opts.run, opts.model, opts.unit)
    elif isinstance(opts, o.BatchCommandOptions) and out.is_dir():
        register_tree(out)


DEMO_CATALOGUE = "catalogue.sqlite"  # inside DIR unless --catalogue / $GYROLAB_CATALOGUE


def demo_catalogue(out: Path, option: str | None) -> str | None:
    """Where a demo registers its directory (``gyrolab demo``, ``demo --fc``): ``option``,
    else ``$GYROLAB_CATALOGUE`` where the user set it, else ``out/catalogue.sqlite`` (a
    demo's simulated units stay out of a lab's catalogue unless asked); None when
    registration is off."""
    import os

    from gyrolab.catalogue.store import ENV, catalogue_url, sqlite_url

    if option or os.environ.get(ENV, "").strip():
        return catalogue_url(option)
    return sqlite_url(out / DEMO_CATALOGUE)
