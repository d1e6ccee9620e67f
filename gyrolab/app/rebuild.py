"""``gyrolab runs rebuild DIR...``: the catalogue recreated from the files.

Walks each DIR (hidden directories and temporary ``.part`` outputs skipped) and registers
what it finds, by what each file is, not by its name:

* ``*.mcap`` gyrolab recordings: a segment of a run (``gyrolab apply``'s compensated
  recordings — those with a ``compensation`` record — as applications);
* directories with a ``model.json``: models (a 2–3-axis model's axis directories are part
  of it); with a ``metrics.json`` and an ``index.html``: reports;
* files naming their model on a ``gyrolab export … model sha256:…`` line (``.params``,
  ``.parm``, ``.c`` with its ``.h``, kalibr ``.yaml``) or JSON exports with
  ``model_sha256``: exports;
* JSON records of format ``gyrolab.flash`` / ``gyrolab.verification``.

A model is linked to its calibration and validation runs, and a report to its run, through
the path the model or report recorded (as given on the command line: tried as written,
then against DIR and the directories above the model, then by file name among the
recordings found when that is unique). A file that cannot be read is listed as skipped with
the reason; the others are registered. Registering the same files twice changes nothing
(every row is keyed by a file hash).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gyrolab.app.index_files import (
    EXPORT_MODEL_RE,
    FLASH_FORMAT,
    VERIFICATION_FORMAT,
    application_entry,
    export_entry,
    is_application,
    model_entry,
    record_entry,
    report_entry,
    run_entry,
)
from gyrolab.catalogue.entries import RunEntry, UnitRef
from gyrolab.errors import GyrolabError, InputError

EXPORT_SUFFIXES = {".params": "px4", ".parm": "ardupilot", ".c": "c", ".yaml": "kalibr"}
TARGET_MARK = " target "


@dataclass
class Found:
    """What a walk found, by kind."""

    recordings: list[Path] = field(default_factory=list)
    models: list[Path] = field(default_factory=list)
    reports: list[Path] = field(default_factory=list)
    exports: list[Path] = field(default_factory=list)
    json_files: list[Path] = field(default_factory=list)


@dataclass
class Rebuilt:
    """What a rebuild registered (counts by kind) and skipped (path, reason)."""

    counts: dict[str, int] = field(default_factory=dict)
    skipped: list[tuple[str, str]] = field(default_factory=list)
    entries: list[Any] = field(default_factory=list)

    def add(self, kind: str, entry: Any) -> None:
        self.counts[kind] = self.counts.get(kind, 0) + 1
        self.entries.append(entry)


def walk(root: Path) -> Found:
    """The files under ``root`` the catalogue indexes (module docstring)."""
    from gyrolab.compensation.model_dir import ModelDir

    found = Found()
    for dirpath, dirnames, filenames in os.walk(root):
        here = Path(dirpath)
        dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
        if ModelDir.is_model_dir(here):
            found.models.append(here)
            dirnames[:] = []  # an axis directory is part of its model
            continue
        if "metrics.json" in filenames and "index.html" in filenames:
            found.reports.append(here)
            dirnames[:] = []
            continue
        for name in sorted(filenames):
            if name.startswith(".") or name.endswith(".part"):
                continue
            p = here / name
            if p.suffix == ".mcap":
                found.recordings.append(p)
            elif p.suffix in EXPORT_SUFFIXES:
                found.exports.append(p)
            elif p.suffix == ".json":
                found.json_files.append(p)
    return found


def resolve(
    recorded: str | None, near: list[Path], runs: dict[Path, RunEntry], out: Rebuilt
) -> str | None:
    """The file hash of the run a model or report recorded as ``recorded``: a recording
    found in the walk, or the file at that path outside it (then registered too)."""
    if not recorded:
        return None
    p = Path(recorded)
    candidates = [p] if p.is_absolute() else [Path.cwd() / p, *(d / p for d in near)]
    for c in candidates:
        if not c.is_file():
            continue
        key = c.resolve()
        if key not in runs:
            try:
                runs[key] = run_entry(key)
            except GyrolabError:
                continue
            out.add("runs", runs[key])
        return runs[key].segment.file_hash
    same_name = [e for path, e in runs.items() if path.name == p.name]
    return same_name[0].segment.file_hash if len(same_name) == 1 else None


def _near(d: Path, root: Path) -> list[Path]:
    """``d``'s parent directories up to and including ``root``."""
    out = []
    for parent in d.parents:
        out.append(parent)
        if parent == root:
            break
    return out


def _target(head: str) -> dict[str, Any]:
    """The target an export's provenance line states (``… target {json}``)."""
    for line in head.splitlines():
        if EXPORT_MODEL_RE.search(line) and TARGET_MARK in line:
            try:
                t = json.loads(line.split(TARGET_MARK, 1)[1].strip().removesuffix("*/"))
                return t if isinstance(t, dict) else {}
            except ValueError:
                return {}
    return {}


def rebuild_entries(root: str | os.PathLike[str]) -> Rebuilt:
    """Every entry the files under ``root`` give (module docstring); nothing written."""
    from gyrolab.compensation.model_dir import ModelDir

    base = Path(root)
    if not base.is_dir():
        raise InputError(base, "not a directory")
    base = base.resolve()
    found = walk(base)
    out = Rebuilt()
    from gyrolab.record.reader import read_metadata

    runs: dict[Path, RunEntry] = {}
    run_records: dict[Path, Any] = {}  # each run's `run` metadata record
    applications: list[tuple[Path, dict[str, Any]]] = []
    for p in found.recordings:
        try:
            meta = read_metadata(p)
            if is_application(meta):
                applications.append((p, meta))
                continue
            runs[p.resolve()] = entry = run_entry(p)
            run_records[p.resolve()] = meta.get("run")
            out.add("runs", entry)
        except GyrolabError as e:
            out.skipped.append((str(p), str(e)))

    def unit_of(file_hash: str | None, serial: str | None) -> UnitRef | None:
        run = next((e for e in runs.values() if e.segment.file_hash == file_hash), None)
        if run is None:
            return UnitRef(serial) if serial else None
        units = {u.serial: u for u in run.units}
        if serial:
            return units.get(serial, UnitRef(serial))
        return run.units[0] if len(run.units) == 1 else None

    models: dict[Path, Any] = {}
    for d in found.models:
        try:
            m = model_entry(d)
            m.calibration_file = resolve(m.calibration_path, _near(d, base), runs, out)
            m.validation_file = resolve(m.validation_path, _near(d, base), runs, out)
            for a in m.also:
                a.file_hash = resolve(a.path, _near(d, base), runs, out)
            m.unit = unit_of(m.calibration_file, None if m.unit is None else m.unit.serial)
            models[d.resolve()] = m
            out.add("models", m)
        except (GyrolabError, OSError) as e:
            out.skipped.append((str(d), str(e)))
    for p in found.exports:
        head = p.read_text(encoding="utf-8", errors="replace")[:4096]
        model = EXPORT_MODEL_RE.search(head)
        if model is None:
            continue
        files = [p] + ([p.with_suffix(".h")] if p.suffix == ".c" else [])
        entry = export_entry(
            model.group(1),
            EXPORT_SUFFIXES[p.suffix],
            _target(head),
            [f for f in files if f.is_file()],
        )
        out.add("exports", entry)
    for p in found.json_files:
        try:
            d = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, ValueError, UnicodeDecodeError):
            continue
        if not isinstance(d, dict):
            continue
        if d.get("format") in (FLASH_FORMAT, VERIFICATION_FORMAT):
            try:
                out.add("records", record_entry(p))
            except GyrolabError as e:
                out.skipped.append((str(p), str(e)))
        elif isinstance(d.get("model_sha256"), str):  # a JSON export
            out.add("exports", export_entry(d["model_sha256"], "json", d.get("target") or {}, [p]))
    for p, meta in applications:
        try:
            comp = meta.get("compensation", {})
            per_unit = comp.get("units") if isinstance(comp.get("units"), dict) else None
            dirs = [
                Path(str(info.get("model_dir", "")))
                for info in (per_unit.values() if per_unit else [comp])
                if isinstance(info, dict)
            ]
            hashes: list[str | None] = []
            for model_dir in dirs:
                if ModelDir.is_model_dir(model_dir):
                    hashes.append(ModelDir(model_dir).digest())
                else:  # moved since: the model of that name found here
                    named = [m for path, m in models.items() if path.name == model_dir.name]
                    hashes.append(named[0].model_hash if len(named) == 1 else None)
            # apply copies its input's `run` record: the input is the run that has it
            source = [
                runs[q].segment.file_hash for q, r in run_records.items() if r == meta.get("run")
            ]
            entry = application_entry(p, hashes, source[0] if len(source) == 1 else None)
            out.add("applications", entry)
        except (GyrolabError, OSError) as e:
            out.skipped.append((str(p), str(e)))
    for d in found.reports:
        try:
            metrics = json.loads((d / "metrics.json").read_text(encoding="utf-8"))
            run_file = resolve(str(metrics.get("run") or ""), _near(d, base), runs, out)
            cal = metrics.get("calibration_run")
            serial = metrics.get("unit")
            # the model fitted on the report's calibration run: of the report's unit, or
            # held out on this very run (the model's --validate run may be another unit's)
            candidates = [
                m
                for m in models.values()
                if cal
                and m.calibration_path == cal
                and (
                    not serial
                    or m.unit is None
                    or m.unit.serial == serial
                    or (run_file is not None and m.validation_file == run_file)
                )
            ]
            model_hash = candidates[0].model_hash if len(candidates) == 1 else None
            out.add("reports", report_entry(d, run_file, model_hash, unit_of(run_file, serial)))
        except (GyrolabError, OSError, ValueError) as e:
            out.skipped.append((str(d), str(e)))
    return out
