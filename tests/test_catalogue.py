"""The catalogue (docs/catalogue.md) on SQLite and on a real PostgreSQL server.

Every test that takes ``catalogue`` runs twice: on an SQLite file and on a database of a
PostgreSQL server the tests start themselves (``tests/pgserver.py``; skipped, saying why,
where the server binaries are absent — CI installs them). Covered: the migrations build
exactly the schema; registering is idempotent and never erases what another command knew;
two stations (processes) writing at once lose and duplicate nothing; the demo's units are
listed and traced run → model → export; ``rebuild`` recreates the same index from the
files; a catalogue that cannot be reached never fails a command (one warning); the
command-line errors are one line, exit 2.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pgserver
import pytest
from sqlalchemy import func, select
from test_demo import demo_catalogue_file, make_demo

from gyrolab.app import register as reg
from gyrolab.app.demo import demo_catalogue
from gyrolab.catalogue import Catalogue, CatalogueError, schema
from gyrolab.catalogue.entries import (
    AlsoRunRef,
    ApplicationEntry,
    ExportEntry,
    FlashEntry,
    ModelEntry,
    RunEntry,
    SegmentEntry,
    UnitRef,
    VerificationEntry,
)
from gyrolab.catalogue.store import HEAD, catalogue_url, default_path
from gyrolab.cli import main
from gyrolab.record.reader import read_metadata

REPO = Path(__file__).resolve().parents[1]
VOLATILE = ("registered_at", "first_seen", "id", "unit_id", "host")


@pytest.fixture(scope="session")
def pg_server() -> Iterator[str]:
    reason = pgserver.why_not()
    if reason is not None:
        pytest.skip(reason)
    with pgserver.postgres_server() as url:
        yield url


_databases = iter(range(1, 10_000))


@pytest.fixture(params=["sqlite", "postgresql"])
def catalogue(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    """A new, empty catalogue's URL: an SQLite file, or a database on the test server."""
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'catalogue.sqlite'}"
    server = request.getfixturevalue("pg_server")
    return pgserver.create_database(server, f"catalogue_{next(_databases)}")


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The session's demo (tests/test_demo.py makes it once), registered as it ran in the
    session's catalogue (conftest: $GYROLAB_CATALOGUE)."""
    return make_demo(tmp_path_factory)


def run_cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    rc = main(args)
    out, err = capsys.readouterr()
    return rc, out, err


def strip(x: Any) -> Any:
    """A catalogue dump without what differs from one registration to another."""
    if isinstance(x, dict):
        return {k: strip(v) for k, v in x.items() if k not in VOLATILE}
    if isinstance(x, list):
        return [strip(v) for v in x]
    return x


def counts(url: str) -> dict[str, int]:
    cat = Catalogue.open(url)
    try:
        with cat.engine.connect() as conn:
            return {
                t.name: conn.execute(select(func.count()).select_from(t)).scalar_one()
                for t in schema.Base.metadata.sorted_tables
            }
    finally:
        cat.close()


# ------------------------------------------------------------------ where it lives


def test_url_from_option_environment_or_default(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("GYROLAB_CATALOGUE", raising=False)
    monkeypatch.setenv("XDG_DATA_HOME", "/data/x")
    assert default_path() == Path("/data/x/gyrolab/catalogue.sqlite")
    assert catalogue_url() == "sqlite:////data/x/gyrolab/catalogue.sqlite"
    monkeypatch.setenv("GYROLAB_CATALOGUE", "postgresql://lab@db/gyro")
    assert catalogue_url() == "postgresql://lab@db/gyro"
    assert catalogue_url("cat.sqlite") == f"sqlite:///{Path.cwd() / 'cat.sqlite'}"
    monkeypatch.setenv("GYROLAB_CATALOGUE", "off")
    assert catalogue_url() is None


def test_demo_registers_inside_its_directory_unless_told(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.delenv("GYROLAB_CATALOGUE", raising=False)
    assert demo_catalogue(tmp_path, None) == f"sqlite:///{tmp_path / 'catalogue.sqlite'}"
    assert demo_catalogue(tmp_path, "x.sqlite") == f"sqlite:///{Path.cwd() / 'x.sqlite'}"
    monkeypatch.setenv("GYROLAB_CATALOGUE", "postgresql://lab@db/gyro")
    assert demo_catalogue(tmp_path, None) == "postgresql://lab@db/gyro"


# ------------------------------------------------------------------ schema and writes


def test_migrations_build_the_schema(catalogue: str) -> None:
    """Opening a new catalogue applies the migrations (shipped in the package), which
    build exactly the tables of schema.py; HEAD is Alembic's head."""
    from alembic.autogenerate import compare_metadata
    from alembic.config import Config
    from alembic.migration import MigrationContext
    from alembic.script import ScriptDirectory

    from gyrolab.catalogue.store import MIGRATIONS, current_revision

    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS))
    assert ScriptDirectory.from_config(cfg).get_current_head() == HEAD
    cat = Catalogue.open(catalogue)
    try:
        with cat.engine.connect() as conn:
            assert current_revision(conn) == HEAD
            diff = compare_metadata(MigrationContext.configure(conn), schema.Base.metadata)
            assert diff == []
    finally:
        cat.close()


def _run(key: str, file: str, *units: UnitRef, number: int = 1, outcome: str = "complete"):
    return RunEntry(
        run_key=key,
        source="acquire",
        station="bench-2",
        operator="ana",
        profile_name="short",
        profile={"name": "short", "step": [{"setpoint_c": 25.0}]},
        simulated=False,
        units=list(units),
        segment=SegmentEntry(file, f"/runs/{file[-4:]}.mcap", 1000, number, outcome),
    )


def test_registration_is_idempotent_and_keeps_what_others_knew(catalogue: str) -> None:
    cat = Catalogue.open(catalogue)
    try:
        # a run interrupted, then resumed: two segments of one run, the outcome the last's
        cat.add(_run("run-1", "sha256:f001", UnitRef("SN1", "G7"), outcome="interrupted"))
        cat.add(_run("run-1", "sha256:f002", UnitRef("SN1"), number=2))
        cat.add(_run("run-1", "sha256:f002", UnitRef("SN1"), number=2))  # again: no new row
        model = ModelEntry("sha256:m1", "/models/m1", UnitRef("SN1"), "sha256:f001")
        cat.add(model)
        # an export registers the model again without knowing its unit or runs
        cat.add(ModelEntry("sha256:m1", "/models/m1", None))
        cat.add(ExportEntry("sha256:m1", "px4", {"instance": 0}, [("/x/m.params", "sha256:e1")]))
        (run,) = cat.runs()
        assert run["outcome"] == "complete" and [s["number"] for s in run["segments"]] == [1, 2]
        unit = cat.unit("SN1")
        assert unit is not None and unit["unit"]["part_number"] == "G7"  # not erased
        (m,) = unit["models"]
        assert m["calibration_file"] == "sha256:f001" and m["unit_id"] is not None
    finally:
        cat.close()
    c = counts(catalogue)
    assert (c["runs"], c["segments"], c["units"], c["models"], c["exports"]) == (1, 2, 1, 1, 1)


def test_a_units_models_are_not_the_other_units_of_its_multi_unit_run(catalogue: str) -> None:
    """Two units tested at once (one file), a model each: each unit shows its own model;
    a model of another unit validated on a unit's own single-unit run still shows there."""
    cat = Catalogue.open(catalogue)
    try:
        cat.add(_run("run-m", "sha256:fm01", UnitRef("SA", "G7"), UnitRef("SB", "G7")))
        cat.add(_run("run-b", "sha256:fb01", UnitRef("SB", "G7")))
        cat.add(ModelEntry("sha256:ma", "/models/A", UnitRef("SA"), "sha256:fm01", "sha256:fb01"))
        cat.add(ModelEntry("sha256:mb", "/models/B", UnitRef("SB"), "sha256:fm01"))
        for serial, paths in (("SA", ["/models/A"]), ("SB", ["/models/A", "/models/B"])):
            unit = cat.unit(serial)
            assert unit is not None
            assert sorted(m["path"] for m in unit["models"]) == paths, serial
    finally:
        cat.close()


def test_a_copy_that_applied_a_model_per_unit_is_under_each_model(catalogue: str) -> None:
    """`apply DIR MULTI` registers one copy with every unit's model (revision 0003): each
    unit sees it under its own model; registering it again adds no row."""
    cat = Catalogue.open(catalogue)
    try:
        cat.add(_run("run-m", "sha256:fm02", UnitRef("SA", "G7"), UnitRef("SB", "G7")))
        cat.add(ModelEntry("sha256:ma", "/models/SA", UnitRef("SA"), "sha256:fm02"))
        cat.add(ModelEntry("sha256:mb", "/models/SB", UnitRef("SB"), "sha256:fm02"))
        app = ApplicationEntry(None, "sha256:fm02", "sha256:c1", "/c/all.mcap")
        app.models = ["sha256:ma", "sha256:mb"]
        cat.add(app)
        cat.add(app)
        for serial, h in (("SA", "sha256:ma"), ("SB", "sha256:mb")):
            unit = cat.unit(serial)
            assert unit is not None
            (a,) = unit["applications"]
            assert a["path"] == "/c/all.mcap" and a["models"] == ["sha256:ma", "sha256:mb"]
            t = cat.trace(serial)
            assert t is not None
            (m,) = t["runs"][0]["models"]
            assert m["model_hash"] == h and [x["path"] for x in m["applications"]] == [
                "/c/all.mcap"
            ]
    finally:
        cat.close()
    c = counts(catalogue)
    assert (c["applications"], c["application_models"]) == (1, 2)


def test_flash_and_verification_complete_the_trace(catalogue: str) -> None:
    """The flight-controller commands' API: a flash of an export's parameters, and the
    verification verdict of that flash, end the trace."""
    cat = Catalogue.open(catalogue)
    try:
        cat.add(_run("run-9", "sha256:f009", UnitRef("SN9", "G7")))
        cat.add(ModelEntry("sha256:m9", "/models/m9", UnitRef("SN9"), "sha256:f009"))
        cat.add(ExportEntry("sha256:m9", "px4", {}, [("/x/m9.params", "sha256:e9")]))
        cat.add(
            FlashEntry("sha256:r1", "/x/flash.json", UnitRef("SN9"), "sha256:e9", "fc-1", "written")
        )
        cat.add(
            VerificationEntry("sha256:r2", "/x/verify.json", UnitRef("SN9"), "PASS", "sha256:r1")
        )
        t = cat.trace("SN9")
    finally:
        cat.close()
    assert t is not None
    (model,) = t["runs"][0]["models"]
    (export,) = model["exports"]
    (flash,) = export["flashes"]
    assert flash["device"] == "fc-1" and flash["verifications"][0]["verdict"] == "PASS"
    assert t["verdict"] == {"verdict": "PASS", "from": "verification"}


def test_a_models_also_run_is_traced_and_registering_again_fills_it(catalogue: str) -> None:
    """``compensate --also`` (revision 0002): the model hangs under its calibration run and
    under the cold start it was also fitted on; a second registration that knows the file
    fills the hash the first did not know, and erases nothing."""
    cat = Catalogue.open(catalogue)
    try:
        cat.add(_run("run-a", "sha256:fa01", UnitRef("SNA", "G7")))
        cat.add(_run("run-b", "sha256:fb02", UnitRef("SNA", "G7")))
        blind = AlsoRunRef(None, "blake2b-160:cc", "cold.mcap")
        cat.add(ModelEntry("sha256:ma", "/m/a", UnitRef("SNA"), "sha256:fa01", also=[blind]))
        (m,) = cat.unit("SNA")["models"]
        assert m["also"] == [
            {"file_hash": None, "data_hash": "blake2b-160:cc", "path": "cold.mcap"}
        ]
        known = AlsoRunRef("sha256:fb02", None, None)
        cat.add(ModelEntry("sha256:ma", "/m/a", UnitRef("SNA"), None, also=[known]))
        t = cat.trace("SNA")
    finally:
        cat.close()
    assert t is not None
    roles = {r["run_key"]: [m["role"] for m in r["models"]] for r in t["runs"]}
    assert roles == {"run-a": ["calibration"], "run-b": ["also"]}
    (m,) = t["runs"][1]["models"]
    assert m["also"] == [
        {"file_hash": "sha256:fb02", "data_hash": "blake2b-160:cc", "path": "cold.mcap"}
    ]
    assert m["calibration_file"] == "sha256:fa01"  # kept: the second did not know it


def test_a_catalogue_at_revision_0001_is_upgraded_keeping_its_rows(tmp_path: Path) -> None:
    """A catalogue written by a gyrolab before ``--also`` (revision 0001) is migrated to
    the head when opened, its models kept (with no ``--also`` runs)."""
    from alembic import command
    from alembic.config import Config
    from sqlalchemy import create_engine

    from gyrolab.catalogue.store import MIGRATIONS, current_revision

    url = f"sqlite:///{tmp_path / 'old.sqlite'}"
    engine = create_engine(url)
    with engine.begin() as conn:
        cfg = Config()
        cfg.set_main_option("script_location", str(MIGRATIONS))
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, "0001")
        assert current_revision(conn) == "0001"
        conn.exec_driver_sql(
            "INSERT INTO models (model_hash, path, held_out, axes, metrics, registered_at) "
            "VALUES ('sha256:old', '/m/old', 0, 1, '{}', '2026-11-26 10:00:00')"
        )
    engine.dispose()
    cat = Catalogue.open(url)
    try:
        with cat.engine.connect() as conn:
            assert current_revision(conn) == HEAD
            rows = conn.execute(select(schema.Model.__table__.c.model_hash)).all()
            also = conn.execute(select(func.count()).select_from(schema.ModelAlsoRun)).scalar()
    finally:
        cat.close()
    assert [r[0] for r in rows] == ["sha256:old"] and also == 0


def test_parameters_flashed_from_a_model_hang_under_it(catalogue: str) -> None:
    """A flash of a model's parameters with no export file (the flight-controller command
    writes the model's set itself) is traced model → flash → verification."""
    cat = Catalogue.open(catalogue)
    try:
        cat.add(_run("run-8", "sha256:f008", UnitRef("SN8")))
        cat.add(ModelEntry("sha256:m8", "/models/m8", UnitRef("SN8"), "sha256:f008"))
        flash = FlashEntry(
            "sha256:r8", "/x/flash.json", UnitRef("SN8"), "sha256:set8", "fc-2", "written",
            model_hash="sha256:m8",
        )  # fmt: skip
        cat.add(flash)
        cat.add(VerificationEntry("sha256:v8", "/x/v.json", UnitRef("SN8"), "FAIL", "sha256:r8"))
        t = cat.trace("SN8")
    finally:
        cat.close()
    assert t is not None
    (model,) = t["runs"][0]["models"]
    assert model["exports"] == [] and model["flashes"][0]["device"] == "fc-2"
    assert model["flashes"][0]["verifications"][0]["verdict"] == "FAIL"
    assert t["verdict"] == {"verdict": "FAIL", "from": "verification"}


WRITER = """
import sys, time
from pathlib import Path
from gyrolab.catalogue import Catalogue
from gyrolab.catalogue.entries import ModelEntry, RunEntry, SegmentEntry, UnitRef
url, station, n, scratch = sys.argv[1], sys.argv[2], int(sys.argv[3]), Path(sys.argv[4])
(scratch / f"ready-{station}").touch()
while not (scratch / "go").exists():
    time.sleep(0.01)
cat = Catalogue.open(url)  # both open the new catalogue at once: it is migrated once
def run(key, file, units):
    seg = SegmentEntry(file, f"/runs/{file}.mcap", 100, 1, "complete")
    return RunEntry(key, "acquire", station, "op", "short", {}, False, units, seg)
for k in range(n):
    units = [UnitRef(f"SN{k % 5}", "G7"), UnitRef(f"SN{(k + 1) % 5}")]
    cat.add(run(f"shared-{k}", f"sha256:shared{k}", units))  # both stations register it
    cat.add(run(f"{station}-{k}", f"sha256:{station}{k}", units))
    cat.add(ModelEntry(f"sha256:model{k}", f"/m/{k}", UnitRef(f"SN{k % 5}"), f"sha256:shared{k}"))
cat.close()
"""


def test_two_stations_writing_at_once(catalogue: str, tmp_path: Path) -> None:
    n = 20
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", WRITER, catalogue, s, str(n), str(tmp_path)],
            env=env,
            stderr=subprocess.PIPE,
            text=True,
        )
        for s in ("a", "b")
    ]
    deadline = time.monotonic() + 60
    while not all((tmp_path / f"ready-{s}").exists() for s in "ab"):
        assert time.monotonic() < deadline and all(p.poll() is None for p in procs)
        time.sleep(0.01)
    (tmp_path / "go").touch()
    for p in procs:
        _out, err = p.communicate(timeout=120)
        assert p.returncode == 0, err
    c = counts(catalogue)
    assert c["units"] == 5
    assert c["runs"] == 3 * n and c["segments"] == 3 * n and c["run_units"] == 2 * 3 * n
    assert c["models"] == n


# ------------------------------------------------------------------ the demo, end to end


def _demo_units(demo: Path) -> set[str]:
    units = set()
    for name in ("calibration.mcap", "heldout.mcap"):
        run = read_metadata(demo / name)["run"]
        units.add(run["unit_serial"])
    return units


def _check_demo(demo: Path, args: list[str], capsys: pytest.CaptureFixture[str]) -> dict[str, Any]:
    """The demo's units are listed, and each one's trace goes run → model → export."""
    rc, out, _ = run_cli(["runs", "list", "--json", *args], capsys)
    assert rc == 0
    runs = [r for r in json.loads(out) if r["segments"][0]["path"].startswith(str(demo))]
    assert {u for r in runs for u in r["units"]} == _demo_units(demo)
    traces = {}
    for serial in _demo_units(demo):
        rc, out, _ = run_cli(["runs", "trace", serial, "--json", *args], capsys)
        assert rc == 0
        t = json.loads(out)
        models = [m for r in t["runs"] for m in r["models"] if m["path"] == str(demo / "model")]
        assert models, serial
        exports = {Path(e["path"]).name for e in models[0]["exports"]}
        assert exports == {"gyro_comp.c", "ardupilot.parm"}
        reports = [r["path"] for m in models for r in m["reports"]]
        assert str(demo / "report") in reports
        traces[serial] = t
        rc, text, _ = run_cli(["runs", "trace", serial, *args], capsys)
        assert "model" in text and "export c" in text and "export ardupilot" in text
    return traces


def test_demo_units_listed_and_traced(demo: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The demo registered itself, in the catalogue it was told (test_demo.make_demo: its
    own, which no other test writes, so this holds in any order of the tests)."""
    _check_demo(demo, ["--catalogue", str(demo_catalogue_file(demo))], capsys)


def test_rebuild_recreates_the_demo(
    demo: Path, catalogue: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """An empty catalogue rebuilt from the demo's files holds what the demo registered;
    a second rebuild changes nothing."""
    rc, out, _ = run_cli(["runs", "rebuild", str(demo), "--catalogue", catalogue], capsys)
    assert rc == 0 and "registered 2 runs, 1 models, 2 exports" in out
    before = counts(catalogue)
    assert run_cli(["runs", "rebuild", str(demo), "--catalogue", catalogue], capsys)[0] == 0
    assert counts(catalogue) == before
    _check_demo(demo, ["--catalogue", catalogue], capsys)


def test_same_index_on_sqlite_and_postgresql(
    demo: Path, pg_server: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    traces = []
    for url in (
        f"sqlite:///{tmp_path / 'c.sqlite'}",
        pgserver.create_database(pg_server, f"catalogue_{next(_databases)}"),
    ):
        assert run_cli(["runs", "rebuild", str(demo), "--catalogue", url], capsys)[0] == 0
        traces.append(strip(_check_demo(demo, ["--catalogue", url], capsys)))
    assert traces[0] == traces[1]


def test_commands_register_what_rebuild_finds(
    demo: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """What compensate, export and report register (from the paths they were given) is
    what rebuild finds again in the files."""
    by_commands, rebuilt = (f"sqlite:///{tmp_path / n}.sqlite" for n in ("a", "b"))
    cal, held, model = demo / "calibration.mcap", demo / "heldout.mcap", demo / "model"
    assert reg.register_models([model], cal, held, url=by_commands)
    for name, fmt in (("gyro_comp.c", "c"), ("ardupilot.parm", "ardupilot")):
        files = [demo / "firmware" / name]
        if fmt == "c":
            files.append(files[0].with_suffix(".h"))
        target = {"instance": 0, "kind": "chosen"} if fmt == "c" else {"instance": 0}
        assert reg.register_export(model, fmt, target, files, url=by_commands)
    assert reg.register_report(demo / "report", held, model, url=by_commands)
    assert reg.register_report(demo / "calibration-report", cal, url=by_commands)
    assert run_cli(["runs", "rebuild", str(demo), "--catalogue", rebuilt], capsys)[0] == 0
    traces = [
        strip(_check_demo(demo, ["--catalogue", url], capsys)) for url in (by_commands, rebuilt)
    ]
    assert traces[0] == traces[1]


def test_fleet_takes_its_units_from_the_catalogue(
    demo: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cat = tmp_path / "c.sqlite"
    assert run_cli(["runs", "rebuild", str(demo), "--catalogue", str(cat)], capsys)[0] == 0
    pn = read_metadata(demo / "calibration.mcap")["run"]["unit_model"]
    out = tmp_path / "fleet"
    args = ["fleet", "--part-number", pn, "--since", "2000-01-01", "--catalogue", str(cat)]
    assert run_cli([*args, "--out", str(out)], capsys)[0] == 0
    rows = json.loads((out / "fleet.json").read_text())
    assert rows["n_units"] == 1
    rc, _, err = run_cli(["fleet", "--part-number", "nope", "--catalogue", str(cat),
                          "--out", str(tmp_path / "f2")], capsys)  # fmt: skip
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "no unit" in err


# ------------------------------------------------------------------ never stops a command


def test_unreachable_catalogue_warns_once_and_rebuild_registers_later(
    demo: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import socket

    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    monkeypatch.setenv("GYROLAB_CATALOGUE", f"postgresql://gyrolab@127.0.0.1:{port}/none")
    monkeypatch.setattr(reg, "_warned", [])
    for k, (fmt, name) in enumerate((("json", "m.json"), ("ardupilot", "m.parm"))):
        out = tmp_path / name
        rc, _, err = run_cli(
            ["export", str(demo / "model"), "--format", fmt, "--out", str(out)], capsys
        )
        assert rc == 0 and out.is_file()
        warnings = [line for line in err.splitlines() if "warning: not registered" in line]
        assert len(warnings) == (1 if k == 0 else 0)  # once per process
    cat = tmp_path / "later.sqlite"
    assert run_cli(["runs", "rebuild", str(tmp_path), "--catalogue", str(cat)], capsys)[0] == 0
    assert counts(f"sqlite:///{cat}")["exports"] == 2


def test_acquire_with_unreachable_catalogue_completes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A catalogue on a path that cannot be created (under a file): the acquisition runs to
    the end and exits 0, with one warning; ``rebuild`` registers the run later."""
    from simruns import three_step_profile

    (tmp_path / "file").write_text("")
    monkeypatch.setenv("GYROLAB_CATALOGUE", str(tmp_path / "file" / "c.sqlite"))
    monkeypatch.setattr(reg, "_warned", [])
    profile = tmp_path / "p.toml"
    profile.write_text(three_step_profile("tiny").replace("320", "30"))
    run = tmp_path / "runs" / "run.mcap"
    run.parent.mkdir()
    rc, _, err = run_cli(
        ["acquire", "--bench", "sim", "--profile", str(profile), "--speed", "200",
         "--out", str(run)], capsys)  # fmt: skip
    assert rc == 0 and run.is_file()
    assert sum("warning: not registered" in line for line in err.splitlines()) == 1
    cat = tmp_path / "c.sqlite"
    assert run_cli(["runs", "rebuild", str(run.parent), "--catalogue", str(cat)], capsys)[0] == 0
    cat_ = Catalogue.open(str(cat))
    try:
        (r,) = cat_.runs()
    finally:
        cat_.close()
    assert r["outcome"] == "complete" and r["source"] == "acquire"
    assert r["units"] == ["SIM-GYRO-0001"]


def _segment_file(path: Path, segment: int, t0: float, events: list[tuple[float, str]]) -> None:
    """A small recording: segment ``segment`` of run ``r1`` (the run record's keys of a
    resumed run, docs/recording-format.md), 10 s of rate and PT100 from ``t0``."""
    import numpy as np

    from gyrolab.record.writer import RecordingWriter

    run = {"source": "acquire", "profile": {"name": "p"}, "run_id": "r1", "segment": segment,
           "unit_serial": "SN5", "unit_model": "G7", "bench_name": "bench-1"}  # fmt: skip
    if segment > 1:  # a continuation names the segment it continues, beside it
        run["previous_segment"] = {"file": f"seg{segment - 1}.mcap", "segment": segment - 1,
                                   "run_id": "r1"}  # fmt: skip
        run["resumed"] = {"after_t": 9.0, "at_t": t0, "step": 0}
    w = RecordingWriter(path, start_time_ns=1_700_000_000 * 10**9, run=run, bench={"name": "b"})
    for t, event in events:
        w.write_event(t, event, 0, None, "")
    for k in range(0, 1000, 50):
        counts = np.arange(k, k + 50, dtype=np.int32)
        w.write_rate_block(t0 + k / 100, 0.01, int(t0 * 100) + k, counts * 1e-3)
        w.write_pt100(t0 + k / 100, 110.0, 25.0)
    w.close()


def test_a_resumed_run_is_one_run_of_its_segments(catalogue: str, tmp_path: Path) -> None:
    """Two files of one run (run id, segment 1 then 2): one run, two segments, the run's
    outcome the last segment's."""
    _segment_file(tmp_path / "seg1.mcap", 1, 0.0, [(0.0, "run_started"), (9.0, "aborted")])
    _segment_file(tmp_path / "seg2.mcap", 2, 40.0, [(40.0, "run_resumed"), (49.0, "run_ended")])
    assert main(["runs", "rebuild", str(tmp_path), "--catalogue", catalogue]) == 0
    cat = Catalogue.open(catalogue)
    try:
        (run,) = cat.runs()
    finally:
        cat.close()
    assert run["run_key"] == "r1" and run["units"] == ["SN5"] and run["station"] == "bench-1"
    assert [(s["number"], Path(s["path"]).name) for s in run["segments"]] == [
        (1, "seg1.mcap"),
        (2, "seg2.mcap"),
    ]
    assert run["outcome"] == "complete"


def test_rebuild_skips_a_damaged_recording(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "broken.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 64)
    rc, out, err = run_cli(
        ["runs", "rebuild", str(tmp_path), "--catalogue", str(tmp_path / "c.sqlite")], capsys
    )
    assert rc == 1 and "skipped: " in err and "broken.mcap" in err and "1 skipped" in out


# ------------------------------------------------------------------ errors: one line, exit 2


@pytest.mark.parametrize(
    "args, words",
    [
        (["runs", "trace", "NO-SUCH-UNIT"], "no such unit"),
        (["runs", "list", "--since", "yesterday"], "not an ISO 8601"),
        (["runs", "list", "--catalogue", "mysql://x@y/z"], "SQLite or PostgreSQL"),
        (["runs", "rebuild", "/no/such/dir"], "not a directory"),
    ],
)
def test_errors_are_one_line(
    args: list[str], words: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    if "--catalogue" not in args:
        args = [*args, "--catalogue", str(tmp_path / "c.sqlite")]
    rc, _, err = run_cli(args, capsys)
    assert rc == 2 and len(err.strip().splitlines()) == 1 and words in err


def test_newer_schema_is_refused(tmp_path: Path) -> None:
    from sqlalchemy import text

    url = f"sqlite:///{tmp_path / 'c.sqlite'}"
    Catalogue.open(url).close()
    cat = Catalogue.open(url)
    with cat.engine.begin() as conn:
        conn.execute(text("UPDATE alembic_version SET version_num = '9999'"))
    cat.close()
    with pytest.raises(CatalogueError, match="newer than this gyrolab"):
        Catalogue.open(url)
