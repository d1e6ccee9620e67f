"""The driver registry: which driver fills which role on a bench.

Each module in :mod:`gyrolab.instruments.drivers` registers one :class:`DriverSpec` at
import time with :func:`register`. ``BENCH.toml`` names the driver per role
(``[thermometer] driver = "agilent34401a"``); the bench loader checks the rest of the
table against the spec's config dataclass (unknown keys are errors), and
``gyrolab acquire`` opens it with :func:`open_driver` (``spec.open``). Adding a driver is one module
in ``drivers/`` plus its test (docs/instruments.md, "Adding a driver").

Roles and the recording's name for each (the ``source`` of its ``/log`` entries and the key
of its identity in the ``bench`` metadata): ``thermometer`` → ``multimeter``, ``chamber``
→ ``oven``, ``rate_stream`` → ``adc`` (the names recordings have always used), and on a
multi-unit bench ``multi_thermometer`` → ``scanner`` (one PT100 per unit).
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

ROLES = ("thermometer", "chamber", "rate_stream", "multi_thermometer")
SOURCE_NAME = {
    "thermometer": "multimeter",
    "chamber": "oven",
    "rate_stream": "adc",
    "multi_thermometer": "scanner",
}
DEFAULT_DRIVER = {
    "thermometer": "agilent34401a",
    "chamber": "watlowf4",
    "rate_stream": "gyroadc",
    "multi_thermometer": "keysight34970a",
}


@dataclass(frozen=True)
class OpenContext:
    """What opening a driver needs besides its config.

    ``address``: where the instrument is (the config's resource/port, or the simulated
    bench's); ``timeout``: maps a configured timeout (s) to the one to use (the simulated
    bench scales them); ``setpoint_limits_c``: the bench's limits (chambers);
    ``clock``: the monotonic clock of event time stamps (the ADC reader).
    """

    address: str
    timeout: Callable[[float], float]
    setpoint_limits_c: tuple[float, float]
    clock: Callable[[], float]
    visa_library: str = "@py"


@dataclass(frozen=True)
class DriverSpec:
    """A driver: its ``name`` in BENCH.toml, its ``role``, its ``config`` dataclass,
    ``open(config, ctx)`` returning the connected role object, the config field holding its
    address (``address_key``), ``sim_backend``: the simulated instrument in
    ``gyrolab.sim.bench.SimBench`` that speaks its protocol (its model name there; "" =
    none) and ``sim_address``: the key of ``SimBench.resources()`` the driver connects to.

    The config dataclass, declared in the driver's module: frozen, every field a BENCH.toml
    key with a default (typed ``str``, ``int``, ``float`` or ``bool``: the loader checks
    them), a ``driver`` field defaulting to the driver's name, ``serial``, the address
    field, ``period_s`` and ``timeout_s`` where the role is polled (thermometer,
    chamber), and what :class:`~gyrolab.instruments.roles.RateStreamConfig` names for a
    rate stream. Optionally ``check(safe_state_mode)``, raising ``ValueError`` with a
    message for settings that make no sense (the loader reports it as an input error)."""

    name: str
    role: str
    config: type
    open: Callable[[Any, OpenContext], Any]
    address_key: str
    sim_backend: str = ""
    sim_address: str = ""
    description: str = ""


_SPECS: dict[str, DriverSpec] = {}
_loaded = False


_D = TypeVar("_D")


def connected(device: _D) -> _D:
    """``device.connect()``, closing the device first if that fails (no port is left half
    open when a bench does not come up), then re-raising; returns the connected device."""
    try:
        device.connect()  # type: ignore[attr-defined]
    except BaseException:
        device.close()  # type: ignore[attr-defined]
        raise
    return device


def register(spec: DriverSpec) -> DriverSpec:
    """Add a driver (called by its module in ``drivers/`` at import time)."""
    if spec.role not in ROLES:
        raise ValueError(f"driver {spec.name!r}: unknown role {spec.role!r} (one of {ROLES})")
    old = _SPECS.get(spec.name)
    if old is not None and old is not spec and old.open is not spec.open:
        raise ValueError(f"driver {spec.name!r} registered twice")
    _SPECS[spec.name] = spec
    return spec


def unregister(name: str) -> None:
    """Remove a driver (a test's throw-away driver, after the test)."""
    _SPECS.pop(name, None)


def _load() -> None:
    global _loaded
    if _loaded:
        return
    from gyrolab.instruments import drivers

    for m in sorted(pkgutil.iter_modules(drivers.__path__), key=lambda m: m.name):
        importlib.import_module(f"{drivers.__name__}.{m.name}")
    _loaded = True


def drivers(role: str | None = None) -> list[DriverSpec]:
    """All registered drivers (of one role), by name."""
    _load()
    return [s for _, s in sorted(_SPECS.items()) if role is None or s.role == role]


def get(name: str, role: str) -> DriverSpec:
    """The driver ``name`` for ``role``; ``KeyError`` with the choices when there is none."""
    _load()
    spec = _SPECS.get(name)
    if spec is None or spec.role != role:
        names = ", ".join(s.name for s in drivers(role))
        raise KeyError(f"no {role} driver {name!r} (registered: {names})")
    return spec


def default_config(role: str) -> Any:
    """The config, all defaults, of the role's default driver (``DEFAULT_DRIVER``)."""
    return get(DEFAULT_DRIVER[role], role).config()


def address(config: Any, role: str) -> str:
    """Where the instrument of ``config`` is: its driver's ``address_key`` field."""
    return str(getattr(config, get(config.driver, role).address_key))


def open_driver(config: Any, role: str, ctx: OpenContext) -> Any:
    """Open, identify and name the driver ``config.driver`` for ``role`` at ``ctx.address``:
    the connected role object, its ``name`` the role's source name in the recording."""
    dev = get(config.driver, role).open(config, ctx)
    dev.name = SOURCE_NAME[role]
    return dev
