"""Declarative driver settings: each setting of an instrument declared once, with its
command, its validator and its documentation (PyMeasure's ``Instrument.control`` and
``Instrument.setting``, docs/instruments.md "Declaring a setting").

A driver class states its settings as class attributes::

    class Agilent34401A:
        RANGES_OHM = (100.0, 1e3, ...)
        range_ohm = Setting(
            "CONF:FRES {value:g}", "4-wire resistance range", unit="Ω",
            validator=one_of, values="RANGES_OHM", cast=float,
        )

and the :class:`Setting` descriptor does the rest:

* ``drv.x = v`` validates ``v`` (a :class:`~gyrolab.instruments.roles.LimitError` naming the
  instrument and the setting, **before anything is sent**), writes it (a text command
  through ``drv.write``, or a Modbus holding register through ``drv.write_register``) and,
  with ``readback=True``, reads it back and compares;
* ``drv.x`` reads the instrument when the setting has a ``get`` (a query through
  ``drv.query``, or a register through ``drv.read_register``), else gives the value last
  held or written;
* ``Setting.hold(drv, v)`` (``drv.hold("x", v)`` on a :class:`Settings` driver) validates
  and keeps ``v`` without any I/O — the configured value a driver checks when it is
  created and sends when it connects (``drv.send("x", ...)``).

A validator is a plain function ``validator(value, values) -> value`` that raises
``ValueError(reason)`` (the PyMeasure contract): :func:`one_of`, :func:`in_range` and
:func:`finite_within` here. ``values`` may be a constant, the name of a class attribute
(so a derived model narrows it: the 34465A's NPLC list), or a callable of the driver (a
chamber's limits, known per bench).

:func:`finite_within` is the one chamber setpoint-limit check: both chamber drivers declare
their setpoint with it (the bench limits, and the controller's own range where it reports
one).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

from gyrolab.instruments.roles import InstrumentError, LimitError

__all__ = ["Setting", "Settings", "finite_within", "in_range", "one_of"]

Validator = Callable[[Any, Any], Any]


def one_of(value: Any, values: Sequence[Any]) -> Any:
    """``value`` if it is one of ``values`` (PyMeasure's ``strict_discrete_set``)."""
    if value not in values:
        raise ValueError(f"is not one of {tuple(values)}")
    return value


def in_range(value: Any, values: tuple[float, float]) -> Any:
    """``value`` if it is a finite number in ``[lo, hi]`` (``strict_range``)."""
    return finite_within(value, [("range", values)])


def finite_within(value: Any, values: Sequence[tuple[str, tuple[float, float]]]) -> float:
    """``value`` if it is a finite number inside every named range ``(what, (lo, hi))``:
    e.g. a chamber setpoint inside the bench limits and the controller's own range."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError("is not a finite number")
    for what, (lo, hi) in values:
        if not lo <= value <= hi:
            raise ValueError(f"outside the {what} [{lo}, {hi}]")
    return value


def _passthrough(value: Any, values: Any) -> Any:
    return value


class Setting:
    """One instrument setting, declared once (see the module docstring).

    Parameters
    ----------
    set : a command template formatted with ``value`` (after ``set_process``) and ``drv``
        (``"FRES:NPLC {value:g}"``), a Modbus holding register number, or None (read-only).
    doc : what the setting is (the descriptor's ``__doc__``; docs and ``help()``).
    get : a query (its reply, stripped, goes through ``get_process``), a register number
        (its raw value through ``get_process``), or None: reading gives the held value.
    unit : shown in error messages after the value ("Ω", "°C").
    label : the setting's name in error messages (default: the attribute's name).
    validator, values : ``validator(value, values)`` checks a value before anything is
        sent; ``values`` as in the module docstring.
    cast : applied to the validated value before it is held (``float``).
    set_process : ``set_process(drv, value)`` → what the command or register gets
        (``round``, a unit conversion to the register's raw integer).
    get_process : ``get_process(drv, reply)`` → the value read.
    readback : after writing, read the setting back (``get``) and compare the raw values;
        a mismatch is an :class:`~gyrolab.instruments.roles.InstrumentError`.
    """

    def __init__(
        self,
        set: str | int | None,
        doc: str,
        *,
        get: str | int | None = None,
        unit: str = "",
        label: str = "",
        validator: Validator = _passthrough,
        values: Any = (),
        cast: Callable[[Any], Any] | None = None,
        set_process: Callable[[Any, Any], Any] | None = None,
        get_process: Callable[[Any, Any], Any] | None = None,
        readback: bool = False,
    ) -> None:
        if readback and get is None:
            raise ValueError("readback needs a get command")
        self.set_cmd, self.get_cmd = set, get
        self.__doc__ = doc
        self.unit, self.label = unit, label
        self.validator, self.values, self.cast = validator, values, cast
        self.set_process, self.get_process = set_process, get_process
        self.readback = readback
        self.name = ""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name
        self.label = self.label or name.replace("_", " ")

    def with_command(self, set: str | int | None = None, get: str | int | None = None) -> Setting:
        """The same setting (doc, validator, values, processing) on other commands: a
        derived instrument's variant (the scanner's commands take a channel list)."""
        s = Setting.__new__(Setting)
        s.__dict__.update(self.__dict__)
        s.set_cmd = self.set_cmd if set is None else set
        s.get_cmd = self.get_cmd if get is None else get
        return s

    # ------------------------------------------------------------------ checks
    def allowed(self, drv: Any) -> Any:
        """The allowed ``values`` for this driver (an attribute name or a callable
        resolved on it)."""
        v = self.values
        if isinstance(v, str):
            return getattr(drv, v)
        return v(drv) if callable(v) else v

    def check(self, drv: Any, value: Any) -> Any:
        """The validated (and cast) value, or a :class:`LimitError`; no I/O."""
        try:
            ok = self.validator(value, self.allowed(drv))
        except ValueError as e:
            shown = f"{value!r}" if not isinstance(value, (int, float)) else f"{value}"
            unit = f" {self.unit}" if self.unit else ""
            raise LimitError(_instrument(drv), f"{self.label} {shown}{unit} {e}") from None
        return self.cast(ok) if self.cast is not None else ok

    def hold(self, drv: Any, value: Any) -> Any:
        """Validate ``value`` and keep it as the setting's value; nothing is sent."""
        ok = self.check(drv, value)
        drv.__dict__[self.name] = ok
        return ok

    # ------------------------------------------------------------------ I/O
    def raw(self, drv: Any, value: Any) -> Any:
        """What the command or register gets for a validated ``value``."""
        return self.set_process(drv, value) if self.set_process is not None else value

    def write(self, drv: Any, value: Any) -> Any:
        """Validate, hold, write (and read back); returns the raw value written."""
        if self.set_cmd is None:
            raise AttributeError(f"{self.label} is read-only")
        ok = self.hold(drv, value)
        raw = self.raw(drv, ok)
        if isinstance(self.set_cmd, int):
            drv.write_register(self.set_cmd, raw)
        else:
            drv.write(self.set_cmd.format(value=raw, drv=drv))
        if self.readback:
            back = self.read_raw(drv)
            if back != raw:
                raise InstrumentError(
                    _instrument(drv), f"{self.label} read-back {back} != written {raw}"
                )
        return raw

    def read_raw(self, drv: Any) -> Any:
        """The instrument's raw reply (stripped) or register value for the setting."""
        if isinstance(self.get_cmd, int):
            return drv.read_register(self.get_cmd)
        return str(drv.query(self.get_cmd)).strip()

    def read(self, drv: Any) -> Any:
        """The setting as the instrument holds it now (needs ``get``)."""
        raw = self.read_raw(drv)
        return self.get_process(drv, raw) if self.get_process is not None else raw

    # ------------------------------------------------------------------ descriptor
    def __get__(self, drv: Any, owner: type | None = None) -> Any:
        if drv is None:
            return self
        if self.get_cmd is not None:
            return self.read(drv)
        try:
            return drv.__dict__[self.name]
        except KeyError:
            raise AttributeError(f"{self.label} has not been set") from None

    def __set__(self, drv: Any, value: Any) -> None:
        self.write(drv, value)


class Settings:
    """Mix-in for a driver with :class:`Setting` s: ``hold`` and ``send`` by name."""

    def hold(self, name: str, value: Any) -> Any:
        """Validate and keep a setting's value without sending it (see :class:`Setting`)."""
        return _setting(self, name).hold(self, value)

    def send(self, *names: str) -> None:
        """Write the held values of the named settings, in order."""
        for name in names:
            _setting(self, name).write(self, self.__dict__[name])


def _setting(drv: Any, name: str) -> Setting:
    s = getattr(type(drv), name, None)
    if not isinstance(s, Setting):
        raise AttributeError(f"{type(drv).__name__}.{name} is not a Setting")
    return s


def _instrument(drv: Any) -> str:
    return str(getattr(drv, "NAME", type(drv).__name__))
