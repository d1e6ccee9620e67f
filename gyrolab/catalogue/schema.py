"""The catalogue's tables (SQLAlchemy 2 declarative), revision ``0002`` of the migrations.

What is linked to what (docs/catalogue.md draws it)::

    unit ─< run_unit >─ run ─< segment            a run: one or more segment files
    unit ─< model ── segment (calibration, validation)
    model ─< model_also_run ── segment            compensate --also: the causal model's other runs
    model ─< export ─< flash >─ unit ─< verification ── flash, segment
    model ─< flash                                parameters flashed from the model itself
    model ─< application ── segment               gyrolab apply's compensated recording
    unit ─< report ── segment, model              gyrolab report's verdict

A row and the unit or run it belongs to are registered together (foreign keys); every other
link is the referenced file's hash, as the file itself states it (a model names its
calibration run, an export its model), so links hold whatever order things are registered
in — a model registered before its run, or again by ``rebuild`` — and are joined on the
hashes when read.

Every row that stands for a file carries the file's SHA-256 (``sha256:<hex>``) and the path
it was registered at: the catalogue is an index of the files, which stay the record
(``gyrolab runs rebuild DIR`` recreates it from them). Times are naive UTC. A schema change
is a new Alembic revision in ``migrations/versions`` (this module is the head's shape;
``tests/test_catalogue.py`` checks that the migrations build exactly these tables).
"""

from __future__ import annotations

import datetime as dt
from typing import Any

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    DateTime,
    ForeignKey,
    Integer,
    String,
    Text,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column

HASH = String(80)  # "sha256:" + 64 hex digits, or compensation's "blake2b-160:" + 40
NAME = String(200)


class Base(DeclarativeBase):
    pass


class Unit(Base):
    """A unit under test: its serial (unique) and part number (the run's ``unit_model``)."""

    __tablename__ = "units"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    serial: Mapped[str] = mapped_column(String(64), unique=True)
    part_number: Mapped[str | None] = mapped_column(NAME)
    first_seen: Mapped[dt.datetime] = mapped_column(DateTime)


class Run(Base):
    """One test run of one or more units: its segments are the files. ``run_key`` is the
    recording's ``run_id`` where it has one, else the first segment's file hash."""

    __tablename__ = "runs"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    run_key: Mapped[str] = mapped_column(String(100), unique=True)
    source: Mapped[str] = mapped_column(String(32))  # simulate | acquire
    station: Mapped[str] = mapped_column(NAME)  # the bench's name (BENCH.toml)
    operator: Mapped[str] = mapped_column(NAME)
    profile_name: Mapped[str] = mapped_column(NAME)
    profile: Mapped[Any] = mapped_column(JSON)
    simulated: Mapped[bool] = mapped_column(Boolean)
    outcome: Mapped[str] = mapped_column(String(32))  # the last segment's
    started_at: Mapped[dt.datetime | None] = mapped_column(DateTime)
    registered_at: Mapped[dt.datetime] = mapped_column(DateTime)


class Segment(Base):
    """One recording file of a run (segment 1, and each continuation after a resume)."""

    __tablename__ = "segments"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id"), index=True)
    number: Mapped[int] = mapped_column(Integer)
    file_hash: Mapped[str] = mapped_column(HASH, unique=True)
    path: Mapped[str] = mapped_column(Text)
    size_bytes: Mapped[int] = mapped_column(BigInteger)
    outcome: Mapped[str] = mapped_column(String(32))
    outcome_line: Mapped[str] = mapped_column(Text)
    started_at: Mapped[dt.datetime | None] = mapped_column(DateTime)
    host: Mapped[str] = mapped_column(NAME)  # the machine that registered it
    registered_at: Mapped[dt.datetime] = mapped_column(DateTime)


class RunUnit(Base):
    """Which units a run tested (a multi-unit run: every serial of the file)."""

    __tablename__ = "run_units"
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id"), primary_key=True)
    unit_id: Mapped[int] = mapped_column(ForeignKey("units.id"), primary_key=True, index=True)


class Model(Base):
    """A fitted model directory: identified by the hash of its ``model.json`` (which holds no
    clock reading: the same fit gives the same bytes)."""

    __tablename__ = "models"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    model_hash: Mapped[str] = mapped_column(HASH, unique=True)
    path: Mapped[str] = mapped_column(Text)
    unit_id: Mapped[int | None] = mapped_column(ForeignKey("units.id"), index=True)
    # the runs' segment files (where the fit knew them) and their data (guards.py)
    calibration_file: Mapped[str | None] = mapped_column(HASH, index=True)
    validation_file: Mapped[str | None] = mapped_column(HASH, index=True)
    calibration_hash: Mapped[str | None] = mapped_column(HASH)
    validation_hash: Mapped[str | None] = mapped_column(HASH)
    calibration_path: Mapped[str | None] = mapped_column(Text)
    validation_path: Mapped[str | None] = mapped_column(Text)
    held_out: Mapped[bool] = mapped_column(Boolean)
    family: Mapped[str | None] = mapped_column(String(64))  # the headline's drift family
    axes: Mapped[int] = mapped_column(Integer)
    metrics: Mapped[Any] = mapped_column(JSON)
    created_at: Mapped[dt.datetime | None] = mapped_column(DateTime)
    registered_at: Mapped[dt.datetime] = mapped_column(DateTime)


class ModelAlsoRun(Base):
    """A run a model's causal part was also fitted on, from its own power-on
    (``compensate --also``; revision 0002), in the order given: the recording's file hash
    where the fit knew the file, the data's content hash and path as model.json names
    them."""

    __tablename__ = "model_also_runs"
    model_id: Mapped[int] = mapped_column(ForeignKey("models.id"), primary_key=True)
    position: Mapped[int] = mapped_column(Integer, primary_key=True)
    file_hash: Mapped[str | None] = mapped_column(HASH, index=True)
    data_hash: Mapped[str | None] = mapped_column(HASH)
    path: Mapped[str | None] = mapped_column(Text)


class Export(Base):
    """A model written in a firmware's or tool's format (``gyrolab export``)."""

    __tablename__ = "exports"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    model_hash: Mapped[str | None] = mapped_column(HASH, index=True)
    format: Mapped[str] = mapped_column(String(16))
    target: Mapped[Any] = mapped_column(JSON)  # instance, device id, kind, topic: as given
    file_hash: Mapped[str] = mapped_column(HASH, unique=True)
    path: Mapped[str] = mapped_column(Text)
    files: Mapped[Any] = mapped_column(JSON)  # [{"path", "sha256"}] every file written
    created_at: Mapped[dt.datetime] = mapped_column(DateTime)


class Application(Base):
    """A model applied to a run (``gyrolab apply``): the compensated recording."""

    __tablename__ = "applications"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    model_hash: Mapped[str | None] = mapped_column(HASH, index=True)
    run_file: Mapped[str | None] = mapped_column(HASH, index=True)  # the input segment
    file_hash: Mapped[str] = mapped_column(HASH, unique=True)
    path: Mapped[str] = mapped_column(Text)
    created_at: Mapped[dt.datetime] = mapped_column(DateTime)


class ApplicationModel(Base):
    """A model of a compensated recording that applied several, one per unit of a
    multi-unit run (``gyrolab apply`` without ``--unit``; revision 0003)."""

    __tablename__ = "application_models"
    application_id: Mapped[int] = mapped_column(ForeignKey("applications.id"), primary_key=True)
    model_hash: Mapped[str] = mapped_column(HASH, primary_key=True, index=True)


class Flash(Base):
    """A parameter set written to a device (a flight controller) and read back."""

    __tablename__ = "flashes"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    record_hash: Mapped[str] = mapped_column(HASH, unique=True)  # the flash's record file
    record_path: Mapped[str] = mapped_column(Text)
    unit_id: Mapped[int | None] = mapped_column(ForeignKey("units.id"), index=True)
    # what was written: the parameter set's hash (an export file's, when one was flashed)
    # and the model it came from
    params_hash: Mapped[str] = mapped_column(HASH, index=True)
    model_hash: Mapped[str | None] = mapped_column(HASH, index=True)
    device: Mapped[str] = mapped_column(Text)  # the device's identity (board, id, port)
    result: Mapped[str] = mapped_column(String(32))  # written | failed | restored
    detail: Mapped[Any] = mapped_column(JSON)
    created_at: Mapped[dt.datetime] = mapped_column(DateTime)
    host: Mapped[str] = mapped_column(NAME)


class Verification(Base):
    """A verification of a flashed unit: PASS or FAIL, on a verification run."""

    __tablename__ = "verifications"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    record_hash: Mapped[str] = mapped_column(HASH, unique=True)  # the verdict's record file
    record_path: Mapped[str] = mapped_column(Text)
    unit_id: Mapped[int | None] = mapped_column(ForeignKey("units.id"), index=True)
    flash_record: Mapped[str | None] = mapped_column(HASH, index=True)
    run_file: Mapped[str | None] = mapped_column(HASH, index=True)  # the verification run
    verdict: Mapped[str] = mapped_column(String(16))  # PASS | FAIL
    detail: Mapped[Any] = mapped_column(JSON)
    created_at: Mapped[dt.datetime] = mapped_column(DateTime)
    host: Mapped[str] = mapped_column(NAME)


class Report(Base):
    """A report of one unit's run (``gyrolab report``): outcome and, with a spec, verdict.
    Identified by the hash of its ``metrics.json``."""

    __tablename__ = "reports"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    report_hash: Mapped[str] = mapped_column(HASH, unique=True)
    unit_id: Mapped[int | None] = mapped_column(ForeignKey("units.id"), index=True)
    run_file: Mapped[str | None] = mapped_column(HASH, index=True)
    model_hash: Mapped[str | None] = mapped_column(HASH, index=True)
    path: Mapped[str] = mapped_column(Text)
    outcome: Mapped[str | None] = mapped_column(String(32))
    verdict: Mapped[str | None] = mapped_column(String(16))  # PASS | FAIL | None (no spec)
    spec: Mapped[str | None] = mapped_column(Text)
    held_out: Mapped[bool] = mapped_column(Boolean)
    created_at: Mapped[dt.datetime] = mapped_column(DateTime)
