"""Reading the catalogue: runs, one unit's rows, the trace, the models a fleet takes.

Everything comes back as plain dicts and lists (JSON-ready: times as ISO 8601 UTC with
``Z``), which ``gyrolab runs … --json`` prints as they are.
"""

from __future__ import annotations

import datetime as dt
from collections import defaultdict
from typing import Any

from sqlalchemy import Connection, Row, Table, func, select

from gyrolab.catalogue import schema

T_UNIT = schema.Unit.__table__
T_RUN = schema.Run.__table__
T_SEG = schema.Segment.__table__
T_RU = schema.RunUnit.__table__
T_MODEL = schema.Model.__table__
T_EXPORT = schema.Export.__table__
T_APP = schema.Application.__table__
T_APP_MODEL = schema.ApplicationModel.__table__
T_FLASH = schema.Flash.__table__
T_VER = schema.Verification.__table__
T_REPORT = schema.Report.__table__
T_ALSO = schema.ModelAlsoRun.__table__


def _iso(t: dt.datetime | None) -> str | None:
    return None if t is None else t.replace(microsecond=0).isoformat() + "Z"


def _row(r: Row[Any], drop: tuple[str, ...] = ("id",)) -> dict[str, Any]:
    out = {}
    for k, v in r._mapping.items():
        if k in drop:
            continue
        out[k] = _iso(v) if isinstance(v, dt.datetime) else v
    return out


def _segments(conn: Connection, run_ids: list[int]) -> dict[int, list[dict[str, Any]]]:
    out: dict[int, list[dict[str, Any]]] = defaultdict(list)
    if run_ids:
        q = select(T_SEG).where(T_SEG.c.run_id.in_(run_ids)).order_by(T_SEG.c.number, T_SEG.c.id)
        for r in conn.execute(q):
            out[r.run_id].append(_row(r, ("id", "run_id")))
    return out


def _serials(conn: Connection, run_ids: list[int]) -> dict[int, list[str]]:
    out: dict[int, list[str]] = defaultdict(list)
    if run_ids:
        q = (
            select(T_RU.c.run_id, T_UNIT.c.serial)
            .join(T_UNIT, T_UNIT.c.id == T_RU.c.unit_id)
            .where(T_RU.c.run_id.in_(run_ids))
            .order_by(T_UNIT.c.serial)
        )
        for run_id, serial in conn.execute(q):
            out[run_id].append(serial)
    return out


def list_runs(
    conn: Connection,
    serial: str | None = None,
    part_number: str | None = None,
    since: dt.datetime | None = None,
) -> list[dict[str, Any]]:
    """Every run (newest first), with its units and segments; filtered by a unit's serial,
    a part number (any of the run's units), and a start time (≥ ``since``, naive UTC; a run
    whose start is unknown counts by when it was registered)."""
    q = select(T_RUN)
    if serial is not None or part_number is not None:
        sub = select(T_RU.c.run_id).join(T_UNIT, T_UNIT.c.id == T_RU.c.unit_id)
        if serial is not None:
            sub = sub.where(T_UNIT.c.serial == serial)
        if part_number is not None:
            sub = sub.where(T_UNIT.c.part_number == part_number)
        q = q.where(T_RUN.c.id.in_(sub))
    if since is not None:
        started = T_RUN.c.started_at
        q = q.where((started >= since) | (started.is_(None) & (T_RUN.c.registered_at >= since)))
    rows = conn.execute(q.order_by(T_RUN.c.started_at.desc(), T_RUN.c.id.desc())).all()
    ids = [r.id for r in rows]
    segs, serials = _segments(conn, ids), _serials(conn, ids)
    out = []
    for r in rows:
        d = _row(r)
        d["units"] = serials[r.id]
        d["segments"] = segs[r.id]
        out.append(d)
    return out


def _by(
    conn: Connection,
    table: Table,
    column: str,
    values: list[Any],
    drop: tuple[str, ...] = ("id",),
) -> list[dict[str, Any]]:
    if not values:
        return []
    names = ("created_at", "path", "record_path", "id")  # the same order however registered
    order = [table.c[n] for n in names if n in table.c]
    q = select(table).where(table.c[column].in_(values)).order_by(*order)
    return [_row(r, drop) for r in conn.execute(q)]


def _also(conn: Connection, model_ids: list[int]) -> dict[int, list[dict[str, Any]]]:
    """Each model's ``--also`` runs, in order (file hash, data hash, path)."""
    out: dict[int, list[dict[str, Any]]] = defaultdict(list)
    if model_ids:
        q = select(T_ALSO).where(T_ALSO.c.model_id.in_(model_ids))
        for r in conn.execute(q.order_by(T_ALSO.c.model_id, T_ALSO.c.position)):
            out[r.model_id].append(_row(r, ("model_id", "position")))
    return out


def _applications(conn: Connection, model_hashes: list[str]) -> list[dict[str, Any]]:
    """The compensated recordings of these models, each with ``models``: every model it
    applied (one, or one per unit of a multi-unit run: ``application_models``)."""
    if not model_hashes:
        return []
    q = select(T_APP_MODEL).where(T_APP_MODEL.c.model_hash.in_(model_hashes))
    linked = [r.application_id for r in conn.execute(q)]
    rows = _by(conn, T_APP, "model_hash", model_hashes, drop=()) + _by(
        conn, T_APP, "id", linked, drop=()
    )
    apps = {a["id"]: a for a in rows}
    models: dict[int, set[str]] = defaultdict(set)
    if apps:
        q = select(T_APP_MODEL).where(T_APP_MODEL.c.application_id.in_(list(apps)))
        for r in conn.execute(q):
            models[r.application_id].add(r.model_hash)
    out = []
    for i, a in sorted(apps.items(), key=lambda kv: (kv[1]["created_at"], kv[1]["path"], kv[0])):
        a.pop("id")
        a["models"] = sorted(models[i] | ({a["model_hash"]} if a["model_hash"] else set()))
        out.append(a)
    return out


def unit(conn: Connection, serial: str) -> dict[str, Any] | None:
    """Everything registered about one unit, table by table (None: not in the catalogue)."""
    u = conn.execute(select(T_UNIT).where(T_UNIT.c.serial == serial)).first()
    if u is None:
        return None
    runs = list_runs(conn, serial=serial)
    run_files = [s["file_hash"] for r in runs for s in r["segments"]]
    # the unit's models, and the models fitted, also fitted (compensate --also) or
    # validated on its runs (another serial's) — not those of the other units of a
    # multi-unit run, fitted on the same file but theirs
    units_of_file = {s["file_hash"]: set(r["units"]) for r in runs for s in r["segments"]}
    serials = sorted(set().union(*units_of_file.values())) if units_of_file else []
    q = select(T_UNIT.c.id, T_UNIT.c.serial).where(T_UNIT.c.serial.in_(serials))
    serial_of = {r.id: r.serial for r in conn.execute(q)}

    def theirs(m: dict[str, Any], file: str | None) -> bool:
        owner = serial_of.get(m["unit_id"])
        return owner not in (None, serial) and owner in units_of_file.get(file or "", ())

    model_rows = _by(conn, T_MODEL, "unit_id", [u.id], drop=())
    for column in ("calibration_file", "validation_file"):
        rows = _by(conn, T_MODEL, column, run_files, drop=())
        model_rows += [m for m in rows if not theirs(m, m[column])]
    if run_files:
        q = select(T_ALSO.c.model_id, T_ALSO.c.file_hash).where(T_ALSO.c.file_hash.in_(run_files))
        also_file = {r.model_id: r.file_hash for r in conn.execute(q)}
        rows = _by(conn, T_MODEL, "id", list(also_file), drop=())
        model_rows += [m for m in rows if not theirs(m, also_file[m["id"]])]
    models: dict[str, dict[str, Any]] = {}
    for m in model_rows:
        models.setdefault(m["model_hash"], m)
    also = _also(conn, [m["id"] for m in models.values()])
    for m in models.values():
        m["also"] = also.get(m.pop("id"), [])
    model_hashes = list(models)
    # the unit's reports, and the reports of its models (on another unit's run too)
    reports = {r["report_hash"]: r for r in _by(conn, T_REPORT, "unit_id", [u.id])}
    for r in _by(conn, T_REPORT, "run_file", run_files):
        if r["unit_id"] in (None, u.id):  # not another unit's of a multi-unit run
            reports.setdefault(r["report_hash"], r)
    for r in _by(conn, T_REPORT, "model_hash", model_hashes):
        reports.setdefault(r["report_hash"], r)
    flashes = {f["record_hash"]: f for f in _by(conn, T_FLASH, "unit_id", [u.id])}
    for f in _by(conn, T_FLASH, "model_hash", model_hashes):
        if f["unit_id"] in (None, u.id):
            flashes.setdefault(f["record_hash"], f)
    return {
        "unit": _row(u, drop=()),
        "runs": runs,
        "models": list(models.values()),
        "exports": _by(conn, T_EXPORT, "model_hash", model_hashes),
        "applications": _applications(conn, model_hashes),
        "flashes": list(flashes.values()),
        "verifications": _by(conn, T_VER, "unit_id", [u.id]),
        "reports": list(reports.values()),
    }


def trace(conn: Connection, serial: str) -> dict[str, Any] | None:
    """The unit → its runs → the models fitted (or validated) on them → their exports →
    the flashes of those parameters → the verification verdicts; reports beside the run
    and the model they are of. ``verdict``: the latest verification's, else the latest
    report's with a spec, else None."""
    d = unit(conn, serial)
    if d is None:
        return None
    flashes_of: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for f in d["flashes"]:
        f["verifications"] = [
            v for v in d["verifications"] if v["flash_record"] == f["record_hash"]
        ]
        flashes_of[f["params_hash"]].append(f)
    exports_of: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for e in d["exports"]:
        e["flashes"] = flashes_of.get(e["file_hash"], [])
        exports_of[e["model_hash"]].append(e)
    apps_of: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for a in d["applications"]:
        for h in a["models"]:  # one model, or one per unit of a multi-unit run
            apps_of[h].append(a)
    reports = d["reports"]
    exported = {e["file_hash"] for e in d["exports"]}
    flashed_from: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for f in d["flashes"]:
        if f["params_hash"] not in exported and f["model_hash"]:
            flashed_from[f["model_hash"]].append(f)  # flashed from the model, no export file
    for m in d["models"]:
        m["flashes"] = flashed_from.get(m["model_hash"], [])
        m["exports"] = exports_of.get(m["model_hash"], [])
        m["applications"] = apps_of.get(m["model_hash"], [])
        m["reports"] = [r for r in reports if r["model_hash"] == m["model_hash"]]
    placed: set[str] = set()
    for run in d["runs"]:
        files = {s["file_hash"] for s in run["segments"]}
        run["models"] = []
        for m in d["models"]:
            role = (
                "calibration"
                if m["calibration_file"] in files
                else "validation"
                if m["validation_file"] in files
                else "also"  # compensate --also: the causal model's other power-on
                if any(a["file_hash"] in files for a in m["also"])
                else None
            )
            if role is not None:
                run["models"].append({"role": role, **m})
                placed.add(m["model_hash"])
        run["reports"] = [r for r in reports if r["run_file"] in files and not r["model_hash"]]
    orphans = [m for m in d["models"] if m["model_hash"] not in placed]
    verifications = sorted(d["verifications"], key=lambda v: v["created_at"] or "")
    with_spec = sorted((r for r in reports if r["verdict"]), key=lambda r: r["created_at"] or "")
    verdict = (
        {"verdict": verifications[-1]["verdict"], "from": "verification"}
        if verifications
        else {"verdict": with_spec[-1]["verdict"], "from": "report"}
        if with_spec
        else None
    )
    return {
        "unit": d["unit"],
        "runs": d["runs"],
        "models_without_run": orphans,
        "unlinked_verifications": [v for v in verifications if not v["flash_record"]],
        "verdict": verdict,
    }


def fleet_models(
    conn: Connection, part_number: str | None = None, since: dt.datetime | None = None
) -> list[dict[str, Any]]:
    """Per unit (of ``part_number``, with a run since ``since``), its latest registered
    model: ``serial``, ``path``, ``model_hash`` (units without a model are left out)."""
    serials = {s for r in list_runs(conn, part_number=part_number, since=since) for s in r["units"]}
    if part_number is not None and since is None:  # units with models but no run registered
        q = select(T_UNIT.c.serial).where(T_UNIT.c.part_number == part_number)
        serials |= set(conn.execute(q).scalars())
    out = []
    for serial in sorted(serials):
        q = (
            select(T_MODEL.c.path, T_MODEL.c.model_hash)
            .join(T_UNIT, T_UNIT.c.id == T_MODEL.c.unit_id)
            .where(T_UNIT.c.serial == serial)
            .order_by(
                func.coalesce(T_MODEL.c.created_at, T_MODEL.c.registered_at).desc(),
                T_MODEL.c.id.desc(),
            )
            .limit(1)
        )
        m = conn.execute(q).first()
        if m is not None:
            out.append({"serial": serial, "path": m.path, "model_hash": m.model_hash})
    return out
