"""Spec limits for a gyro under test and the verdict of a run against them.

A spec file is flat TOML (read with :func:`gyrolab.tomlfile.read_toml`); every key is
optional, unknown keys and wrong types are refused (``InputError``: one line, exit 2)::

    name = "G-7 acceptance, rev B"
    series = "causal"                      # "raw", "causal" (= "compensated") or "offline"
                                           #  (default: causal when the report has a
                                           #  model, else raw)
    max_bias_stability_deg_per_h = 2.0     # std of the 3.6 s averages
    max_bias_instability_deg_per_h = 0.5   # Allan floor / 0.664
    max_arw_deg_per_sqrt_h = 0.08
    max_drift_pp_deg_per_s = 0.005
    max_rms_deg_per_s = 0.01
    min_temperature_coverage = 0.9         # share of the profile's setpoint span the gyro
                                           #  case reached (0 … 1)
    max_gap_s = 10.0                       # gyro data missing in gaps, seconds
    require_complete = true                # the run ended "complete"
    require_safe_state = true              # the oven's safe state was verified

:func:`evaluate` gives one :class:`Line` per limit (measured value, pass/fail) and the
overall verdict (PASS only when every line passes; a limit whose value could not be
measured fails). The module knows nothing about the report's layout, so a fleet report
can evaluate many runs against one spec.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any

from gyrolab.errors import InputError
from gyrolab.tomlfile import read_toml

#: metric limits: key -> (metrics.json key, label, unit)
METRIC_LIMITS: dict[str, tuple[str, str, str]] = {
    "max_bias_stability_deg_per_h": ("bias_stability_deg_per_h", "bias stability", "°/h"),
    "max_bias_instability_deg_per_h": (
        "bias_instability_deg_per_h",
        "bias instability",
        "°/h",
    ),
    "max_arw_deg_per_sqrt_h": ("arw_deg_per_sqrt_h", "angle random walk", "°/√h"),
    "max_drift_pp_deg_per_s": ("drift_pp_deg_per_s", "drift peak-to-peak", "°/s"),
    "max_rms_deg_per_s": ("rms_deg_per_s", "RMS", "°/s"),
}
#: run limits: key -> (label, unit)
RUN_LIMITS: dict[str, tuple[str, str]] = {
    "min_temperature_coverage": ("temperature coverage (gyro case)", ""),
    "max_gap_s": ("gyro data missing in gaps", "s"),
}
FLAGS: dict[str, str] = {
    "require_complete": "run complete",
    "require_safe_state": "oven safe state verified",
}
#: ``gyrolab fleet`` only: which units its yield counts (docs/fleet.md). By default a unit
#: whose metrics are in-sample (no ``--validate``) or whose model covers less than
#: ``min_calibrated_span_c`` of temperature is marked and not counted.
FLEET_FLAGS = ("allow_in_sample",)
FLEET_LIMITS = ("min_calibrated_span_c",)
DEFAULT_MIN_CALIBRATED_SPAN_C = 30.0
TEXT_KEYS = ("name", "description", "series")
#: ``series`` → (the metrics.json keys that hold it, first present; its name in the verdict).
#: The compensated output is the causal one (what ``gyrolab apply`` writes: raw − d from
#: past temperature readings, full bandwidth; the GA-BP drift model's for a model without
#: a causal part). The paper's offline reconstruction is low-passed and cannot run in real
#: time: a spec judges it only when it names it, ``series = "offline"``.
SERIES: dict[str, tuple[tuple[str, ...], str]] = {
    "raw": (("raw",), "raw"),
    "causal": (("causal", "compensated_drift_only"), "causal"),
    "compensated": (("causal", "compensated_drift_only"), "causal"),
    "offline": (("compensated",), "offline"),
}


@dataclass
class Spec:
    """The limits of a spec file (``None``: not limited)."""

    path: str = ""
    name: str = ""
    description: str = ""
    series: str | None = None
    limits: dict[str, float] = field(default_factory=dict)
    flags: dict[str, bool] = field(default_factory=dict)
    fleet: dict[str, float | bool] = field(default_factory=dict)  # FLEET_FLAGS, FLEET_LIMITS


def load_spec(path: str | os.PathLike[str]) -> Spec:
    """Read and check a spec file; ``InputError`` naming the file and the bad key."""
    d = read_toml(path, "spec file")
    known = set(METRIC_LIMITS) | set(RUN_LIMITS) | set(FLAGS) | set(TEXT_KEYS)
    known |= {*FLEET_FLAGS, *FLEET_LIMITS}
    unknown = sorted(set(d) - known)
    if unknown:
        raise InputError(
            path, f"unknown key(s) {', '.join(unknown)} (known: {', '.join(sorted(known))})"
        )
    spec = Spec(path=str(path))
    for k in TEXT_KEYS:
        if k in d and not isinstance(d[k], str):
            raise InputError(path, f"{k} must be a string")
    spec.name = d.get("name", "")
    spec.description = d.get("description", "")
    spec.series = d.get("series")
    if spec.series is not None and spec.series not in SERIES:
        raise InputError(path, f"series must be one of {', '.join(SERIES)}, not {spec.series!r}")
    for k in (*METRIC_LIMITS, *RUN_LIMITS, *FLEET_LIMITS):
        if k not in d:
            continue
        v = d[k]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise InputError(path, f"{k} must be a number, not {v!r}")
        if v < 0 or (k == "min_temperature_coverage" and v > 1):
            bound = "between 0 and 1" if k == "min_temperature_coverage" else "≥ 0"
            raise InputError(path, f"{k} = {v} must be {bound}")
        (spec.fleet if k in FLEET_LIMITS else spec.limits)[k] = float(v)
    for k in (*FLAGS, *FLEET_FLAGS):
        if k in d:
            if not isinstance(d[k], bool):
                raise InputError(path, f"{k} must be true or false, not {d[k]!r}")
            (spec.fleet if k in FLEET_FLAGS else spec.flags)[k] = d[k]
    return spec


@dataclass
class Line:
    """One limit checked: ``measured`` and ``limit`` formatted for a table; ``unit``: the
    measured value's (the limit carries its own)."""

    quantity: str
    limit: str
    measured: str
    passed: bool
    unit: str = ""

    def text(self) -> str:
        """``quantity: measured unit (limit …) PASS|FAIL``, as the command prints it."""
        value = self.measured + (f" {self.unit}" if self.unit and self.measured != "—" else "")
        return f"{self.quantity}: {value} (limit {self.limit}) {'PASS' if self.passed else 'FAIL'}"


@dataclass
class Verdict:
    spec: Spec
    series: str
    lines: list[Line]

    @property
    def passed(self) -> bool:
        return all(line.passed for line in self.lines)

    @property
    def word(self) -> str:
        return "PASS" if self.passed else "FAIL"

    def summary(self) -> str:
        """``PASS (8 limit(s), metrics on the causal output)``; failing lines named."""
        failed = [line.quantity for line in self.lines if not line.passed]
        what = f"{len(self.lines)} limit(s), metrics on the {self.series} output"
        return f"{self.word} ({what}" + (f"; failed: {', '.join(failed)})" if failed else ")")

    def to_dict(self) -> dict[str, Any]:
        return {
            "spec": self.spec.name or os.path.basename(self.spec.path),
            "series": self.series,
            "verdict": self.word,
            "lines": [vars(line) for line in self.lines],
        }


def _num(x: Any, digits: int = 4) -> str:
    return f"{x:.{digits}g}" if isinstance(x, (int, float)) and math.isfinite(x) else "—"


def series_metrics(spec: Spec, metrics: dict[str, Any], has_model: bool) -> tuple[str, dict]:
    """The output the metric limits apply to: its name (``raw``, ``causal`` or
    ``offline``) and its five metrics from ``metrics`` (``{}`` when the report lacks it).
    Default: the causal output when there is a model, else the raw one."""
    keys, name = SERIES[spec.series or ("causal" if has_model else "raw")]
    found = next((metrics[k] for k in keys if isinstance(metrics.get(k), dict)), {})
    return name, found


def evaluate(
    spec: Spec,
    metrics: dict[str, Any],
    *,
    has_model: bool,
    coverage_fraction: float = math.nan,
    gap_s: float = math.nan,
    complete: bool = False,
    safe_state_ok: bool = False,
) -> Verdict:
    """Check a run against ``spec``.

    ``metrics`` is the report's ``metrics.json`` content (``raw``, ``causal``,
    ``compensated`` (offline) … dicts of the five metrics); the metric limits apply to the
    output :func:`series_metrics` picks (by default the causal output when there is a
    model, else the raw output). A limit on an output the report does not have fails
    ("—" measured).
    """
    series, values = series_metrics(spec, metrics, has_model)
    lines: list[Line] = []
    for key, (mkey, label, unit) in METRIC_LIMITS.items():
        if key in spec.limits:
            v = values.get(mkey)
            ok = isinstance(v, (int, float)) and math.isfinite(v) and v <= spec.limits[key]
            lines.append(
                Line(
                    f"{label} ({series} output)",
                    f"≤ {spec.limits[key]:g} {unit}",
                    _num(v),
                    bool(ok),
                    unit,
                )
            )
    if "min_temperature_coverage" in spec.limits:
        lim = spec.limits["min_temperature_coverage"]
        ok = math.isfinite(coverage_fraction) and coverage_fraction >= lim
        lines.append(
            Line(
                RUN_LIMITS["min_temperature_coverage"][0],
                f"≥ {100 * lim:g} %",
                "—" if not math.isfinite(coverage_fraction) else f"{100 * coverage_fraction:.1f} %",
                bool(ok),
            )
        )
    if "max_gap_s" in spec.limits:
        lim = spec.limits["max_gap_s"]
        ok = math.isfinite(gap_s) and gap_s <= lim
        lines.append(
            Line(RUN_LIMITS["max_gap_s"][0], f"≤ {lim:g} s", _num(gap_s), bool(ok), "s")
        )
    if spec.flags.get("require_complete"):
        lines.append(Line(FLAGS["require_complete"], "required", _yes(complete), complete))
    if spec.flags.get("require_safe_state"):
        lines.append(
            Line(FLAGS["require_safe_state"], "required", _yes(safe_state_ok), safe_state_ok)
        )
    return Verdict(spec, series, lines)


def _yes(b: bool) -> str:
    return "yes" if b else "no"
