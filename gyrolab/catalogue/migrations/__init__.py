"""Alembic migrations of the catalogue (applied on open: gyrolab.catalogue.store)."""
