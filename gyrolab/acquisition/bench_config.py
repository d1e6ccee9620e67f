"""Bench configuration: the ``BENCH.toml`` that ``gyrolab acquire --bench`` reads.

One file says everything about a bench that is not the profile: where each instrument is
(VISA resource, serial port), how to talk to it, the safety limits and safe state, the
ADC's conversion from counts to °/s, the recorder's crash-loss policy, and who runs which
unit. ``docs/bench-config.md`` documents every key; ``examples/lab.toml`` is a complete
example. Unknown keys are errors (a typo in a safety limit must not pass silently).

Each instrument table (``[thermometer]``, ``[chamber]``, ``[rate_stream]``) is the config
dataclass of the driver its ``driver`` key names, declared in that driver's module and found through
:mod:`gyrolab.instruments.registry`; this module holds only what is bench-wide (run, limits,
safe state, recorder) and names no driver.

The ``run`` table goes into the recording's ``run`` metadata, the instrument tables (with
the identities the drivers read at connect time) into ``bench``.
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from gyrolab.errors import InputError
from gyrolab.instruments import registry
from gyrolab.profiles.profile import SETPOINT_BOUNDS_C
from gyrolab.tomlfile import read_toml


@dataclass(frozen=True)
class RunInfo:
    """Who runs what: into the ``run`` metadata record."""

    operator: str = ""
    unit_serial: str = ""
    unit_model: str = ""
    profile: str = "paper"  # built-in name or a profile TOML (relative to the bench file)
    notes: str = ""


@dataclass(frozen=True)
class UnitConfig:
    """One unit of a multi-unit bench (``[[unit]]``, docs/bench-config.md): its ``serial``
    (the recording's /unit/<serial>/… topics), its rate stream (``rate_stream``: the
    rate-stream driver's config, the bench's ``[rate_stream]`` table with this unit's
    ``driver``, ``port`` and overrides) and its temperature: ``temperature = "pt100"``
    read by the scanner on ``temperature_channel``, or ``"internal"``, the unit's own
    sensor in its rate stream (``temperature_channel`` None; the stream config's
    ``internal_temperature`` set)."""

    serial: str
    rate_stream: Any
    temperature_channel: int | None
    temperature: str = "pt100"

    @property
    def internal(self) -> bool:
        return self.temperature == "internal"


@dataclass(frozen=True)
class Limits:
    """Safety limits. Any breach drives the oven to the safe state and ends the run."""

    setpoint_min_c: float = -45.0
    setpoint_max_c: float = 70.0
    pt100_min_c: float = -50.0  # under-temperature watchdog on the PT100
    pt100_max_c: float = 75.0  # over-temperature watchdog on the PT100
    comm_timeout_s: float = 60.0  # an instrument silent longer than this is lost
    watchdog_samples: int = 3  # consecutive out-of-limit readings before acting (noise)


@dataclass(frozen=True)
class SafeState:
    """What the oven is told when a run ends early (fault, limit, SIGINT)."""

    # "setpoint": command and verify setpoint_c. "off": that, then switch the chamber
    # off and verify it (F4: its [chamber] control_event output; ESPEC: STANDBY).
    mode: str = "setpoint"
    setpoint_c: float = 25.0


@dataclass(frozen=True)
class Suspend:
    """Suspenders: conditions that hold the run instead of ending it, each for at most
    its limit (run seconds; 0: the condition is not a suspender — a chamber alarm then
    ends the run at once, the temperature sensor is lost after ``comm_timeout_s``, an
    operator pause is refused). gyrolab/acquisition/suspend.py, docs/bench-config.md."""

    chamber_alarm_s: float = 300.0  # a chamber alarm or open door (where the driver sees it)
    temperature_lost_s: float = 60.0  # the watched temperature gives no reading
    # a rate stream, or the watched temperature, silent this long holds the run (0: a
    # stream's silence never does; the temperature's at once)
    hold_after_s: float = 5.0
    operator_pause_s: float = 1800.0  # SIGUSR1 (pause) ... SIGUSR2 (resume)
    resoak_band_c: float = 1.0  # the temperature leaving +- this while held: the step re-soaks


@dataclass(frozen=True)
class RecorderConfig:
    """Crash-loss policy of the MCAP recorder (docs/reliability.md)."""

    flush_every_s: float = 1.0  # run seconds between chunk flushes (kill -9 window)
    fsync_every_s: float = 2.0  # wall seconds between fsyncs (power-cut window)
    chunk_size: int = 1 << 20


@dataclass(frozen=True)
class BenchConfig:
    """A whole bench. ``source`` is the file it came from (for messages)."""

    name: str = "bench"
    run: RunInfo = field(default_factory=RunInfo)
    # The three roles (``[thermometer]``, ``[chamber]``, ``[rate_stream]``), each the config
    # dataclass of the driver its table names (gyrolab.instruments.registry); each field
    # is named as its role and table (the older tables [multimeter], [oven] and [adc] are
    # still read: _ROLE_TABLES).
    thermometer: Any = field(default_factory=lambda: registry.default_config("thermometer"))
    chamber: Any = field(default_factory=lambda: registry.default_config("chamber"))
    rate_stream: Any = field(default_factory=lambda: registry.default_config("rate_stream"))
    limits: Limits = field(default_factory=Limits)
    safe_state: SafeState = field(default_factory=SafeState)
    recorder: RecorderConfig = field(default_factory=RecorderConfig)
    suspend: Suspend = field(default_factory=Suspend)
    # A multi-unit bench: its units (``[[unit]]``) and the scanning multimeter that reads
    # their PT100s (``[scanner]``); none on a single-unit bench, and no scanner when every
    # unit is read by its internal sensor (``[[unit]] temperature = "internal"``).
    units: tuple[UnitConfig, ...] = ()
    scanner: Any = None
    source: str = "<defaults>"

    def to_dict(self) -> dict[str, Any]:
        """The TOML layout (``bench_from_dict`` reads it back); a multi-unit bench's units
        as ``unit`` tables, its scanner without the channel list they give it."""
        d = asdict(self)
        d.pop("source")
        units, scanner = d.pop("units"), d.pop("scanner")
        if units:
            # TOML has no null: a unit on its internal sensor has no temperature_channel
            d["unit"] = [{k: v for k, v in u.items() if v is not None} for u in units]
            del d["thermometer"]  # a multi-unit bench has no [thermometer]
            if scanner is not None:  # none when every unit is on its internal sensor
                d["scanner"] = {k: v for k, v in scanner.items() if k != "channels"}
        return d

    def profile_path(self) -> str:
        """The profile spec, with a relative TOML path resolved against the bench file."""
        spec = self.run.profile
        if spec.lower().endswith(".toml") and not os.path.isabs(spec) and self.source:
            base = Path(self.source).parent if Path(self.source).is_file() else Path(".")
            return str(base / spec)
        return spec


_SECTIONS: dict[str, type] = {
    "run": RunInfo,
    "limits": Limits,
    "safe_state": SafeState,
    "recorder": RecorderConfig,
    "suspend": Suspend,
}


def _section(cls: type, raw: Any, where: str, source: str) -> Any:
    if not isinstance(raw, dict):
        raise InputError(source, f"[{where}] must be a table")
    known = {f.name: f for f in fields(cls)}
    unknown = sorted(set(raw) - set(known))
    if unknown:
        raise InputError(source, f"[{where}]: unknown key(s) {unknown}")
    kw: dict[str, Any] = {}
    for k, v in raw.items():
        typ = known[k].type
        try:
            if typ in ("float", float):
                if isinstance(v, bool):
                    raise TypeError
                v = float(v)
                if not math.isfinite(v):
                    raise ValueError
            elif typ in ("int", int):
                if isinstance(v, bool) or float(v) != int(v):
                    raise TypeError
                v = int(v)
            elif typ in ("str", str):
                if not isinstance(v, str):
                    raise TypeError
            elif typ in ("bool", bool):
                if not isinstance(v, bool):
                    raise TypeError
        except (TypeError, ValueError):
            raise InputError(source, f"[{where}] {k} = {v!r}: expected {typ}") from None
        kw[k] = v
    return cls(**kw)


# Role tables: each role (a BenchConfig field of that name) and its table names, the
# current one first, then the older name still read as the same table.
_ROLE_TABLES = (
    ("thermometer", ("thermometer", "multimeter")),
    ("chamber", ("chamber", "oven")),
    ("rate_stream", ("rate_stream", "adc")),
)
# Every role's table names; a multi-unit bench's scanner is the table [scanner].
_TABLE_NAMES = {**dict(_ROLE_TABLES), "multi_thermometer": ("scanner",)}


def _named(d: dict[str, Any], names: tuple[str, ...], source: str, both: str) -> str:
    """Which of ``names`` (a current name, then its older one) ``d`` uses: the one given,
    else the current one; both given is an error (``both`` formats the two)."""
    given = [n for n in names if n in d]
    if len(given) > 1:
        raise InputError(source, both.format(*given[:2]) + ": keep one")
    return given[0] if given else names[0]


def _role_table(d: dict[str, Any], role: str, source: str) -> tuple[str, dict[str, Any]]:
    """The table of ``role`` as the file names it (its current or its older name; both is
    an error) and its contents (empty when absent)."""
    where = _named(d, _TABLE_NAMES[role], source, "[{}] and [{}] are the same role")
    raw = d.get(where, {})
    if not isinstance(raw, dict):
        raise InputError(source, f"[{where}] must be a table")
    return where, raw


def _role_section(d: dict[str, Any], role: str, source: str) -> Any:
    """The driver config of one role: ``driver`` (default: the bench's original driver)
    picks the dataclass the rest of the table is checked against."""
    where, raw = _role_table(d, role, source)
    name = raw.get("driver", registry.DEFAULT_DRIVER[role])
    try:
        spec = registry.get(str(name), role)
    except KeyError as e:
        raise InputError(source, f"[{where}] driver = {name!r}: {e.args[0]}") from None
    return _section(spec.config, raw, where, source)


def bench_from_dict(d: dict[str, Any], source: str = "<dict>") -> BenchConfig:
    """Build and check a :class:`BenchConfig` from the TOML layout."""
    tables = {t for _, names in _ROLE_TABLES for t in names}
    unknown = sorted(set(d) - set(_SECTIONS) - tables - {"name", "scanner", "unit"})
    if unknown:
        raise InputError(source, f"unknown table(s) or key(s) {unknown}")
    kw: dict[str, Any] = {
        name: _section(cls, d.get(name, {}), name, source) for name, cls in _SECTIONS.items()
    }
    for role, _ in _ROLE_TABLES:
        kw[role] = _role_section(d, role, source)
    if "unit" in d or "scanner" in d:
        kw["units"], kw["scanner"] = _multi_unit(d, source)
    cfg = BenchConfig(name=str(d.get("name", Path(source).stem)), source=source, **kw)
    validate(cfg)
    return cfg


# A unit's overrides of [rate_stream] keys: a table named as that table (or its older name).
_UNIT_OVERRIDES = _TABLE_NAMES["rate_stream"]
_UNIT_KEYS = ("serial", "driver", "port", "temperature", "temperature_channel", *_UNIT_OVERRIDES)
# A unit's temperature (``[[unit]] temperature``): its PT100 on a scanner channel, or the
# unit's own internal sensor, reported in its rate stream.
TEMPERATURE_SOURCES = ("pt100", "internal")


def _multi_unit(d: dict[str, Any], source: str) -> tuple[tuple[UnitConfig, ...], Any]:
    """``[[unit]]`` and ``[scanner]``: the units (each one's rate-stream config is the
    ``[rate_stream]`` table with the unit's ``driver``, ``port`` and ``rate_stream``
    overrides) and the
    scanner's config, its channel list taken from the units read by PT100 (no scanner when
    every unit is on its internal sensor)."""
    from gyrolab.record.format import check_serial

    raw_units = d.get("unit")
    if not isinstance(raw_units, list) or not raw_units:
        raise InputError(source, "[scanner] needs the units it reads: one [[unit]] table each")
    if not all(isinstance(u, dict) for u in raw_units):
        raise InputError(source, "unit must be an array of tables ([[unit]])")
    for t in _TABLE_NAMES["thermometer"]:
        if t in d:
            raise InputError(
                source, f"[{t}]: a multi-unit bench reads each unit's PT100 with [scanner]"
            )
    raw_scanner = d.get("scanner")
    if raw_scanner is not None and not isinstance(raw_scanner, dict):
        raise InputError(source, "[scanner] must be a table")
    if raw_scanner is not None and "channels" in raw_scanner:
        raise InputError(source, "[scanner] channels: set by each [[unit]] temperature_channel")
    shared_where, shared = _role_table(d, "rate_stream", source)
    units = []
    for i, u in enumerate(raw_units, start=1):
        where = f"[[unit]] {i}"
        unknown = sorted(set(u) - set(_UNIT_KEYS))
        if unknown:
            raise InputError(source, f"{where}: unknown key(s) {unknown}")
        try:
            serial = check_serial(u.get("serial"))  # type: ignore[arg-type]
        except ValueError as e:
            raise InputError(source, f"{where} serial: {e}") from None
        where = f"[[unit]] {serial}"
        temperature, ch = _unit_temperature(u, where, source)
        key = _named(u, _UNIT_OVERRIDES, source, where + ": {} and {} are the same table")
        over = u.get(key, {})
        if not isinstance(over, dict):
            raise InputError(source, f"{where}: {key} must be a table of [{shared_where}] keys")
        raw = {**shared, **over, **{k: u[k] for k in ("driver", "port") if k in u}}
        name = raw.get("driver", registry.DEFAULT_DRIVER["rate_stream"])
        try:
            spec = registry.get(str(name), "rate_stream")
        except KeyError as e:
            raise InputError(source, f"{where} driver = {name!r}: {e.args[0]}") from None
        if temperature == "internal":
            # The stream must carry the sensor: its driver's config says whether it can.
            if "internal_temperature" not in {f.name for f in fields(spec.config)}:
                raise InputError(
                    source,
                    f'{where} temperature = "internal": its rate-stream driver {name!r} '
                    "reports no internal temperature",
                )
            raw["internal_temperature"] = True
        stream = _section(spec.config, raw, f"{where} {key}", source)
        units.append(UnitConfig(serial, stream, ch, temperature))
    channels = tuple(u.temperature_channel for u in units if not u.internal)
    if not channels:
        if raw_scanner is not None:
            raise InputError(
                source,
                '[scanner]: every [[unit]] has temperature = "internal", so it reads no PT100 '
                "(remove [scanner])",
            )
        return tuple(units), None
    if raw_scanner is None:
        raise InputError(source, "[[unit]] needs [scanner], the multimeter reading their PT100s")
    scanner = _role_section(d, "multi_thermometer", source)
    return tuple(units), replace(scanner, channels=channels)


def _unit_temperature(u: dict[str, Any], where: str, source: str) -> tuple[str, int | None]:
    """A ``[[unit]]``'s temperature: ``("pt100", channel)`` or ``("internal", None)``."""
    temperature = u.get("temperature", "pt100")
    if temperature not in TEMPERATURE_SOURCES:
        raise InputError(
            source,
            f'{where}: temperature = {temperature!r}: "pt100" (its PT100 on the scanner\'s '
            'temperature_channel) or "internal" (the unit\'s own sensor, in its rate stream)',
        )
    ch = u.get("temperature_channel")
    if temperature == "internal":
        if ch is not None:
            raise InputError(
                source,
                f'{where}: temperature = "internal" and temperature_channel = {ch!r}: '
                "give one of the two",
            )
        return temperature, None
    if isinstance(ch, bool) or not isinstance(ch, int):
        raise InputError(
            source,
            f"{where}: temperature_channel = {ch!r}: the scanner channel of its PT100, an "
            'integer such as 101 (or temperature = "internal" for its own sensor)',
        )
    return temperature, ch


# Physical bounds a limit must lie within (docs/bench-config.md, "Limits"): beyond them a
# value is a typo, not a bench. Setpoints: the profiles' own bound, the widest range of the
# chambers MEMS tests use (gyrolab.profiles.profile.SETPOINT_BOUNDS_C). PT100: the range of
# the Callendar-Van Dusen equations (IEC 60751), -200...+850 °C.
PT100_BOUNDS_C = (-200.0, 850.0)
# How far inside the PT100 watchdog window every setpoint must lie: the case settles at
# the setpoint +- control error and meter noise, and must not trip the watchdog there.
PT100_MARGIN_C = 2.0


def validate(cfg: BenchConfig) -> None:
    """Consistency checks; raises InputError naming the file and the key."""
    s = cfg.source
    lim = cfg.limits
    for key, bounds in (
        ("setpoint_min_c", SETPOINT_BOUNDS_C),
        ("setpoint_max_c", SETPOINT_BOUNDS_C),
        ("pt100_min_c", PT100_BOUNDS_C),
        ("pt100_max_c", PT100_BOUNDS_C),
    ):
        v = getattr(lim, key)
        if not bounds[0] <= v <= bounds[1]:
            raise InputError(
                s,
                f"[limits] {key} = {v:g} °C is outside the physical bounds "
                f"[{bounds[0]:g}, {bounds[1]:g}] °C (docs/bench-config.md)",
            )
    if not lim.setpoint_min_c < lim.setpoint_max_c:
        raise InputError(s, "[limits] setpoint_min_c must be below setpoint_max_c")
    if not lim.pt100_min_c < lim.pt100_max_c:
        raise InputError(s, "[limits] pt100_min_c must be below pt100_max_c")
    if lim.comm_timeout_s <= 0 or lim.watchdog_samples < 1:
        raise InputError(s, "[limits] comm_timeout_s must be > 0 and watchdog_samples >= 1")
    ss = cfg.safe_state
    if ss.mode not in ("setpoint", "off"):
        raise InputError(s, f"[safe_state] mode = {ss.mode!r}: 'setpoint' or 'off'")
    if not lim.setpoint_min_c <= ss.setpoint_c <= lim.setpoint_max_c:
        raise InputError(s, "[safe_state] setpoint_c is outside the setpoint limits")
    if not lim.pt100_min_c < ss.setpoint_c < lim.pt100_max_c:
        raise InputError(s, "[safe_state] setpoint_c is outside [limits] pt100_min_c..pt100_max_c")
    # The driver's own checks (its config's optional check(), registry.DriverSpec): each
    # role's, and on a multi-unit bench every unit's stream's and the scanner's too.
    drivers = [(f"[{role}]", getattr(cfg, role)) for role, _ in _ROLE_TABLES]
    drivers += [(f"[[unit]] {u.serial} rate_stream", u.rate_stream) for u in cfg.units]
    if cfg.scanner is not None:
        drivers.append(("[scanner]", cfg.scanner))
    for where, sub in drivers:
        check = getattr(sub, "check", None)
        if check is not None:
            try:
                check(ss.mode)
            except ValueError as e:
                raise InputError(s, f"{where} {sub.driver}: {e}") from None
    periods = [("thermometer", cfg.thermometer.period_s), ("chamber", cfg.chamber.period_s)]
    if cfg.scanner is not None:
        periods.append(("scanner", cfg.scanner.period_s))
    for name, period in periods:
        if not period > 0:
            raise InputError(s, f"[{name}] period_s must be > 0")
    streams = [("[rate_stream]", cfg.rate_stream)]
    streams += [(f"[[unit]] {u.serial} rate_stream", u.rate_stream) for u in cfg.units]
    for where, a in streams:
        if not (a.sample_rate_hz > 0 and a.block_s > 0):
            raise InputError(s, f"{where} sample_rate_hz and block_s must be > 0")
    _check_units(cfg)
    sus = cfg.suspend
    for key in ("chamber_alarm_s", "temperature_lost_s", "hold_after_s", "operator_pause_s"):
        if getattr(sus, key) < 0:
            raise InputError(s, f"[suspend] {key} must be >= 0 (0: not a suspender)")
    if not sus.resoak_band_c > 0:
        raise InputError(s, "[suspend] resoak_band_c must be > 0 °C")
    r = cfg.recorder
    if not (0 < r.flush_every_s <= 1.5):
        # The 2 s crash-loss promise needs flush period + one stream block below 2 s.
        raise InputError(s, "[recorder] flush_every_s must be in (0, 1.5] s")
    for where, a in streams:
        if r.flush_every_s + a.block_s > 2.0:
            raise InputError(s, f"[recorder] flush_every_s + {where} block_s must not exceed 2 s")
    if not r.fsync_every_s > 0 or r.chunk_size < 1024:
        raise InputError(s, "[recorder] fsync_every_s must be > 0 and chunk_size >= 1024")


def _check_units(cfg: BenchConfig) -> None:
    """Units: distinct serials and scanner channels. A unit may have 1–3 axes (a flight
    controller's IMUs have three each)."""
    s = cfg.source
    channels = list(cfg.scanner.channels) if cfg.scanner is not None else []
    for what, values in (("serial", [u.serial for u in cfg.units]), ("channel", channels)):
        dup = sorted({v for v in values if values.count(v) > 1}, key=str)
        if dup:
            raise InputError(s, f"[[unit]] {what} {dup[0]} is given to more than one unit")


def check_bench_for_profile(cfg: BenchConfig, profile: Any, profile_source: str) -> None:
    """Refuse (before any I/O) a profile the bench's PT100 watchdog would abort: every
    setpoint must lie at least ``PT100_MARGIN_C`` inside ``[pt100_min_c, pt100_max_c]``.
    (Setpoints against ``setpoint_min_c..setpoint_max_c``: ``profiles.plan.check_profile_limits``.)
    """
    lim = cfg.limits
    lo, hi = lim.pt100_min_c + PT100_MARGIN_C, lim.pt100_max_c - PT100_MARGIN_C
    for i, st in enumerate(profile.steps):
        if not lo <= st.setpoint_c <= hi:
            raise InputError(
                cfg.source,
                f"[limits] pt100_min_c..pt100_max_c = {lim.pt100_min_c:g}..{lim.pt100_max_c:g} "
                f"°C would stop profile {profile_source} at step {i + 1} (setpoint "
                f"{st.setpoint_c:g} °C): the watchdog window must contain every setpoint "
                f"with {PT100_MARGIN_C:g} °C to spare",
            )


def load_bench(path: str | os.PathLike[str]) -> BenchConfig:
    """Read and check a bench TOML file."""
    p = Path(path)
    d = read_toml(p, "bench file")
    cfg = bench_from_dict(d, str(p))
    # Where each instrument is: a multi-unit bench reaches the chamber, the scanner and
    # every unit's rate stream (its [thermometer] and [rate_stream] port are not used).
    needed: list[tuple[str, str, Any]] = []
    for role, _ in _ROLE_TABLES:
        if cfg.units and role != "chamber":
            continue
        needed.append((f"[{_role_table(d, role, str(p))[0]}]", role, getattr(cfg, role)))
    if cfg.scanner is not None:
        needed.append(("[scanner]", "multi_thermometer", cfg.scanner))
    if cfg.units:
        needed += [(f"[[unit]] {u.serial}", "rate_stream", u.rate_stream) for u in cfg.units]
    for where, role, sub in needed:
        key = registry.get(sub.driver, role).address_key
        if not getattr(sub, key):
            raise InputError(p, f"{where} {key} is required for a real bench")
    return cfg
