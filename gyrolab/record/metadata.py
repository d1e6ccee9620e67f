"""The typed ``run`` and ``bench`` metadata records: the one metadata schema of a recording.

Both producers (``gyrolab simulate``, ``gyrolab acquire``) build a :class:`RunMetadata` and
a :class:`BenchMetadata` and hand them to :class:`~gyrolab.record.writer.RecordingWriter`,
so their files carry the same keys (docs/recording-format.md, "Metadata records", is the
contract). Readers go through :func:`normalise_run` / :func:`normalise_bench` (the first
step of each ``from_dict``), which rewrite what older files wrote, so every recording
already written reads in the documented shape:

- ``run.source`` ``"simulation"`` → ``"simulate"``;
- ``run.profile`` as the profile's name with the table in ``run.profile_definition`` →
  ``run.profile`` = the table (a bare name → ``{"name": …}``);
- ``bench.adc.rate_hz`` (and ``bench.units.<serial>.adc.rate_hz``) →
  ``sample_rate_hz``, the BENCH.toml ``[rate_stream]`` (formerly ``[adc]``) key the acquisition
  always wrote;
- ``bench.bench`` (the simulator's bench name) → ``bench.name``, ``simulated`` true for
  ``"sim"``.

Keys a type does not know are kept in ``extra`` and written back, so nothing read is lost.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

from gyrolab import __version__
from gyrolab.record.format import FORMAT_VERSION


def normalise_run(d: Mapping[str, Any]) -> dict[str, Any]:
    """``d`` with the older spellings of the ``run`` record rewritten (module docstring);
    nothing added, nothing else changed."""
    out = dict(d)
    if out.get("source") == "simulation":
        out["source"] = "simulate"
    definition = out.pop("profile_definition", None)
    if isinstance(definition, dict):
        out["profile"] = definition
    elif isinstance(out.get("profile"), str):
        out["profile"] = {"name": out["profile"]}
    return out


def _normalise_adc(adc: Any) -> Any:
    if isinstance(adc, dict) and "rate_hz" in adc and "sample_rate_hz" not in adc:
        adc = {("sample_rate_hz" if k == "rate_hz" else k): v for k, v in adc.items()}
    return adc


def normalise_bench(d: Mapping[str, Any]) -> dict[str, Any]:
    """``d`` with the older spellings of the ``bench`` record rewritten (module docstring)."""
    out = dict(d)
    if "name" not in out and isinstance(out.get("bench"), str):
        out["name"] = out.pop("bench")
        if out["name"] == "sim":
            out.setdefault("simulated", True)
    if "adc" in out:
        out["adc"] = _normalise_adc(out["adc"])
    units = out.get("units")
    if isinstance(units, dict):
        out["units"] = {
            s: {**u, "adc": _normalise_adc(u["adc"])} if isinstance(u, dict) and "adc" in u else u
            for s, u in units.items()
        }
    return out


def _split(cls: type, d: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """``d`` split into the keyword arguments of dataclass ``cls`` and the rest."""
    names = {f.name for f in fields(cls)} - {"extra"}
    known = {k: v for k, v in d.items() if k in names}
    return known, {k: v for k, v in d.items() if k not in names}


@dataclass
class RunMetadata:
    """The ``run`` record: what was run, when, by whom, on what."""

    source: str  # "simulate" | "acquire": the producer
    start_time: str  # ISO 8601
    profile: dict[str, Any]  # the profile as a table (Profile.to_dict())
    operator: str = ""
    unit_serial: str = ""
    unit_model: str = ""
    notes: str = ""
    bench_name: str = ""
    seed: int | None = None  # simulated runs: the noise seed
    speed: float | str | None = None  # simulated runs: time factor, "max" unpaced
    format_version: str = FORMAT_VERSION
    software_version: str = __version__
    axes: int = 1  # written only for a multi-axis unit
    units: list[str] | None = None  # the multi-unit layout's serials (the writer sets it)
    # An acquired run (docs/recording-format.md, "Segments"): its id, this file's segment
    # number (1, 2, …), and for a continuation the segment it continues
    # (``{"file", "segment", "run_id"}``) and where (``{"after_t", "at_t", "step"}``).
    run_id: str | None = None
    segment: int | None = None
    previous_segment: dict[str, Any] | None = None
    resumed: dict[str, Any] | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "format_version": self.format_version,
            "software_version": self.software_version,
            "source": self.source,
            "start_time": self.start_time,
            "operator": self.operator,
            "unit_serial": self.unit_serial,
            "unit_model": self.unit_model,
            "notes": self.notes,
            "bench_name": self.bench_name,
            "profile": self.profile,
            "seed": self.seed,
            "speed": self.speed,
        }
        # Layout keys appear only where the layout needs them (a single-axis, single-unit
        # file has neither, as before they existed).
        if self.axes > 1:
            d["axes"] = self.axes
        if self.units is not None:
            d["units"] = list(self.units)
        for key in ("run_id", "segment", "previous_segment", "resumed"):
            if getattr(self, key) is not None:  # absent before segments existed, as then
                d[key] = getattr(self, key)
        d.update(self.extra)
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> RunMetadata:
        """From a ``run`` record as any gyrolab wrote it (older spellings normalised)."""
        known, extra = _split(cls, normalise_run(d))
        known.setdefault("source", "")
        known.setdefault("start_time", "")
        known.setdefault("profile", {})
        return cls(**known, extra=extra)


@dataclass
class BenchMetadata:
    """The ``bench`` record: the instruments (each one's ``describe()``) and the bench's
    limits, safe state and recorder settings (``None`` where they do not apply: a
    ``gyrolab simulate`` run has no bench limits, safe state or recorder table)."""

    name: str
    simulated: bool
    multimeter: dict[str, Any] | None = None
    oven: dict[str, Any] | None = None
    adc: dict[str, Any] | None = None  # driver, sample_rate_hz, bits, vref_v, … (docs)
    limits: dict[str, Any] | None = None
    safe_state: dict[str, Any] | None = None
    recorder: dict[str, Any] | None = None
    units: dict[str, dict[str, Any]] | None = None  # multi-unit: per-unit calibration
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "name": self.name,
            "simulated": self.simulated,
            "multimeter": self.multimeter,
            "oven": self.oven,
            "adc": self.adc,
            "limits": self.limits,
            "safe_state": self.safe_state,
            "recorder": self.recorder,
        }
        if self.units is not None:
            d["units"] = self.units
        d.update(self.extra)
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> BenchMetadata:
        """From a ``bench`` record as any gyrolab wrote it (older spellings normalised)."""
        known, extra = _split(cls, normalise_bench(d))
        known.setdefault("name", "")
        known.setdefault("simulated", False)
        return cls(**known, extra=extra)

    def sample_rate_hz(self, unit: str | None = None) -> float | None:
        """The gyro ADC's sample rate (Hz): the bench's, or unit ``unit``'s in a
        multi-unit recording (falling back to the bench's); None when not recorded."""
        adc = self.adc
        if unit is not None and self.units and isinstance(self.units.get(unit), dict):
            adc = self.units[unit].get("adc", adc)
        rate = adc.get("sample_rate_hz") if isinstance(adc, dict) else None
        return float(rate) if isinstance(rate, (int, float)) else None
