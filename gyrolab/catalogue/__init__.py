"""The catalogue: an index of every unit, run, model, export, flash and verdict.

Commands register what they wrote (``gyrolab/app/register.py``); ``gyrolab runs`` reads it
(docs/catalogue.md). It is an index of the files, never the only copy: ``gyrolab runs
rebuild DIR`` recreates it from them.

    from gyrolab.catalogue import Catalogue
    with Catalogue.open() as cat:          # --catalogue / $GYROLAB_CATALOGUE / default file
        cat.add(entry)                     # any entry of gyrolab.catalogue.entries
        cat.trace("SN0001")

Layout: ``store.py`` (where it lives, opening it, migrations on open), ``schema.py`` (the
tables), ``entries.py`` (what a command registers), ``write.py`` / ``read.py``, ``digest.py``
(the file hashes that key everything), ``migrations/`` (Alembic).
"""

from __future__ import annotations

import datetime as dt
from typing import Any

from sqlalchemy import Engine

from gyrolab.catalogue import read, write
from gyrolab.catalogue.store import CatalogueError, catalogue_url, connect, shown


class Catalogue:
    """An open catalogue (its schema at the head revision)."""

    def __init__(self, engine: Engine, url: str) -> None:
        self.engine = engine
        self.url = url

    @classmethod
    def open(cls, url: str | None = None) -> Catalogue:
        """The catalogue at ``url`` (a URL or an SQLite file; default: :func:`catalogue_url`),
        migrated on open.
        Raises :class:`CatalogueError` when registration is off or it cannot be reached."""
        from sqlalchemy.exc import SQLAlchemyError

        target = catalogue_url(url)
        if target is None:
            raise CatalogueError("the catalogue is off (GYROLAB_CATALOGUE=off)")
        try:
            return cls(connect(target), target)
        except SQLAlchemyError as e:
            raise CatalogueError(f"catalogue {shown(target)}: {_reason(e)}") from None

    def close(self) -> None:
        self.engine.dispose()

    def __enter__(self) -> Catalogue:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def add(self, entry: Any) -> int:
        """Register one entry (one transaction); its row's id."""
        writer = write.WRITERS[type(entry)]
        with self.engine.begin() as conn:
            return writer(conn, entry)

    def runs(
        self,
        serial: str | None = None,
        part_number: str | None = None,
        since: dt.datetime | None = None,
    ) -> list[dict[str, Any]]:
        with self.engine.connect() as conn:
            return read.list_runs(conn, serial, part_number, since)

    def unit(self, serial: str) -> dict[str, Any] | None:
        with self.engine.connect() as conn:
            return read.unit(conn, serial)

    def trace(self, serial: str) -> dict[str, Any] | None:
        with self.engine.connect() as conn:
            return read.trace(conn, serial)

    def fleet_models(
        self, part_number: str | None = None, since: dt.datetime | None = None
    ) -> list[dict[str, Any]]:
        with self.engine.connect() as conn:
            return read.fleet_models(conn, part_number, since)


def _reason(e: Exception) -> str:
    """The first line of a database error, without SQLAlchemy's background link."""
    text = str(getattr(e, "orig", None) or e).strip().splitlines()
    return text[0] if text else type(e).__name__


__all__ = ["Catalogue", "CatalogueError", "catalogue_url"]
