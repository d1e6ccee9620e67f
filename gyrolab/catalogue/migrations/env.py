"""Alembic environment of the catalogue: run on the connection the catalogue opened.

:func:`gyrolab.catalogue.store.upgrade` hands its connection (inside its transaction, under
its lock) in ``config.attributes["connection"]``; there is no ``alembic.ini``.
"""

from __future__ import annotations

from alembic import context

from gyrolab.catalogue.schema import Base

connection = context.config.attributes["connection"]
context.configure(
    connection=connection,
    target_metadata=Base.metadata,
    render_as_batch=connection.dialect.name == "sqlite",  # SQLite alters by table copy
    compare_type=True,
)
with context.begin_transaction():
    context.run_migrations()
