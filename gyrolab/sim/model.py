"""The simulator model (``SIM_MODEL.toml``): thermal parameters, sensors, effects.

Layout (docs/sim-model.md)::

    format = "gyrolab-sim-model/1"
    [thermal]            # ThermalParams fields, SI units
    air_tau_s = 240.0
    ...
    [sensors]            # ADC and multimeter
    adc_bits = 24
    adc_vref_v = 2.5
    adc_gain_v_per_dps = 0.01
    adc_offset_v = 0.0
    dmm_noise_ohm = 0.002
    [[effect]]           # one table per effect, in order
    name = "bias_poly"
    c0 = 0.02
    ...

Missing keys take their defaults; unknown effects, unknown keys and bad values are an
:class:`~gyrolab.errors.InputError` naming the file.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import tomli_w

from gyrolab.errors import InputError
from gyrolab.sim.effects import EFFECTS
from gyrolab.sim.sensors import AdcModel
from gyrolab.sim.thermal import ThermalParams
from gyrolab.tomlfile import read_toml

FORMAT = "gyrolab-sim-model/1"


@dataclass(frozen=True)
class SensorParams:
    """The gyro ADC and the 4-wire multimeter reading the PT100."""

    adc: AdcModel = field(default_factory=AdcModel)
    dmm_noise_ohm: float = 0.002  # 1σ reading noise, Ω (≈ 5 mK on a PT100)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.dmm_noise_ohm) and self.dmm_noise_ohm >= 0):
            raise ValueError("sensors dmm_noise_ohm must be >= 0")

    def to_dict(self) -> dict[str, Any]:
        return {
            "adc_bits": int(self.adc.bits),
            "adc_vref_v": self.adc.vref_v,
            "adc_gain_v_per_dps": self.adc.gain_v_per_dps,
            "adc_offset_v": self.adc.offset_v,
            "dmm_noise_ohm": self.dmm_noise_ohm,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SensorParams:
        known = {"adc_bits", "adc_vref_v", "adc_gain_v_per_dps", "adc_offset_v", "dmm_noise_ohm"}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown [sensors] key(s) {sorted(unknown)}")
        for k, v in d.items():
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ValueError(f"sensors {k} must be a number")
        base = cls()
        adc = AdcModel(
            bits=int(d.get("adc_bits", base.adc.bits)),
            vref_v=float(d.get("adc_vref_v", base.adc.vref_v)),
            gain_v_per_dps=float(d.get("adc_gain_v_per_dps", base.adc.gain_v_per_dps)),
            offset_v=float(d.get("adc_offset_v", base.adc.offset_v)),
        )
        return cls(adc=adc, dmm_noise_ohm=float(d.get("dmm_noise_ohm", base.dmm_noise_ohm)))


@dataclass(frozen=True)
class EffectSpec:
    """One effect of the model: its vocabulary name and full parameter set."""

    name: str
    params: dict[str, float]


def make_effect_spec(name: str, params: dict[str, Any] | None = None) -> EffectSpec:
    """Validate ``name`` and ``params`` (missing ones take defaults). ValueError if bad."""
    cls = EFFECTS.get(name)
    if cls is None:
        raise ValueError(f"unknown effect {name!r} (known: {', '.join(EFFECTS)})")
    params = dict(params or {})
    unknown = set(params) - set(cls.PARAMS)
    if unknown:
        raise ValueError(
            f"effect {name}: unknown parameter(s) {sorted(unknown)} (has: {', '.join(cls.PARAMS)})"
        )
    full = {
        k: spec.validate(name, k, params.get(k, spec.default)) for k, spec in cls.PARAMS.items()
    }
    return EffectSpec(name, full)


@dataclass(frozen=True)
class SimModel:
    """Thermal model + sensors + the ordered list of effects."""

    thermal: ThermalParams = field(default_factory=ThermalParams)
    sensors: SensorParams = field(default_factory=SensorParams)
    effects: tuple[EffectSpec, ...] = ()

    def effect_names(self) -> list[str]:
        return [e.name for e in self.effects]

    def has(self, name: str) -> bool:
        return name in self.effect_names()

    def get(self, name: str) -> EffectSpec | None:
        return next((e for e in self.effects if e.name == name), None)

    def with_effect(self, name: str, **params: Any) -> SimModel:
        """Add ``name`` (appended) or, if present, update the given parameters of it."""
        cur = self.get(name)
        if cur is None:
            return replace(self, effects=self.effects + (make_effect_spec(name, params),))
        merged = {**cur.params, **params}
        new = make_effect_spec(name, merged)
        return replace(self, effects=tuple(new if e is cur else e for e in self.effects))

    def without_effect(self, name: str) -> SimModel:
        return replace(self, effects=tuple(e for e in self.effects if e.name != name))

    def with_thermal(self, **params: Any) -> SimModel:
        return replace(self, thermal=replace(self.thermal, **params))

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "thermal": self.thermal.to_dict(),
            "sensors": self.sensors.to_dict(),
            "effect": [{"name": e.name, **e.params} for e in self.effects],
        }

    def to_toml(self) -> str:
        return tomli_w.dumps(self.to_dict())

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SimModel:
        """Build from the TOML layout; ValueError on anything unknown or bad."""
        unknown = set(d) - {"format", "thermal", "sensors", "effect"}
        if unknown:
            raise ValueError(f"unknown top-level key(s) {sorted(unknown)}")
        if d.get("format", FORMAT) != FORMAT:
            raise ValueError(f"unsupported format {d.get('format')!r} (want {FORMAT!r})")
        th = d.get("thermal", {})
        known_th = {f.name for f in fields(ThermalParams)}
        if set(th) - known_th:
            raise ValueError(f"unknown [thermal] key(s) {sorted(set(th) - known_th)}")
        for k, v in th.items():
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ValueError(f"thermal {k} must be a number")
        thermal = ThermalParams(**{k: float(v) for k, v in th.items()})
        sensors = SensorParams.from_dict(d.get("sensors", {}))
        effects = []
        raw = d.get("effect", [])
        if not isinstance(raw, list):
            raise ValueError("[[effect]] must be an array of tables")
        for i, e in enumerate(raw):
            if not isinstance(e, dict) or "name" not in e:
                raise ValueError(f"effect {i + 1} has no name")
            params = {k: v for k, v in e.items() if k != "name"}
            effects.append(make_effect_spec(str(e["name"]), params))
        return cls(thermal=thermal, sensors=sensors, effects=tuple(effects))


def nominal_model() -> SimModel:
    """The simulator's nominal model (docs/sim-model.md): first-order oven, ``bias_poly``, ``arw``,
    ``bias_instability`` — with defaults tuned to the paper's bench."""
    return SimModel(
        effects=(
            make_effect_spec("bias_poly"),
            make_effect_spec("arw"),
            make_effect_spec("bias_instability"),
        )
    )


def load_sim_model(path: str | os.PathLike[str]) -> SimModel:
    """Read a ``SIM_MODEL.toml``; InputError naming the file on any problem."""
    p = Path(path)
    d = read_toml(p, "model file")
    try:
        return SimModel.from_dict(d)
    except (ValueError, TypeError) as e:
        raise InputError(p, str(e)) from None


def parse_effect_arg(text: str) -> tuple[str, dict[str, float]]:
    """``NAME[:k=v,...]`` → (name, params). ValueError on bad syntax or non-numeric values."""
    name, _, rest = text.partition(":")
    name = name.strip()
    params: dict[str, float] = {}
    if rest.strip():
        for item in rest.split(","):
            k, eq, v = item.partition("=")
            if not eq or not k.strip():
                raise ValueError(f"bad parameter {item!r} in --effect {text!r} (want k=v)")
            try:
                params[k.strip()] = float(v)
            except ValueError:
                raise ValueError(
                    f"--effect {text!r}: {k.strip()} = {v!r} is not a number"
                ) from None
    return name, params


def apply_effect_args(model: SimModel, specs: list[str]) -> SimModel:
    """Apply ``--effect`` arguments (add, or update the parameters of a present effect)."""
    for s in specs:
        name, params = parse_effect_arg(s)
        model = model.with_effect(name, **params)
    return model
