"""Writing entries: one transaction each, idempotent by the file hashes that key them.

Every write is an ``INSERT … ON CONFLICT (key) DO UPDATE … RETURNING id`` (SQLite ≥ 3.35 and
PostgreSQL both speak it): two stations registering the same unit or run at once get one
row, and registering a file again updates its row (a moved file: its new path) instead of
adding one.
"""

from __future__ import annotations

import socket
from collections.abc import Iterable
from dataclasses import asdict
from typing import Any

from sqlalchemy import Connection, Table, func, select, update
from sqlalchemy.sql.dml import Insert

from gyrolab.catalogue import schema
from gyrolab.catalogue.entries import (
    ApplicationEntry,
    ExportEntry,
    FlashEntry,
    ModelEntry,
    ReportEntry,
    RunEntry,
    UnitRef,
    VerificationEntry,
    utc_now,
)
from gyrolab.outputs import json_safe

HOST = socket.gethostname()


def _insert(conn: Connection, table: Table) -> Insert:
    if conn.dialect.name == "postgresql":
        from sqlalchemy.dialects.postgresql import insert
    else:
        from sqlalchemy.dialects.sqlite import insert
    return insert(table)  # type: ignore[no-any-return]


def upsert(
    conn: Connection,
    table: Table,
    values: dict[str, Any],
    key: Iterable[str],
    keep: Iterable[str] = (),
    fill: Iterable[str] = (),
) -> int:
    """Insert ``values``, or update the row with the same ``key``: every column but the
    key, the id and ``keep``; a ``fill`` column only where the new value is not NULL (what
    one command did not know — a model's unit, an export's model — never erases what
    another registered). The row's id."""
    key, keep, fill = list(key), set(keep), set(fill)
    stmt = _insert(conn, table).values(**values)
    ex = stmt.excluded  # type: ignore[attr-defined]
    changed: dict[str, Any] = {
        c: func.coalesce(ex[c], table.c[c]) if c in fill else ex[c]
        for c in values
        if c not in key and c not in keep and c != "id"
    }
    if not changed:  # still an update, so that RETURNING gives the existing row's id
        changed = {key[0]: ex[key[0]]}
    stmt = stmt.on_conflict_do_update(index_elements=key, set_=changed)  # type: ignore[attr-defined]
    return int(conn.execute(stmt.returning(table.c.id)).scalar_one())


def unit_id(conn: Connection, unit: UnitRef | None) -> int | None:
    """The unit's id, added if new; a part number given replaces an unknown one."""
    if unit is None or not unit.serial:
        return None
    t = schema.Unit.__table__
    stmt = _insert(conn, t).values(
        serial=unit.serial, part_number=unit.part_number or None, first_seen=utc_now()
    )
    ex = stmt.excluded  # type: ignore[attr-defined]
    stmt = stmt.on_conflict_do_update(  # type: ignore[attr-defined]
        index_elements=["serial"],
        set_={"part_number": func.coalesce(ex.part_number, t.c.part_number)},
    )
    return int(conn.execute(stmt.returning(t.c.id)).scalar_one())


def add_run(conn: Connection, e: RunEntry) -> int:
    """The run (by ``run_key``), its units, and the segment file; the run's outcome is its
    last segment's. Returns the run's id."""
    now = utc_now()
    run_id = upsert(
        conn,
        schema.Run.__table__,
        {
            "run_key": e.run_key,
            "source": e.source,
            "station": e.station,
            "operator": e.operator,
            "profile_name": e.profile_name,
            "profile": json_safe(e.profile),
            "simulated": e.simulated,
            "outcome": e.segment.outcome,
            "started_at": e.started_at,
            "registered_at": now,
        },
        key=["run_key"],
        keep=["started_at", "registered_at"],  # the first segment's start is the run's
    )
    for u in e.units:
        uid = unit_id(conn, u)
        stmt = _insert(conn, schema.RunUnit.__table__).values(run_id=run_id, unit_id=uid)
        conn.execute(stmt.on_conflict_do_nothing())  # type: ignore[attr-defined]
    s = e.segment
    upsert(
        conn,
        schema.Segment.__table__,
        {
            "run_id": run_id,
            "number": s.number,
            "file_hash": s.file_hash,
            "path": s.path,
            "size_bytes": s.size_bytes,
            "outcome": s.outcome,
            "outcome_line": s.outcome_line,
            "started_at": s.started_at,
            "host": HOST,
            "registered_at": now,
        },
        key=["file_hash"],
    )
    seg = schema.Segment.__table__
    last = (
        select(seg.c.outcome)
        .where(seg.c.run_id == run_id)
        .order_by(seg.c.number.desc(), seg.c.id.desc())
        .limit(1)
        .scalar_subquery()
    )
    run = schema.Run.__table__
    conn.execute(update(run).where(run.c.id == run_id).values(outcome=last))
    return run_id


def _values(conn: Connection, e: Any) -> dict[str, Any]:
    """An entry's columns: its unit as the unit's id (added if new), JSON made safe."""
    values = asdict(e)
    if "unit" in values:
        unit = values.pop("unit")
        values["unit_id"] = unit_id(conn, None if unit is None else UnitRef(**unit))
    for k in ("metrics", "detail", "target"):
        if k in values:
            values[k] = json_safe(values[k])
    return values


def add_model(conn: Connection, e: ModelEntry) -> int:
    values = _values(conn, e)
    also = values.pop("also")
    values["registered_at"] = utc_now()
    t = schema.Model.__table__
    fill = [c.name for c in t.columns if c.nullable]
    model_id = upsert(conn, t, values, key=["model_hash"], fill=fill)
    ta = schema.ModelAlsoRun.__table__
    for k, a in enumerate(also):  # the same model, the same runs: fill what was unknown
        stmt = _insert(conn, ta).values(model_id=model_id, position=k, **a)
        ex = stmt.excluded  # type: ignore[attr-defined]
        stmt = stmt.on_conflict_do_update(  # type: ignore[attr-defined]
            index_elements=["model_id", "position"],
            set_={c: func.coalesce(ex[c], ta.c[c]) for c in a},
        )
        conn.execute(stmt)
    return model_id


def add_export(conn: Connection, e: ExportEntry) -> int:
    (path, digest), *_ = e.files
    values = _values(conn, e)
    values.update(file_hash=digest, path=path, files=[{"path": p, "sha256": d} for p, d in e.files])
    t = schema.Export.__table__
    return upsert(conn, t, values, key=["file_hash"], keep=["created_at"], fill=["model_hash"])


def add_application(conn: Connection, e: ApplicationEntry) -> int:
    t = schema.Application.__table__
    values = _values(conn, e)
    models = values.pop("models")
    fill = ["model_hash", "run_file"]
    app_id = upsert(conn, t, values, key=["file_hash"], keep=["created_at"], fill=fill)
    tm = schema.ApplicationModel.__table__
    for h in models:  # the same file again: the same rows
        stmt = _insert(conn, tm).values(application_id=app_id, model_hash=h)
        conn.execute(stmt.on_conflict_do_nothing())  # type: ignore[attr-defined]
    return app_id


def add_flash(conn: Connection, e: FlashEntry) -> int:
    values = {**_values(conn, e), "host": HOST}
    fill = ["unit_id", "model_hash"]
    return upsert(conn, schema.Flash.__table__, values, key=["record_hash"], fill=fill)


def add_verification(conn: Connection, e: VerificationEntry) -> int:
    values = {**_values(conn, e), "host": HOST}
    fill = ["unit_id", "flash_record", "run_file"]
    return upsert(conn, schema.Verification.__table__, values, key=["record_hash"], fill=fill)


def add_report(conn: Connection, e: ReportEntry) -> int:
    fill = ["unit_id", "run_file", "model_hash", "spec", "verdict", "outcome"]
    t = schema.Report.__table__
    return upsert(conn, t, _values(conn, e), key=["report_hash"], keep=["created_at"], fill=fill)


WRITERS = {
    RunEntry: add_run,
    ModelEntry: add_model,
    ExportEntry: add_export,
    ApplicationEntry: add_application,
    FlashEntry: add_flash,
    VerificationEntry: add_verification,
    ReportEntry: add_report,
}
