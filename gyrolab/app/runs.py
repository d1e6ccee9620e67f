"""``gyrolab runs list|show|trace|rebuild``: reading the catalogue, and rebuilding it.

``list`` prints the runs (newest first) with their units; ``show SERIAL`` everything
registered about a unit; ``trace SERIAL`` the chain unit → runs → model → exported or
flashed parameters → verification verdict. ``--json`` prints the same as JSON (the
structures of :mod:`gyrolab.catalogue.read`). ``rebuild DIR...`` registers every file under
the directories (:mod:`gyrolab.app.rebuild`). Errors (no catalogue, an unknown serial, a bad
``--since``) are one line, exit 2 (docs/catalogue.md).
"""

from __future__ import annotations

import datetime as dt
import json
import sys
from pathlib import Path
from typing import Any

from gyrolab.app.options import RunsOptions
from gyrolab.catalogue import Catalogue
from gyrolab.catalogue.digest import short
from gyrolab.catalogue.entries import parse_time
from gyrolab.catalogue.store import CatalogueError, catalogue_url, shown
from gyrolab.errors import InputError


def parse_since(text: str | None) -> dt.datetime | None:
    """``--since``: an ISO 8601 date or time (UTC unless it says otherwise)."""
    if text is None:
        return None
    t = parse_time(text)
    if t is None:
        raise InputError("--since", f"{text!r} is not an ISO 8601 date or time (2026-11-26)")
    return t


def open_catalogue(url: str | None) -> Catalogue:
    target = catalogue_url(url)
    if target is None:
        raise CatalogueError("the catalogue is off (GYROLAB_CATALOGUE=off): give --catalogue")
    return Catalogue.open(target)


def _print_json(obj: Any) -> None:
    print(json.dumps(obj, indent=2, ensure_ascii=False))


def _when(t: str | None) -> str:
    return (t or "—").replace("T", " ").removesuffix("Z")


def runs_list(
    url: str | None,
    serial: str | None = None,
    part_number: str | None = None,
    since: str | None = None,
    as_json: bool = False,
) -> int:
    with open_catalogue(url) as cat:
        runs = cat.runs(serial, part_number, parse_since(since))
    if as_json:
        _print_json(runs)
        return 0
    print(
        f"{'started (UTC)':<20} {'station':<10} {'operator':<18} {'profile':<10} "
        f"{'outcome':<11} seg  units"
    )
    for r in runs:
        print(
            f"{_when(r['started_at']):<20} {r['station'][:10]:<10} {r['operator'][:18]:<18} "
            f"{r['profile_name'][:10]:<10} {r['outcome']:<11} {len(r['segments']):>3}  "
            + ", ".join(r["units"])
        )
    print(f"{len(runs)} run(s)", file=sys.stderr)
    return 0


def _unit_or_error(cat: Catalogue, serial: str, what: dict[str, Any] | None) -> dict[str, Any]:
    if what is None:
        raise InputError(serial, f"no such unit in the catalogue {shown(cat.url)}")
    return what


def runs_show(url: str | None, serial: str, as_json: bool = False) -> int:
    with open_catalogue(url) as cat:
        d = _unit_or_error(cat, serial, cat.unit(serial))
    if as_json:
        _print_json(d)
        return 0
    u = d["unit"]
    print(
        f"unit {u['serial']}  part number {u['part_number'] or '—'}  first seen "
        f"{_when(u['first_seen'])}"
    )
    for key in ("runs", "models", "exports", "applications", "flashes", "verifications", "reports"):
        print(f"{key}: {len(d[key])}")
        for row in d[key]:
            path = row.get("path") or row.get("record_path") or ""
            digest = (
                (row.get("model_hash") if key == "models" else None)
                or row.get("file_hash")
                or row.get("report_hash")
                or row.get("record_hash")
            )
            if key == "runs":  # a run is its segment files
                path = ", ".join(s["path"] for s in row["segments"])
                digest = row["segments"][0]["file_hash"] if row["segments"] else None
            extra = (
                row.get("verdict")
                or row.get("outcome")
                or row.get("result")
                or row.get("format")
                or row.get("family")
                or ""
            )
            print(f"  {short(digest)}  {extra:<10} {path}")
    return 0


def _metric(m: dict[str, Any]) -> str:
    """The headline a model's trace line shows: causal drift p-p (100 s) when known."""
    metrics = m.get("metrics") or {}
    pp = (metrics.get("drift_pp_100s_deg_per_s") or {}).get("causal")
    return f", causal drift p-p {pp:.3g} deg/s" if isinstance(pp, (int, float)) else ""


def trace_lines(t: dict[str, Any]) -> list[str]:
    """The trace as an indented tree (one line per thing)."""
    u = t["unit"]
    lines = [f"unit {u['serial']} (part number {u['part_number'] or '—'})"]
    calibrated = {
        m["model_hash"] for r in t["runs"] for m in r["models"] if m["role"] == "calibration"
    }

    def model_lines(m: dict[str, Any], pad: str) -> None:
        held = "held out" if m.get("held_out") else "in sample"
        role = f"{m['role']} " if m.get("role") else ""
        lines.append(
            f"{pad}model {short(m['model_hash'])} ({role}{m.get('family') or '—'}, "
            f"{held}{_metric(m)}) {m['path']}"
        )
        if m.get("role") in ("validation", "also") and m["model_hash"] in calibrated:
            return  # its exports are shown under its calibration run
        for e in m["exports"]:
            lines.append(f"{pad}  export {e['format']} {short(e['file_hash'])} {e['path']}")
            for f in e["flashes"]:
                lines.append(
                    f"{pad}    flash {f['result']} to {f['device']} {_when(f['created_at'])}"
                )
                for v in f["verifications"]:
                    lines.append(f"{pad}      verification {v['verdict']} {_when(v['created_at'])}")
        for f in m["flashes"]:
            lines.append(f"{pad}  flash {f['result']} to {f['device']} {_when(f['created_at'])}")
            for v in f["verifications"]:
                lines.append(f"{pad}    verification {v['verdict']} {_when(v['created_at'])}")
        for a in m["applications"]:
            lines.append(f"{pad}  applied {short(a['file_hash'])} {a['path']}")
        for r in m["reports"]:
            lines.append(f"{pad}  report {r['verdict'] or r['outcome'] or '—'} {r['path']}")

    for r in t["runs"]:
        segs = ", ".join(f"{s['number']}: {s['path']}" for s in r["segments"])
        lines.append(
            f"  run {_when(r['started_at'])} {r['station']} / {r['operator']}, "
            f"profile {r['profile_name']}: {r['outcome']} [{segs}]"
        )
        for m in r["models"]:
            model_lines(m, "    ")
        for rep in r["reports"]:
            lines.append(f"    report {rep['verdict'] or rep['outcome'] or '—'} {rep['path']}")
    if t["models_without_run"]:
        lines.append("  (models whose calibration run is not in the catalogue)")
        for m in t["models_without_run"]:
            model_lines(m, "    ")
    for v in t["unlinked_verifications"]:
        lines.append(f"  verification {v['verdict']} {_when(v['created_at'])} (no flash named)")
    v = t["verdict"]
    lines.append(
        f"verdict: {v['verdict']} (from the latest {v['from']})" if v else "verdict: none recorded"
    )
    return lines


def runs_trace(url: str | None, serial: str, as_json: bool = False) -> int:
    with open_catalogue(url) as cat:
        t = _unit_or_error(cat, serial, cat.trace(serial))
    if as_json:
        _print_json(t)
    else:
        print("\n".join(trace_lines(t)))
    return 0


def catalogue_models(url: str | None, part_number: str | None, since: str | None) -> list[str]:
    """``fleet --part-number/--since``: each matching unit's latest registered model
    directory (one line, exit 2 when there is none, or one is no longer there)."""
    when = parse_since(since)
    with open_catalogue(url) as cat:
        models = cat.fleet_models(part_number, when)
        where = shown(cat.url)
    if not models:
        what = " and ".join(
            x
            for x in (part_number and f"part number {part_number}", since and f"since {since}")
            if x
        )
        raise InputError(where, f"no unit with a registered model ({what})")
    from gyrolab.compensation.model_dir import ModelDir

    for m in models:
        if not ModelDir.is_model_dir(m["path"]):
            raise InputError(
                m["path"],
                f"unit {m['serial']}'s model is registered here but no longer there "
                "(gyrolab runs rebuild DIR where it is now)",
            )
    return [m["path"] for m in models]


def runs_rebuild(url: str | None, dirs: list[str]) -> int:
    """Register every file under ``dirs``; prints the counts and what was skipped (exit 0
    when something was registered or nothing was there, 1 when any file was skipped)."""
    from gyrolab.app.rebuild import rebuild_entries

    found = [rebuild_entries(d) for d in dirs]  # every DIR checked before anything is written
    with open_catalogue(url) as cat:
        for r in found:
            for entry in r.entries:
                cat.add(entry)
        where = shown(cat.url)
    skipped = [s for r in found for s in r.skipped]
    counts: dict[str, int] = {}
    for r in found:
        for k, n in r.counts.items():
            counts[k] = counts.get(k, 0) + n
    for path, reason in skipped:
        print(f"gyrolab: skipped: {path}: {reason}", file=sys.stderr)
    what = ", ".join(f"{n} {k}" for k, n in counts.items()) or "nothing"
    print(
        f"registered {what} from {', '.join(str(Path(d)) for d in dirs)} in {where}"
        + (f"; {len(skipped)} skipped" if skipped else "")
    )
    return 1 if skipped else 0


def runs(opts: RunsOptions) -> int:
    """The ``gyrolab runs`` command (module docstring)."""
    if opts.action == "list":
        return runs_list(opts.catalogue, opts.unit, opts.part_number, opts.since, opts.json)
    if opts.action in ("show", "trace"):
        assert opts.serial is not None  # the parser requires it
        call = runs_show if opts.action == "show" else runs_trace
        return call(opts.catalogue, opts.serial, opts.json)
    return runs_rebuild(opts.catalogue, [str(d) for d in opts.dirs])
