"""Instrument roles: what the run engine needs from each instrument, and one error vocabulary.

A bench has three roles (docs/instruments.md, "Roles and drivers"):

* :class:`Thermometer` — the PT100 reader (a 4-wire multimeter): ``read()`` gives a
  :class:`ThermometerReading`.
* :class:`Chamber` — the temperature chamber's controller: ``set_setpoint()`` (limits
  checked before any byte is sent, verified by read-back), ``read()`` gives a
  :class:`ChamberReading`, and where the driver can, ``switch_off()`` (verified).
* :class:`RateStream` — the gyro's ADC stream.

Every driver registered in :mod:`gyrolab.instruments.registry` implements one role itself
(no adapters) and says who it is with ``describe()`` (into the recording's ``bench``
metadata).

Errors (one vocabulary, :func:`is_transient`): a driver raises

* :class:`~gyrolab.instruments.errors.InstrumentError` (or an ``OSError`` /
  ``TimeoutError`` from the transport) for a failed exchange — **transient**: the runner
  logs it and retries at the next poll, until ``comm_timeout_s`` says the instrument is
  lost;
* :class:`~gyrolab.instruments.errors.LimitError` for a setting outside the configured
  limits (nothing was sent) — **never retried**: the run stops, chamber to the safe state;
* :class:`InstrumentFault` for a condition the instrument reports that must end the run
  (a sensor fault) — **never retried**.

Anything else a driver lets escape (a ``TypeError``, a ``KeyError``) is a bug or a
condition nobody anticipated, and is treated as fatal too: a run must not go on retrying
what it does not understand with a chamber under power.
"""

from __future__ import annotations

from typing import Any, NamedTuple, Protocol

from gyrolab.instruments.errors import InstrumentError, InstrumentReport, LimitError


class InstrumentFault(Exception):
    """An instrument reports a condition that must end the run (not a transient error)."""


def is_transient(exc: BaseException) -> bool:
    """Whether a driver's exception may be retried: a failed exchange, not a refused
    setting (:class:`LimitError`), not a fault (:class:`InstrumentFault`), not a bug."""
    if isinstance(exc, (LimitError, InstrumentFault)):
        return False
    return isinstance(exc, (InstrumentError, OSError, TimeoutError))


class ThermometerReading(NamedTuple):
    """One 4-wire PT100 reading: ``resistance_ohm`` (Ω) and ``temperature_c`` (°C)."""

    resistance_ohm: float
    temperature_c: float


class ChamberReading(NamedTuple):
    """The controller's ``setpoint_c`` and its ``process_value_c`` (chamber air, °C)."""

    setpoint_c: float
    process_value_c: float


class Instrument(Protocol):
    """What every role has: a name in the recording, identity, reports, close."""

    # The bench's name for the instrument (the recording's source: "multimeter", "oven",
    # "adc"); set by the registry when it opens the driver.
    name: str

    def describe(self) -> dict[str, Any]:
        """Identity and settings for the ``bench`` metadata (model, idn, serial …)."""
        ...

    def reports(self) -> list[InstrumentReport]:
        """Errors the instrument itself reported since the last call."""
        ...

    def close(self) -> None: ...


class Thermometer(Instrument, Protocol):
    """The PT100 reader."""

    def read(self) -> ThermometerReading:
        """One reading; raises on a failed reading (see :func:`is_transient`)."""
        ...


class Chamber(Instrument, Protocol):
    """The temperature chamber's controller."""

    def set_setpoint(self, setpoint_c: float) -> Any:
        """Command and verify a setpoint; :class:`LimitError` (nothing sent) outside the
        configured limits; raises on failure."""
        ...

    def read(self) -> ChamberReading:
        """Setpoint and process value; raises on failure (:class:`InstrumentFault` when
        the controller reports it cannot control the chamber)."""
        ...

    # Drivers that can switch the chamber off also have ``switch_off()`` (heater and
    # refrigerator off, verified by read-back), used by ``[safe_state] mode = "off"``.


class RateStream(Instrument, Protocol):
    """The gyro's ADC stream (:class:`gyrolab.instruments.gyro_adc.GyroAdcReader`)."""

    def read(self, timeout_s: float) -> Any:
        """Intact samples received so far (an ``AdcRead``: blocks, gaps, events)."""
        ...

    def counters(self) -> dict[str, int]:
        """Running totals: at least ``frames_ok``, ``frames_bad`` and ``frames_lost``."""
        ...
