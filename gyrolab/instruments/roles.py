"""Instrument roles: what the run engine needs from each instrument, and one error vocabulary.

A bench has three roles (docs/instruments.md, "Roles and drivers"), and a multi-unit bench
a fourth:

* :class:`Thermometer` — the PT100 reader (a 4-wire multimeter): ``read()`` gives a
  :class:`ThermometerReading`.
* :class:`Chamber` — the temperature chamber's controller: ``set_setpoint()`` (limits
  checked before any byte is sent, verified by read-back), ``read()`` gives a
  :class:`ChamberReading`, and where the driver can, ``switch_off()`` (verified).
* :class:`RateStream` — the gyro's ADC stream: ``read()`` gives an :class:`AdcRead` of
  gap-free :class:`AdcBlock` s; its config satisfies :class:`RateStreamConfig`.
* :class:`MultiThermometer` — a scanning multimeter reading one PT100 per unit through a
  multiplexer: ``read()`` gives one :class:`ThermometerReading` per scanned channel.

Every driver registered in :mod:`gyrolab.instruments.registry` implements one role itself
(no adapters) and says who it is with ``describe()`` (into the recording's ``bench``
metadata).

Errors (one vocabulary, :func:`is_transient`): a driver raises

* :class:`InstrumentError` (or an ``OSError`` /
  ``TimeoutError`` from the transport) for a failed exchange — **transient**: the runner
  logs it and retries at the next poll, until ``comm_timeout_s`` says the instrument is
  lost;
* :class:`LimitError` for a setting outside the configured
  limits (nothing was sent) — **never retried**: the run stops, chamber to the safe state;
* :class:`InstrumentFault` for a condition the instrument reports that must end the run
  (a sensor fault) — **never retried**.

Anything else a driver lets escape (a ``TypeError``, a ``KeyError``) is a bug or a
condition nobody anticipated, and is treated as fatal too: a run must not go on retrying
what it does not understand with a chamber under power.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol

import numpy as np

from gyrolab.framing import Gap


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
    """The controller's ``setpoint_c`` and its ``process_value_c`` (chamber air, °C), and
    ``alarm``: what the chamber reports of an alarm (or an open door) that stops it, where
    the driver can tell ("" when none). The run engine decides what an alarm does: it holds
    the run (a suspender) or ends it (gyrolab/acquisition/suspend.py)."""

    setpoint_c: float
    process_value_c: float
    alarm: str = ""


# The rate stream's reading: one ``read`` returns an AdcRead of gap-free AdcBlocks.
@dataclass(frozen=True)
class AdcBlock:
    """Consecutive samples with no gap inside (the recorder's ``/gyro/adc`` block).

    ``t0`` (s) is the ADC clock at the first sample, ``period`` (s) the nominal sample
    period, ``first_index`` the first sample's index since the stream's frame 0
    (``first_seq · samples_per_frame``), ``counts`` int32: ``(n,)`` for a single-axis ADC,
    ``(n, axes)`` for several.

    A stream that reports the unit's internal temperature adds ``temperature_c`` (°C, one
    reading every ``samples_per_reading`` samples, the k-th taken at sample
    ``first_index + k · samples_per_reading``); otherwise None and 0.
    """

    first_seq: int
    first_index: int
    t0: float
    period: float
    counts: np.ndarray
    temperature_c: np.ndarray | None = None
    samples_per_reading: int = 0


@dataclass
class AdcEvent:
    """A port event worth logging: ``kind`` is disconnect | reconnect | open_failed | gap."""

    wall_time: float
    kind: str
    message: str
    data: dict[str, Any] = field(default_factory=dict)


@dataclass
class AdcRead:
    """What one ``RateStream.read`` returned: blocks in order, the gaps between
    them (and before the first), and port events."""

    blocks: list[AdcBlock] = field(default_factory=list)
    gaps: list[Gap] = field(default_factory=list)
    events: list[AdcEvent] = field(default_factory=list)

    @property
    def samples(self) -> int:
        return sum(len(b.counts) for b in self.blocks)


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
        """Setpoint, process value and any alarm; raises on failure
        (:class:`InstrumentFault` when the controller reports it cannot control the
        chamber for a reason no suspension can wait out)."""
        ...

    # Drivers that can switch the chamber off also have ``switch_off()`` (heater and
    # refrigerator off, verified by read-back), used by ``[safe_state] mode = "off"``.


class MultiThermometer(Instrument, Protocol):
    """A scanning multimeter: one 4-wire PT100 per channel of its scan list."""

    # The scan list: multiplexer channel numbers (slot·100 + channel, e.g. 101), in order.
    channels: tuple[int, ...]

    def read(self) -> dict[int, ThermometerReading]:
        """One sweep of the scan list: a reading per channel (NaN where the channel
        overloaded: an open sensor); raises on a failed sweep (see :func:`is_transient`)."""
        ...


class RateStream(Instrument, Protocol):
    """The gyro's ADC stream (e.g. the ``gyroadc`` driver)."""

    def read(self, timeout_s: float) -> AdcRead:
        """Intact samples received so far: blocks, gaps, events."""
        ...

    def counters(self) -> dict[str, int]:
        """Running totals: at least ``frames_ok``, ``frames_bad`` and ``frames_lost``."""
        ...


class RateStreamConfig(Protocol):
    """What the run engine reads from a rate-stream driver's config (besides the
    ``driver``, ``serial`` and address every config has): the sample rate (Hz), the
    recorded block length (s), the number of axes and the counts → °/s conversion."""

    sample_rate_hz: float
    block_s: float
    axes: int

    def to_dps(self, counts: Any) -> Any: ...
