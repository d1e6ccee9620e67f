"""Temperature profiles: the setpoint schedule of an oven test and its soak rules.

A profile is a list of steps. Each step commands one oven setpoint and lasts at least
``duration_s`` from the moment it starts (the paper's rule: "drop by 10 °C every 1 h").
A step may add a stability rule: after its minimum duration it is held until the PT100
slope stays below ``stable_slope_c_per_min`` for ``stable_window_s`` (at most
``max_extra_s`` more). The simulator and the acquisition runner read the same profile.

The built-in ``paper`` profile (docs/profiles.md; paper §4.1): 1 h power-on at room
temperature (25 °C), heat to 60 °C and hold 1 h, then −10 °C per hour down to −40 °C,
which is held one more hour — 13 h in all.

The TOML format is documented in docs/profiles.md. Keys are strict, as in BENCH.toml: an
unknown top-level or step key is an error naming the file and the key (a typo such as
``ambiant_c`` must not pass silently). There is no safe setpoint in a profile: the state
a run ends in after a fault belongs to the bench (``[safe_state]`` in BENCH.toml,
docs/bench-config.md), which knows its chamber and its limits.
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gyrolab.errors import InputError
from gyrolab.tomlfile import read_toml

if TYPE_CHECKING:  # numpy is imported where a profile is evaluated: reading one needs none
    import numpy as np

# Bounds every profile lies within (docs/profiles.md, "Bounds"): beyond them a value is a
# typo, not a test. Setpoints: the widest range of the chambers MEMS tests use (compressor
# chambers about -75...+180 °C, LN2-cooled ones down to about -100 °C); a bench's own
# [limits] are checked on top (acquire). The room a run starts in: a lab, not a furnace.
# Length: a week, the longest a profile may run with every stability hold used to the
# full (the paper's is 13 h); 1e300 s would otherwise simulate or record until killed.
SETPOINT_BOUNDS_C = (-100.0, 200.0)
AMBIENT_BOUNDS_C = (-40.0, 60.0)
MAX_PROFILE_S = 7 * 86400.0


@dataclass(frozen=True)
class Step:
    """One oven setpoint held for at least ``duration_s`` seconds."""

    setpoint_c: float
    duration_s: float
    label: str = ""
    stable_slope_c_per_min: float | None = None
    stable_window_s: float = 600.0
    max_extra_s: float = 3600.0

    def __post_init__(self) -> None:
        lo, hi = SETPOINT_BOUNDS_C
        if not lo <= self.setpoint_c <= hi:
            raise ValueError(
                f"setpoint_c = {self.setpoint_c:g} °C is outside [{lo:g}, {hi:g}] °C, the "
                "range of any test chamber"
            )
        if not 0 < self.duration_s <= MAX_PROFILE_S:
            raise ValueError(
                f"duration_s = {self.duration_s:g} must be a positive number of seconds, at "
                f"most {MAX_PROFILE_S:g} (7 days)"
            )
        if self.stable_slope_c_per_min is not None and not self.stable_slope_c_per_min > 0:
            raise ValueError("stable_slope_c_per_min must be positive")
        window, extra = self.stable_window_s, self.max_extra_s
        if not (0 < window <= MAX_PROFILE_S and 0 <= extra <= MAX_PROFILE_S):
            raise ValueError(
                f"stable_window_s must be in (0, {MAX_PROFILE_S:g}] s and max_extra_s in "
                f"[0, {MAX_PROFILE_S:g}] s"
            )

    @property
    def longest_s(self) -> float:
        """The longest this step can last: with a stability rule, ``max_extra_s`` more."""
        extra = self.max_extra_s if self.stable_slope_c_per_min is not None else 0.0
        return self.duration_s + extra


@dataclass(frozen=True)
class Profile:
    """A named sequence of steps; ``ambient_c`` is the room the oven starts in."""

    name: str
    steps: tuple[Step, ...]
    ambient_c: float = 25.0
    description: str = ""
    extra: dict[str, Any] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        if not self.steps:
            raise ValueError("a profile needs at least one step")
        lo, hi = AMBIENT_BOUNDS_C
        if not lo <= self.ambient_c <= hi:
            raise ValueError(
                f"ambient_c = {self.ambient_c:g} °C is outside [{lo:g}, {hi:g}] °C, a room's range"
            )
        longest = sum(s.longest_s for s in self.steps)
        if longest > MAX_PROFILE_S:
            raise ValueError(
                f"the profile can last {longest:g} s with its holds, more than "
                f"{MAX_PROFILE_S:g} s (7 days)"
            )

    @property
    def duration_s(self) -> float:
        """Nominal duration: the sum of the steps' minimum durations."""
        return float(sum(s.duration_s for s in self.steps))

    def step_starts(self) -> np.ndarray:
        """Nominal start time of every step (s since power-on), time rule only."""
        import numpy as np

        return np.concatenate([[0.0], np.cumsum([s.duration_s for s in self.steps])[:-1]])

    def setpoint_at(self, t_s: np.ndarray | float) -> np.ndarray:
        """Setpoint (°C) of the nominal, time-only schedule at times ``t_s``."""
        import numpy as np

        t = np.asarray(t_s, dtype=float)
        idx = np.searchsorted(self.step_starts(), t, side="right") - 1
        idx = np.clip(idx, 0, len(self.steps) - 1)
        return np.array([s.setpoint_c for s in self.steps])[idx]

    def reversed(self, name: str | None = None) -> Profile:
        """The same steps in reverse order (a heating profile from a cooling one)."""
        return Profile(
            name=name or f"{self.name}-reversed",
            steps=tuple(reversed(self.steps)),
            ambient_c=self.ambient_c,
            description=f"{self.description} (reversed)".strip(),
        )

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "name": self.name,
            "description": self.description,
            "ambient_c": self.ambient_c,
            "step": [],
        }
        for s in self.steps:
            sd = {k: v for k, v in asdict(s).items() if v is not None}
            d["step"].append(sd)
        return d


def _paper() -> Profile:
    steps = [Step(25.0, 3600.0, "power-on"), Step(60.0, 3600.0, "heat")]
    for sp in range(50, -40, -10):
        steps.append(Step(float(sp), 3600.0, f"{sp} C"))
    steps.append(Step(-40.0, 7200.0, "-40 C + final hold"))
    return Profile(
        name="paper",
        steps=tuple(steps),
        ambient_c=25.0,
        description="Wei et al. 2021 §4.1: 1 h at 25 °C, 60 °C for 1 h, -10 °C/h to -40 °C, "
        "-40 °C held 1 h more",
    )


def _short() -> Profile:
    """A 48-minute smoke test of the software: the paper's schedule with 4 min steps.

    Not a temperature test: no chamber follows 4 min steps (the simulator's nominal oven
    air has τ = 240 s and heats at most 3 °C/min, cools at most 1.5 °C/min; the gyro case
    follows the air with τ = 580 J/K · 4 K/W ≈ 39 min). Measured
    with ``gyrolab simulate --profile short`` (docs/profiles.md): chamber air 4.9…45.2 °C,
    gyro case (PT100) 25.0…32.0 °C, for setpoints −40…60 °C.
    """
    steps = [Step(25.0, 240.0, "power-on"), Step(60.0, 240.0, "heat")]
    for sp in range(50, -50, -10):
        steps.append(Step(float(sp), 240.0, f"{sp} C"))
    return Profile(
        name="short",
        steps=tuple(steps),
        description="software smoke test: paper shape, 4 min steps; the chamber cannot follow "
        "(simulated: chamber 5-45 °C, gyro case 25-32 °C for setpoints -40..60 °C)",
    )


def _quick() -> Profile:
    """A 3.25 h calibration run (issue 30) for a unit calibrated with a fleet prior
    (``gyrolab compensate --prior``): what ``gyrolab profile design --hours 3.25``
    chooses for the simulator's nominal chamber without a prior (docs/profiles.md) —
    10 min power-on at 25 °C, 30 min towards 60 °C, 140 min towards −40 °C, 15 min back
    towards 25 °C, so the die temperature rises, falls and rises (both hysteresis
    branches, the rate in both signs). The chamber cools slowly when cold: the case
    reaches about −18 … 46 °C, the prior supplies the rest of the range."""
    steps = (
        Step(25.0, 600.0, "power-on"),
        Step(60.0, 1800.0, "hot"),
        Step(-40.0, 8400.0, "cold"),
        Step(25.0, 900.0, "back to ambient"),
    )
    return Profile(
        name="quick",
        steps=steps,
        ambient_c=25.0,
        description="3.25 h up-down-up calibration for compensate --prior (issue 30): "
        "25, 60, -40, 25 °C",
    )


def _paper_ramps() -> Profile:
    """The ``paper`` staircase, then one heating/cooling cycle at the chamber's fastest
    rates (issue 23; docs/profiles.md, "paper_ramps"): from the staircase's −40 °C, 2 h
    towards 60 °C, then 2 h towards −40 °C — 17 h in all. A profile has setpoints, not
    ramp rates: the ramps are the chamber's own limits (the simulator's nominal air heats
    at most 3 °C/min and cools at most 1.5 °C/min, slower below 40 °C), so the heating
    and cooling rates the calibration sees are the fastest a held-out run can reach. The
    heating step is 2 h, not 1, so that the case nears 60 °C again (docs/results.md, "A
    ramp cycle in gyrolab's calibration profile")."""
    steps = _paper().steps + (
        Step(60.0, 7200.0, "ramp up to 60 C"),
        Step(-40.0, 7200.0, "ramp down to -40 C"),
    )
    return Profile(
        name="paper_ramps",
        steps=steps,
        ambient_c=25.0,
        description="paper staircase + one ramp cycle at the chamber's limits: 2 h towards "
        "60 °C, 2 h towards -40 °C (17 h; calibrates the heating/cooling-rate terms)",
    )


def _cold_start() -> Profile:
    """A second calibration run, powered on cold (``gyrolab compensate RUN --also COLD``;
    docs/profiles.md, "cold_start"): the unit soaked unpowered at −20 °C and powered on
    there, 1 h at −20 °C, 1.5 h towards 40 °C, 1 h towards −10 °C — 3.5 h. A power-on in
    a warm room cannot tell a warm-up that always comes at power-on from the die's own
    self-heating; a power-on in the cold can (docs/results.md, "A second power-on,
    cold"). ``ambient_c`` is −20 °C: where the simulator starts the chamber and the unit,
    and where a lab soaks the unit before powering it on and starting the run."""
    steps = (
        Step(-20.0, 3600.0, "power-on cold"),
        Step(40.0, 5400.0, "warm to 40 C"),
        Step(-10.0, 3600.0, "cool to -10 C"),
    )
    return Profile(
        name="cold_start",
        steps=steps,
        ambient_c=-20.0,
        description="second calibration run from a cold power-on (compensate --also): soak "
        "unpowered at -20 °C, power on, then -20, 40, -10 °C (3.5 h)",
    )


BUILTIN: dict[str, Profile] = {
    "paper": _paper(),
    "short": _short(),
    "quick": _quick(),
    "paper_ramps": _paper_ramps(),
    "cold_start": _cold_start(),
}


# Top-level keys of a profile TOML (docs/profiles.md); ``step`` is the [[step]] list.
PROFILE_KEYS = ("name", "description", "ambient_c", "step")
_REMOVED = {
    "safe_setpoint_c": "the safe state belongs to the bench: set [safe_state] setpoint_c "
    "in BENCH.toml (docs/bench-config.md)",
}


def _number(v: Any, what: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ValueError(f"{what} = {v!r}: expected a number")
    if not math.isfinite(v):
        raise ValueError(f"{what} = {v!r}: expected a finite number")
    return float(v)


def profile_from_dict(d: dict[str, Any], source: str = "<dict>") -> Profile:
    """Build a profile from the TOML layout (docs/profiles.md); unknown keys are errors."""
    for k in d:
        if k in _REMOVED:
            raise InputError(source, f"{k} is not a profile key: {_REMOVED[k]}")
    unknown = sorted(set(d) - set(PROFILE_KEYS))
    if unknown:
        raise InputError(
            source, f"unknown key(s) {unknown} (a profile has {', '.join(PROFILE_KEYS)})"
        )
    try:
        raw_steps = d["step"]
        if not isinstance(raw_steps, list) or not raw_steps:
            raise InputError(source, "profile needs a non-empty [[step]] list")
        known = [f for f in Step.__dataclass_fields__]
        steps = []
        for i, sd in enumerate(raw_steps):
            if not isinstance(sd, dict):
                raise InputError(source, f"step {i + 1}: must be a [[step]] table")
            unknown = sorted(set(sd) - set(known))
            if unknown:
                has = ", ".join(known)
                raise InputError(
                    source, f"step {i + 1}: unknown key(s) {unknown} (a step has {has})"
                )
            missing = [k for k in ("setpoint_c", "duration_s") if k not in sd]
            if missing:
                raise InputError(source, f"step {i + 1}: {', '.join(missing)} required")
            kw = {
                k: (str(v) if k == "label" else _number(v, f"step {i + 1}: {k}"))
                for k, v in sd.items()
            }
            try:
                steps.append(Step(**kw))
            except ValueError as e:
                raise InputError(source, f"step {i + 1}: {e}") from None
        return Profile(
            name=str(d.get("name", Path(source).stem)),
            steps=tuple(steps),
            ambient_c=_number(d.get("ambient_c", 25.0), "ambient_c"),
            description=str(d.get("description", "")),
        )
    except InputError:
        raise
    except KeyError as e:
        raise InputError(source, f"profile is missing {e.args[0]!r}") from None
    except (TypeError, ValueError) as e:
        raise InputError(source, f"bad profile: {e}") from None


def load_profile(spec: str | os.PathLike[str]) -> Profile:
    """A built-in profile (``BUILTIN``: paper, short, quick, paper_ramps, cold_start) or a
    profile TOML."""
    s = str(spec)
    if s in BUILTIN:
        return BUILTIN[s]
    p = Path(s)
    if p.suffix.lower() != ".toml":
        raise InputError(s, f"unknown profile (built in: {', '.join(BUILTIN)}; or a .toml file)")
    return profile_from_dict(read_toml(s, "profile file"), s)
