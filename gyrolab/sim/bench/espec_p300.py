"""Simulated ESPEC P-300 / SCP-220 chamber controller: its ASCII command set on TCP.

ESPEC's controllers speak a line protocol of their own (not SCPI, though SCPI-like):
commands and replies end in CR LF; a query returns comma-separated fields; a setting
returns ``OK: <command>``; a refused command returns ``NA:<reason>`` (``NA:CMD ERR``,
``NA:DATA OUT OF RANGE`` …). The subset here is what ``gyrolab`` uses, with the reply
layouts of ESPEC North America's ChamberConnectLibrary (``p300.py``, ``especinteract.py``;
docs/instruments.md):

=================  ==============================================================
``ROM?``           firmware version
``TYPE?``          ``<sensor>,<controller>,<max temp>`` (temperature-only chamber)
``TEMP?``          ``<PV>,<SP>,<upper limit>,<lower limit>``
``TEMP, S<x>``     set the temperature setpoint (°C, one decimal)
``MODE?``          ``OFF`` | ``STANDBY`` | ``CONSTANT`` | ``RUN``
``MODE, <m>``      ``CONSTANT`` (control on), ``STANDBY`` (control stopped), ``OFF``
``MON?``           ``<PV>,<humidity or empty>,<mode>,<number of alarms>``
=================  ==============================================================

Physics: in ``CONSTANT`` the chamber follows the setpoint; in ``STANDBY``/``OFF`` its
heater and refrigerator stop, modelled as the chamber settling to ``ambient_c``. An alarm
(:meth:`EspecP300.set_alarm`, the ``chamber_alarm`` fault) stops the chamber (``MODE?``
reads ``STANDBY``, ``MON?`` counts it) and keeps heater and refrigerator off while it is
active; once it has cleared the chamber stays stopped until ``MODE, CONSTANT``.
"""

from __future__ import annotations

import re
import threading
from collections.abc import Callable
from dataclasses import dataclass

from gyrolab.sim.identities import ESPEC_P300_ROM, ESPEC_P300_TYPE

LIMITS_C = (-75.0, 200.0)  # the controller's own setpoint range (TEMP? fields 3-4)
MODES = ("OFF", "STANDBY", "CONSTANT", "RUN")


@dataclass
class ChamberHooks:
    chamber_c: Callable[[], float]
    set_setpoint: Callable[[float], None]
    ambient_c: float


class EspecP300:
    """The controller's interpreter: ``handle(line)`` → reply line."""

    def __init__(self, hooks: ChamberHooks, setpoint_c: float | None = None) -> None:
        self.hooks = hooks
        self.mode = "STANDBY"
        self.setpoint_c = hooks.ambient_c if setpoint_c is None else float(setpoint_c)
        self.alarms = 0
        self.log: list[str] = []  # every command received, for tests
        self._lock = threading.Lock()

    def _apply(self) -> None:
        on = self.mode in ("CONSTANT", "RUN") and not self.alarms
        self.hooks.set_setpoint(self.setpoint_c if on else self.hooks.ambient_c)

    def set_alarm(self, on: bool) -> None:
        """An alarm trips (``on``: the chamber stops) or clears."""
        with self._lock:
            self.alarms = 1 if on else 0
            if on:
                self.mode = "STANDBY"
            self._apply()

    def handle(self, line: str) -> str:
        with self._lock:
            self.log.append(line)
            return self._handle(line.strip())

    def _handle(self, cmd: str) -> str:
        u = cmd.upper()
        if u == "ROM?":
            return ESPEC_P300_ROM
        if u == "TYPE?":
            return ESPEC_P300_TYPE
        if u == "TEMP?":
            return (
                f"{self.hooks.chamber_c():.1f},{self.setpoint_c:.1f},"
                f"{LIMITS_C[1]:.1f},{LIMITS_C[0]:.1f}"
            )
        if u == "MODE?":
            return self.mode
        if u == "MON?":
            return f"{self.hooks.chamber_c():.1f},,{self.mode},{self.alarms}"
        m = re.fullmatch(r"TEMP\s*,\s*S\s*([-+]?\d+(?:\.\d*)?)", u)
        if m:
            v = float(m.group(1))
            if not LIMITS_C[0] <= v <= LIMITS_C[1]:
                return "NA:DATA OUT OF RANGE"
            self.setpoint_c = round(v, 1)
            self._apply()
            return f"OK: {cmd}"
        m = re.fullmatch(r"MODE\s*,\s*(\w+)", u)
        if m:
            if m.group(1) not in ("OFF", "STANDBY", "CONSTANT"):
                return "NA:PARA ERR"
            self.mode = m.group(1)
            self._apply()
            return f"OK: {cmd}"
        return "NA:CMD ERR"
