"""Exceptions shared by the instrument drivers.

The profile runner catches :class:`InstrumentError` (and its subclasses) from any driver,
logs it, and decides whether to retry or go to the safe state.
"""

from __future__ import annotations

from dataclasses import dataclass


class InstrumentError(Exception):
    """An instrument refused, failed or reported an error."""

    def __init__(self, instrument: str, message: str) -> None:
        self.instrument = instrument
        super().__init__(f"{instrument}: {message}")


class InstrumentTimeout(InstrumentError):
    """No (complete) reply within the timeout: communication lost or instrument busy."""


class LimitError(InstrumentError, ValueError):
    """A requested setting is outside the configured safety limits; nothing was sent."""


@dataclass(frozen=True)
class InstrumentReport:
    """An error the instrument itself reported (not a transport failure): an entry of a
    SCPI error queue (``SYST:ERR?``) or a Modbus exception response.

    The runner logs each to ``/log`` as level ``fault`` with ``code`` and ``text``;
    ``fatal`` ones end the run (oven to the safe state), the others let it continue.
    ``error_class`` names the class the decision was taken on (docs/instruments.md,
    "Errors the instruments report").
    """

    protocol: str  # "SCPI" | "Modbus"
    code: int
    text: str
    error_class: str
    fatal: bool
    context: str = ""  # the command or transaction it came with

    def message(self, instrument: str) -> str:
        action = "run stopped" if self.fatal else "run continues"
        ctx = f" ({self.context})" if self.context else ""
        code = f"{self.code:+d}" if self.protocol == "SCPI" else f"{self.code:02d}"
        return (
            f"{instrument} reported {self.protocol} error {code} "
            f'"{self.text}"{ctx}: {self.error_class}; {action}'
        )

    def data(self) -> dict[str, object]:
        return {
            "protocol": self.protocol,
            "code": self.code,
            "text": self.text,
            "error_class": self.error_class,
            "fatal": self.fatal,
            "context": self.context,
        }
