"""Exceptions shared by the instrument drivers.

The profile runner catches :class:`InstrumentError` (and its subclasses) from any driver,
logs it, and decides whether to retry or go to the safe state.
"""

from __future__ import annotations


class InstrumentError(Exception):
    """An instrument refused, failed or reported an error."""

    def __init__(self, instrument: str, message: str) -> None:
        self.instrument = instrument
        super().__init__(f"{instrument}: {message}")


class InstrumentTimeout(InstrumentError):
    """No (complete) reply within the timeout: communication lost or instrument busy."""


class LimitError(InstrumentError, ValueError):
    """A requested setting is outside the configured safety limits; nothing was sent."""
