"""What each file gyrolab writes says for the catalogue: a catalogue entry from a file.

One function per kind of output — a recording (:func:`run_entry`), a model directory
(:func:`model_entry`), an export (:func:`export_entry`), a compensated recording
(:func:`application_entry`), a report directory (:func:`report_entry`), a flash or
verification record (:func:`record_entry`) — used both by the commands, right after they
wrote the file, and by ``gyrolab runs rebuild``, which finds the files again (so both give
the same rows). Paths are stored absolute. Nothing here writes.
"""

from __future__ import annotations

import datetime as dt
import json
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from gyrolab.catalogue.digest import file_digest
from gyrolab.catalogue.entries import (
    AlsoRunRef,
    ApplicationEntry,
    ExportEntry,
    FlashEntry,
    ModelEntry,
    ReportEntry,
    RunEntry,
    SegmentEntry,
    UnitRef,
    VerificationEntry,
    parse_time,
    utc_now,
)
from gyrolab.errors import InputError
from gyrolab.record.metadata import RunMetadata

PathLike = str | os.PathLike[str]
#: The line every export carries to name its model (gyrolab/export/commands.py writes it).
EXPORT_MODEL_RE = re.compile(r"model (sha256:[0-9a-f]{64})")
#: The metrics of a model or report kept in the catalogue (docs/cli.md keys).
KEPT_METRICS = ("raw", "compensated", "causal", "oracle", "headline", "drift_pp_100s_deg_per_s")
FLASH_FORMAT = "gyrolab.flash"
VERIFICATION_FORMAT = "gyrolab.verification"


def absolute(path: PathLike) -> str:
    return str(Path(path).absolute())


def _json(path: Path) -> dict[str, Any]:
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(path.parent, f"no {path.name}") from None
    except (ValueError, UnicodeDecodeError) as e:
        raise InputError(path, f"damaged JSON ({type(e).__name__})") from None
    if not isinstance(d, dict):
        raise InputError(path, "not a JSON object")
    return d


def is_application(meta: dict[str, dict[str, Any]]) -> bool:
    """A compensated recording (``gyrolab apply``'s output), not a run."""
    return "compensation" in meta


def units_of(run: RunMetadata, bench: dict[str, Any]) -> list[UnitRef]:
    """The units a recording tested, with their part numbers (``unit_model``, or a
    ``part_number`` in the bench record's per-unit table)."""
    serials = list(run.units) if run.units else ([run.unit_serial] if run.unit_serial else [])
    per_unit = bench.get("units") if isinstance(bench.get("units"), dict) else {}
    out = []
    for s in serials:
        u = per_unit.get(s) if isinstance(per_unit.get(s), dict) else {}
        out.append(UnitRef(s, str(u.get("part_number") or run.unit_model or "") or None))
    return out


def named(serial: Any, unit: UnitRef | None) -> UnitRef | None:
    """The unit a file names (its serial, with the part number the caller knew), else the
    caller's."""
    if not serial:
        return unit
    return UnitRef(str(serial), None if unit is None else unit.part_number)


def run_entry(path: PathLike) -> RunEntry:
    """A recording (a segment of a run): its run's metadata, units, outcome and hash.
    Raises :class:`InputError` for a file that is not a readable gyrolab recording."""
    from gyrolab.record.reader import read_metadata, read_recording
    from gyrolab.report.outcome import run_outcome

    p = Path(path)
    meta = read_metadata(p)
    if "run" not in meta:
        raise InputError(p, "not a gyrolab recording (no run metadata)")
    if is_application(meta):
        raise InputError(p, "a compensated recording (gyrolab apply), not a run")
    run = RunMetadata.from_dict(meta["run"])
    bench = meta.get("bench", {})
    outcome = run_outcome(read_recording(p, topics=["/profile/event"]))
    digest = file_digest(p)
    started = parse_time(run.start_time)
    # a resumed run's files carry its id and their segment number (docs/recording-format.md,
    # "Segments"); the reader gives the first segment's record with every segment listed
    raw = meta["run"]
    number = raw.get("segment", 1)
    for seg in raw.get("segments") or []:
        if isinstance(seg, dict) and seg.get("file") == p.name:
            number = seg.get("segment", number)
    profile = run.profile if isinstance(run.profile, dict) else {}
    return RunEntry(
        run_key=str(raw.get("run_id") or digest),
        source=run.source,
        station=run.bench_name or str(bench.get("name", "")),
        operator=run.operator,
        profile_name=str(profile.get("name", "")),
        profile=profile,
        simulated=bool(bench.get("simulated")) or run.source == "simulate",
        units=units_of(run, bench),
        segment=SegmentEntry(
            file_hash=digest,
            path=absolute(p),
            size_bytes=p.stat().st_size,
            number=int(number) if isinstance(number, (int, str)) and str(number).isdigit() else 1,
            outcome=outcome.status,
            outcome_line=outcome.line,
            started_at=started,
        ),
        started_at=started,
    )


def written(path: PathLike) -> dt.datetime:
    """When a file was written (its modification time, naive UTC)."""
    t = dt.datetime.fromtimestamp(Path(path).stat().st_mtime, dt.timezone.utc)
    return t.replace(tzinfo=None, microsecond=0)


def earlier_segments(path: PathLike) -> list[Path]:
    """The files of the segments before ``path`` in its run (a resumed run's record lists
    them, beside it), those that exist."""
    from gyrolab.record.reader import read_metadata

    p = Path(path)
    segs = read_metadata(p).get("run", {}).get("segments") or []
    files = [p.parent / str(s["file"]) for s in segs if isinstance(s, dict) and s.get("file")]
    return [f for f in files if f.name != p.name and f.is_file()]


def _kept(metrics: dict[str, Any]) -> dict[str, Any]:
    if isinstance(metrics.get("axes"), dict):
        return {"axes": {a: _kept(m) for a, m in metrics["axes"].items() if isinstance(m, dict)}}
    return {k: metrics[k] for k in KEPT_METRICS if k in metrics}


def _created(directory: Path) -> Any:
    """When gyrolab wrote a directory (its output marker's time); None if it has none."""
    from gyrolab.outputs import MARKER

    try:
        return parse_time(json.loads((directory / MARKER).read_text()).get("time"))
    except (OSError, ValueError, AttributeError):
        return None


def model_entry(
    model_dir: PathLike,
    calibration_file: str | None = None,
    validation_file: str | None = None,
    unit: UnitRef | None = None,
    also_files: Sequence[str | None] = (),
) -> ModelEntry:
    """A model directory: its hash, unit, the runs it was fitted and validated on (their
    data hashes from ``model.json``/``results.json``; their file hashes where the caller
    knows the files — ``also_files``: those of the ``--also`` runs, in order), its
    headline metrics."""
    from gyrolab.compensation.model_dir import ModelDir

    d = Path(model_dir)
    md = ModelDir(d)
    axes = md.axes()
    axis = axes[0][1]  # the first axis's directory (the model itself when single-axis)
    meta = axis.head()
    metrics = md.require_metrics()
    cal = meta.get("calibration") if isinstance(meta.get("calibration"), dict) else {}
    runs = axis.run_records()
    val = runs.get("validation") if isinstance(runs.get("validation"), dict) else {}
    unit = named(cal.get("unit") or metrics.get("unit"), unit)
    family = (metrics.get("causal_model") or {}).get("family") or (
        metrics.get("headline") or {}
    ).get("family")
    return ModelEntry(
        model_hash=md.digest(),
        path=absolute(d),
        unit=unit,
        calibration_file=calibration_file,
        validation_file=validation_file,
        calibration_hash=cal.get("content_hash"),
        validation_hash=val.get("content_hash"),
        calibration_path=cal.get("path"),
        validation_path=val.get("path"),
        held_out=bool(metrics.get("held_out")),
        family=family,
        axes=len(axes),
        metrics=_kept(metrics),
        created_at=_created(d),
        also=[
            AlsoRunRef(
                also_files[k] if k < len(also_files) else None,
                a.get("content_hash"),
                a.get("path"),
            )
            for k, a in enumerate(cal.get("also") or [])
        ],
    )


def export_entry(
    model_hash: str | None, fmt: str, target: dict[str, Any], files: list[PathLike]
) -> ExportEntry:
    """An export's files (the first is the export itself; ``c``: ``NAME.c``, ``NAME.h``)."""
    return ExportEntry(
        model_hash=model_hash,
        format=fmt,
        target={k: target[k] for k in sorted(target) if target[k] is not None},
        files=[(absolute(f), file_digest(f)) for f in files],
        created_at=written(files[0]),
    )


def export_model_hash(path: PathLike) -> str | None:
    """The model an export names (its ``model sha256:…`` line), None if it names none."""
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            head = f.read(4096)
    except OSError:
        return None
    m = EXPORT_MODEL_RE.search(head)
    return m.group(1) if m else None


def application_entry(
    out: PathLike, model_hashes: list[str | None], run_file: str | None
) -> ApplicationEntry:
    """A compensated recording and the models it applied: one (``model_hash``; None when
    unknown), or one per unit of a multi-unit run (``models``)."""
    known = [h for h in model_hashes if h]
    return ApplicationEntry(
        model_hash=model_hashes[0] if len(model_hashes) == 1 else None,
        run_file=run_file,
        file_hash=file_digest(out),
        path=absolute(out),
        created_at=written(out),
        models=known if len(model_hashes) > 1 else [],
    )


def report_entry(
    report_dir: PathLike, run_file: str | None, model_hash: str | None, unit: UnitRef | None
) -> ReportEntry:
    """A report directory: its run's outcome and, with a spec, its verdict."""
    d = Path(report_dir)
    metrics_path = d / "metrics.json"
    m = _json(metrics_path)
    first = m
    if isinstance(m.get("axes"), dict) and m["axes"]:
        first = next(iter(m["axes"].values()))
    verdicts = [
        a.get("verdict")
        for a in (m["axes"].values() if "axes" in m else [m])
        if isinstance(a, dict) and isinstance(a.get("verdict"), dict)
    ]
    verdict = None
    if verdicts:  # a multi-axis unit passes when every axis passes
        verdict = "PASS" if all(v.get("verdict") == "PASS" for v in verdicts) else "FAIL"
    outcome = first.get("outcome") if isinstance(first.get("outcome"), dict) else {}
    unit = named(first.get("unit"), unit)
    return ReportEntry(
        report_hash=file_digest(metrics_path),
        path=absolute(d),
        unit=unit,
        run_file=run_file,
        model_hash=model_hash,
        outcome=outcome.get("status"),
        verdict=verdict,
        spec=verdicts[0].get("spec") if verdicts else None,
        held_out=bool(m.get("held_out")),
        created_at=_created(d) or utc_now(),
    )


def record_entry(path: PathLike) -> FlashEntry | VerificationEntry:
    """A flash or verification record file (JSON, ``format`` ``gyrolab.flash`` or
    ``gyrolab.verification``; keys in docs/catalogue.md)."""
    p = Path(path)
    d = _json(p)
    fmt = d.get("format")
    serial = d.get("unit")
    unit = UnitRef(str(serial), d.get("part_number")) if serial else None
    created = parse_time(d.get("time")) or utc_now()
    detail = d.get("detail") if isinstance(d.get("detail"), dict) else {}
    if fmt == FLASH_FORMAT:
        return FlashEntry(
            record_hash=file_digest(p),
            record_path=absolute(p),
            unit=unit,
            params_hash=str(d.get("params_sha256", "")),
            model_hash=d.get("model_sha256"),
            device=str(d.get("device", "")),
            result=str(d.get("result", "")),
            detail=detail,
            created_at=created,
        )
    if fmt == VERIFICATION_FORMAT:
        return VerificationEntry(
            record_hash=file_digest(p),
            record_path=absolute(p),
            unit=unit,
            verdict=str(d.get("verdict", "")),
            flash_record=d.get("flash_record_sha256"),
            run_file=d.get("run_sha256"),
            detail=detail,
            created_at=created,
        )
    raise InputError(p, f"not a flash or verification record (format {fmt!r})")
