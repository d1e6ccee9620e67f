"""What a command registers: one typed entry per kind of thing (the catalogue's write API).

A command builds an entry from what it wrote (its outputs are on disk first) and hands it
to :meth:`gyrolab.catalogue.Catalogue.add`. Every entry is keyed by the hash of a file
(``sha256:<hex>``, :func:`gyrolab.catalogue.digest.file_digest`), so adding one twice — a
command's own registration, then ``gyrolab runs rebuild`` over the same files — leaves one
row. Links to other things are the other files' hashes (schema.py).

The flight-controller work registers with :class:`FlashEntry` (parameters written to a
device and read back) and :class:`VerificationEntry` (the verdict of a verification run),
each keyed by the record file that command writes (docs/catalogue.md, "Flashing and
verification").
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass, field
from typing import Any


def utc_now() -> dt.datetime:
    """Now, as the catalogue stores times: naive UTC."""
    return dt.datetime.now(dt.timezone.utc).replace(tzinfo=None)


def parse_time(value: Any) -> dt.datetime | None:
    """An ISO 8601 time (``Z`` or an offset; naive = UTC) as naive UTC; None if unreadable."""
    if isinstance(value, dt.datetime):
        t = value
    elif isinstance(value, str) and value:
        try:
            t = dt.datetime.fromisoformat(value.strip().replace("Z", "+00:00"))
        except ValueError:
            return None
    else:
        return None
    if t.tzinfo is not None:
        t = t.astimezone(dt.timezone.utc).replace(tzinfo=None)
    return t


@dataclass
class UnitRef:
    """A unit as a file names it: serial, and part number where known."""

    serial: str
    part_number: str | None = None


@dataclass
class SegmentEntry:
    """One recording file of a run."""

    file_hash: str
    path: str
    size_bytes: int
    number: int = 1
    outcome: str = "unknown"  # report/outcome.py's statuses
    outcome_line: str = ""
    started_at: dt.datetime | None = None


@dataclass
class RunEntry:
    """A run (``run_key``: the recording's run id, else its first file's hash), the units
    it tested and the segment file being registered."""

    run_key: str
    source: str
    station: str
    operator: str
    profile_name: str
    profile: dict[str, Any]
    simulated: bool
    units: list[UnitRef]
    segment: SegmentEntry
    started_at: dt.datetime | None = None


@dataclass
class ModelEntry:
    """A fitted model directory (``model_hash``: the hash of its ``model.json``)."""

    model_hash: str
    path: str
    unit: UnitRef | None
    calibration_file: str | None = None  # the calibration recording's file hash
    validation_file: str | None = None
    calibration_hash: str | None = None  # model.json's content hash of the run's data
    validation_hash: str | None = None
    calibration_path: str | None = None
    validation_path: str | None = None
    held_out: bool = False
    family: str | None = None
    axes: int = 1
    metrics: dict[str, Any] = field(default_factory=dict)
    created_at: dt.datetime | None = None
    also: list[AlsoRunRef] = field(default_factory=list)  # compensate --also, in order


@dataclass
class AlsoRunRef:
    """A run a model's causal part was also fitted on (``compensate --also``): the
    recording's file hash where known, its data's content hash and path (model.json)."""

    file_hash: str | None
    data_hash: str | None
    path: str | None


@dataclass
class ExportEntry:
    """A model exported (``files``: every file written, ``(path, hash)``; the first is the
    export's own hash)."""

    model_hash: str | None
    format: str
    target: dict[str, Any]
    files: list[tuple[str, str]]
    created_at: dt.datetime = field(default_factory=utc_now)


@dataclass
class ApplicationEntry:
    """A model applied to a recording: the compensated recording written. ``models``: every
    model applied, where there are several (one per unit of a multi-unit run; revision
    0003) — ``model_hash`` is then None."""

    model_hash: str | None
    run_file: str | None
    file_hash: str
    path: str
    created_at: dt.datetime = field(default_factory=utc_now)
    models: list[str] = field(default_factory=list)


@dataclass
class FlashEntry:
    """Parameters written to a device: ``params_hash`` the hash of what was written (the
    export file's, when an export was flashed: the trace then finds the export),
    ``model_hash`` the model they came from (parameters flashed from a model directory
    directly), ``device`` the device's identity as the command read it, ``result``
    ``written`` | ``failed`` | ``restored`` (the backup put back after a failure)."""

    record_hash: str
    record_path: str
    unit: UnitRef | None
    params_hash: str
    device: str
    result: str
    model_hash: str | None = None
    detail: dict[str, Any] = field(default_factory=dict)
    created_at: dt.datetime = field(default_factory=utc_now)


@dataclass
class VerificationEntry:
    """The verdict of a verification (``PASS`` | ``FAIL``) of a flashed unit, on the
    verification run ``run_file`` where it recorded one."""

    record_hash: str
    record_path: str
    unit: UnitRef | None
    verdict: str
    flash_record: str | None = None
    run_file: str | None = None
    detail: dict[str, Any] = field(default_factory=dict)
    created_at: dt.datetime = field(default_factory=utc_now)


@dataclass
class ReportEntry:
    """A report (``report_hash``: the hash of its ``metrics.json``)."""

    report_hash: str
    path: str
    unit: UnitRef | None
    run_file: str | None
    model_hash: str | None
    outcome: str | None
    verdict: str | None
    spec: str | None
    held_out: bool
    created_at: dt.datetime = field(default_factory=utc_now)
