"""SCPI error-queue parsing shared by the SCPI drivers (34401A, 34465A, …).

``SYST:ERR?`` answers ``<code>,"<text>"`` (``+0,"No error"`` when the queue is empty);
the code's class (SCPI-99 / IEEE 488.2) decides whether the run may go on
(docs/instruments.md, "Errors the instruments report").
"""

from __future__ import annotations

import re

from gyrolab.instruments.roles import InstrumentReport

ERROR_REPLY = re.compile(r"^\s*([+-]?\d+)\s*,\s*\"?(.*?)\"?\s*$")


def parse_error_reply(reply: str) -> tuple[int, str] | None:
    """``(code, text)`` of one ``SYST:ERR?`` reply; ``None`` when it is not one."""
    m = ERROR_REPLY.match(reply)
    return (int(m.group(1)), m.group(2)) if m else None


def scpi_error_class(code: int) -> tuple[str, bool]:
    """``(class, fatal)`` of a SCPI error-queue code, by the SCPI-99 / IEEE 488.2 classes.

    * −100…−199 command errors, −200…−299 execution errors, −400…−499 query errors: a
      message the meter refused or could not answer; the meter itself is sound and each
      reading is still checked on its own (``READ?`` parse, overload) → the run continues;
    * −300…−399 device-specific errors (−310 system error, −311 memory error, −330
      self-test failed, …): the meter reports its own malfunction, its readings can no
      longer be trusted → the run stops (oven to the safe state). Except −350 "queue
      overflow", which only says that later errors were dropped → continues;
    * positive codes: instrument-specific (on the 34401A: interface, self-test and
      calibration errors, User's Guide ch. 5), not classified here → logged, continues.
    """
    if -199 <= code <= -100:
        return "command error", False
    if -299 <= code <= -200:
        return "execution error", False
    if code == -350:
        return "error queue overflow", False
    if -399 <= code <= -300:
        return "device-specific error", True
    if -499 <= code <= -400:
        return "query error", False
    return "instrument-specific error", False


def scpi_reports(errors: list[tuple[int, str]], context: str = "") -> list[InstrumentReport]:
    """Error-queue entries ``[(code, text)]`` as :class:`InstrumentReport` s."""
    out = []
    for code, text in errors:
        cls, fatal = scpi_error_class(code)
        out.append(InstrumentReport("SCPI", code, text, cls, fatal, context))
    return out
