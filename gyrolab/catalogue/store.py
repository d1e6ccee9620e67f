"""Where the catalogue lives, opening it (migrations applied on open), and its one lock.

* :func:`catalogue_url`: ``--catalogue`` if given, else ``$GYROLAB_CATALOGUE``, else the
  embedded SQLite file :func:`default_path` (``$XDG_DATA_HOME/gyrolab/catalogue.sqlite``,
  ``~/.local/share/gyrolab/catalogue.sqlite`` by default). A value is a SQLAlchemy URL
  (``sqlite:////abs/path.sqlite``, ``postgresql://user@host/db``) or a plain file path (an
  SQLite file); ``off`` turns registration off.
* :func:`connect`: an engine on the URL with the catalogue's schema brought to the head
  revision first. Every transaction on SQLite is ``BEGIN IMMEDIATE`` (writers take the
  file's write lock at the start and wait up to :data:`BUSY_TIMEOUT_S` for one another, so
  a get-or-create never races); on PostgreSQL the migration runs under a transaction-level
  advisory lock and the writes are ``INSERT … ON CONFLICT`` (``tables.py``). Two stations
  opening a new catalogue at once therefore migrate it once.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from sqlalchemy import Connection, Engine, create_engine, event, inspect, text
from sqlalchemy.engine import URL, make_url
from sqlalchemy.exc import ArgumentError

from gyrolab.errors import GyrolabError

ENV = "GYROLAB_CATALOGUE"
OFF = "off"
#: The head revision of ``migrations/versions`` (a test checks it is Alembic's head):
#: compared before Alembic is imported, so opening an up-to-date catalogue stays cheap.
HEAD = "0003"
BUSY_TIMEOUT_S = 60.0
CONNECT_TIMEOUT_S = 5  # an unreachable server costs a command at most this, then a warning
#: pg_advisory_xact_lock key of the migration ("gyrolab!" as a big-endian int64).
MIGRATION_LOCK = int.from_bytes(b"gyrolab!", "big")
MIGRATIONS = Path(__file__).with_name("migrations")


class CatalogueError(GyrolabError):
    """The catalogue cannot be used (bad URL, unreachable, newer schema): one line."""


def default_path() -> Path:
    """The embedded catalogue: ``$XDG_DATA_HOME/gyrolab/catalogue.sqlite``
    (``~/.local/share/gyrolab/catalogue.sqlite`` when XDG_DATA_HOME is unset)."""
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "gyrolab" / "catalogue.sqlite"


def catalogue_url(option: str | None = None) -> str | None:
    """The catalogue's URL from ``option``, else ``$GYROLAB_CATALOGUE``, else the default
    file; ``None`` when set to ``off`` (nothing is registered)."""
    value = option if option else os.environ.get(ENV, "").strip()
    if not value:
        return sqlite_url(default_path())
    if value.lower() == OFF:
        return None
    if "://" in value:
        return value
    return sqlite_url(Path(value))


def sqlite_url(path: str | os.PathLike[str]) -> str:
    """``sqlite:///`` URL of a file (absolute, so a later change of directory keeps it)."""
    return f"sqlite:///{Path(path).expanduser().absolute()}"


def shown(url: str) -> str:
    """``url`` for messages: an SQLite file as its path, any password hidden."""
    try:
        u = make_url(url)
    except ArgumentError:
        return url
    if u.get_backend_name() == "sqlite" and u.database and u.database != ":memory:":
        return u.database
    return u.render_as_string(hide_password=True)


def _sqlite_engine(u: URL) -> Engine:
    if u.database and u.database != ":memory:":
        Path(u.database).parent.mkdir(parents=True, exist_ok=True)
    engine = create_engine(u, connect_args={"timeout": BUSY_TIMEOUT_S})

    # pysqlite's own transaction handling defers BEGIN to the first write, which lets two
    # writers read, then both try to write (one fails). SQLAlchemy's documented recipe:
    # no implicit BEGIN from the driver, and an explicit BEGIN IMMEDIATE per transaction.
    @event.listens_for(engine, "connect")
    def _connect(dbapi_connection: Any, _record: Any) -> None:
        dbapi_connection.isolation_level = None
        dbapi_connection.execute("PRAGMA foreign_keys = ON")

    @event.listens_for(engine, "begin")
    def _begin(conn: Connection) -> None:
        conn.exec_driver_sql("BEGIN IMMEDIATE")

    return engine


def make_engine(url: str) -> Engine:
    """An engine on ``url`` (SQLite with the locking above; PostgreSQL through psycopg 3)."""
    try:
        u = make_url(url)
    except ArgumentError as e:
        raise CatalogueError(f"catalogue {url!r}: not a database URL ({e})") from None
    backend = u.get_backend_name()
    if backend == "sqlite":
        return _sqlite_engine(u)
    if backend == "postgresql":
        if u.drivername == "postgresql":
            u = u.set(drivername="postgresql+psycopg")
        try:
            return create_engine(
                u, pool_pre_ping=True, connect_args={"connect_timeout": CONNECT_TIMEOUT_S}
            )
        except ModuleNotFoundError as e:
            raise CatalogueError(
                f"catalogue {shown(url)}: the PostgreSQL driver is not installed ({e.name}; "
                "pip install 'gyrolab[postgresql]')"
            ) from None
    raise CatalogueError(f"catalogue {shown(url)}: SQLite or PostgreSQL URLs only")


def current_revision(conn: Connection) -> str | None:
    """The schema revision recorded in the database (None: no catalogue there yet)."""
    if not inspect(conn).has_table("alembic_version"):
        return None
    return conn.execute(text("SELECT version_num FROM alembic_version")).scalar()


def upgrade(conn: Connection) -> None:
    """Bring the schema to the head revision on ``conn``, inside its transaction."""
    from alembic import command
    from alembic.config import Config
    from alembic.script import ScriptDirectory

    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS))
    cfg.attributes["connection"] = conn
    found = current_revision(conn)
    known = {s.revision for s in ScriptDirectory.from_config(cfg).walk_revisions()}
    if found is not None and found not in known:
        raise CatalogueError(
            f"catalogue at schema revision {found}, newer than this gyrolab knows "
            f"({HEAD}): upgrade gyrolab"
        )
    command.upgrade(cfg, "head")


def connect(url: str) -> Engine:
    """An engine on the catalogue at ``url``, its schema migrated to :data:`HEAD`."""
    engine = make_engine(url)
    with engine.begin() as conn:
        if conn.dialect.name == "postgresql":
            conn.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": MIGRATION_LOCK})
        # SQLite: BEGIN IMMEDIATE already holds the write lock
        if current_revision(conn) != HEAD:
            upgrade(conn)
    return engine
