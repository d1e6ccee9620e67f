"""The settings of the compensation model: :class:`PipelineConfig` and its TOML file.

:class:`PipelineConfig` holds every setting of fit and apply (defaults follow the paper
where it says); :data:`DEFAULT_CONFIG` is what ``gyrolab compensate`` uses.

``gyrolab compensate --config FILE.toml``: every field of :class:`PipelineConfig` is a
top-level key of the same name (documented in docs/compensation.md, "Configuration file"),
plus ``seed``. Values are checked against the field's type (TOML arrays for tuples, integers
accepted where a float is expected), against the allowed names of the keys that choose a
method (:data:`CHOICES`) and against positivity where a count or a duration is meant
(:data:`POSITIVE`). An unknown key, a wrong type or a bad value is an
:class:`~gyrolab.errors.InputError` naming the file and the key (one line, exit 2). A key
added to ``PipelineConfig`` is a config key at once; only a constraint on its values needs
a line here.

The file is read through :mod:`gyrolab.tomlfile`, the project's one TOML reader.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from gyrolab.compensation import families
from gyrolab.compensation.fitness import CRITERIA
from gyrolab.compensation.gabp import OPTIMIZERS, BPConfig, GAConfig
from gyrolab.compensation.structured import DEFAULT_LAG_CRITERION, LAG_CRITERIA
from gyrolab.compensation.temperature_model import FITS
from gyrolab.errors import InputError
from gyrolab.numerics.averaging import PAPER_BLOCK_S
from gyrolab.tomlfile import read_toml

DRIFT_MODELS = tuple(FITS)  # the drift model f(T) of PipelineConfig.drift_model


@dataclass(frozen=True)
class PipelineConfig:
    """Settings of the hybrid model; defaults follow the paper where it says."""

    block_s: float = PAPER_BLOCK_S
    use_dtdt: bool = False  # paper: temperature only
    dtdt_window_s: float = 300.0
    hidden: int = 8
    drift_model: str = "gabp"  # the drift model f(T): "gabp" (paper), "bp", "poly"
    ga_population: int = 40
    ga_generations: int = 40
    bp_optimizer: str = "lbfgs"  # "lbfgs" or the paper's plain gradient descent "gd"
    bp_max_iter: int = 400
    bp_learning_rate: float = 0.01  # gd only (paper prints none: traingd's default)
    bp_epochs: int = 1000  # gd only
    vmd_fitness: str = "drift_separation"  # GPSO criterion, fitness.CRITERIA
    k_range: tuple[int, int] = (3, 11)  # paper §4.2
    alpha_range: tuple[float, float] = (50.0, 5000.0)  # paper §4.2
    gpso_population: int = 50  # paper §4.2
    gpso_generations: int = 30
    mpe_scale: int = 12  # paper §4.2
    mpe_order: int = 4
    mpe_delay: int = 1
    mpe_noise_min: float = 0.85  # mpe.DEFAULT_NOISE_MIN
    mpe_drift_max: float = 0.5  # mpe.DEFAULT_DRIFT_MAX
    vmd_K: int | None = None  # fixed (K, alpha): skip the GPSO search
    vmd_alpha: float | None = None
    flp_max_order: int = 32
    flp_criterion: str = "aic"
    min_blocks: int = 256
    min_temp_span_c: float = 2.0
    baselines: tuple[str, ...] = ("poly", "bp")
    # causal drift-model families compared by CV inside the calibration run (causal.py)
    causal_families: tuple[str, ...] = ("poly", "structured", "bp", "gabp")
    # how the structured families choose the die lag: "profile" (the blocked CV, then
    # profile least squares for the model the CV chose; the families are compared at
    # the CV's lag) or "cv" (the blocked CV only): structured.LAG_CRITERIA
    causal_lag_criterion: str = DEFAULT_LAG_CRITERION

    def ga(self) -> GAConfig:
        return GAConfig(population=self.ga_population, generations=self.ga_generations)

    def bp(self) -> BPConfig:
        return BPConfig(
            hidden=self.hidden,
            max_iter=self.bp_max_iter,
            optimizer=self.bp_optimizer,
            learning_rate=self.bp_learning_rate,
            epochs=self.bp_epochs,
        )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PipelineConfig:
        known = {k: v for k, v in d.items() if k in cls.__dataclass_fields__}
        for k in ("k_range", "alpha_range", "baselines", "causal_families"):
            if k in known:
                known[k] = tuple(known[k])
        return cls(**known)


DEFAULT_CONFIG = PipelineConfig()  # what `gyrolab compensate` uses


#: Keys that are not PipelineConfig fields.
EXTRA_KEYS = ("seed",)


#: Allowed values of the keys that choose a method (each element for tuples);
#: ``causal_families``: the registered drift-model families
#: (:mod:`gyrolab.compensation.families`, which a test or an extension may add to).
CHOICES: dict[str, Callable[[], tuple[str, ...]]] = {
    "drift_model": lambda: DRIFT_MODELS,
    "bp_optimizer": lambda: OPTIMIZERS,
    "vmd_fitness": lambda: tuple(CRITERIA),
    "flp_criterion": lambda: ("aic", "mdl"),
    "baselines": lambda: ("poly", "bp"),  # each element
    "causal_families": families.names,  # each element
    "causal_lag_criterion": lambda: LAG_CRITERIA,
}


#: Keys whose value (each element for tuples) must be > 0.
POSITIVE = {
    "block_s",
    "dtdt_window_s",
    "hidden",
    "ga_population",
    "ga_generations",
    "bp_max_iter",
    "bp_learning_rate",
    "bp_epochs",
    "k_range",
    "alpha_range",
    "gpso_population",
    "gpso_generations",
    "mpe_scale",
    "mpe_order",
    "mpe_delay",
    "vmd_K",
    "vmd_alpha",
    "flp_max_order",
    "min_blocks",
}


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", str(tp))


def _coerce(path: str, key: str, value: Any, tp: Any) -> Any:
    """``value`` as type ``tp`` (a resolved annotation) or InputError."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        errors = []
        for a in inner:
            try:
                return _coerce(path, key, value, a)
            except InputError as e:
                errors.append(e)
        raise errors[0]
    if origin is tuple:
        if not isinstance(value, list):
            raise InputError(path, f"{key} must be an array, not {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(path, key, v, args[0]) for v in value)
        if len(value) != len(args):
            raise InputError(path, f"{key} must have {len(args)} elements, not {len(value)}")
        return tuple(_coerce(path, key, v, a) for v, a in zip(value, args, strict=True))
    if tp is bool:
        if not isinstance(value, bool):
            raise InputError(path, f"{key} must be true or false, not {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise InputError(path, f"{key} must be an integer, not {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InputError(path, f"{key} must be a number, not {value!r}")
        if not math.isfinite(value):  # TOML has inf and nan; no setting means either
            raise InputError(path, f"{key} must be a finite number, not {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise InputError(path, f"{key} must be a string, not {value!r}")
        return value
    raise InputError(path, f"{key}: values of type {_type_name(tp)} cannot be set from a file")


def _check_value(path: str, key: str, value: Any) -> None:
    choices = CHOICES[key]() if key in CHOICES else None
    items = value if isinstance(value, tuple) else (value,)
    if choices is not None:
        for v in items:
            if v not in choices:
                raise InputError(path, f"{key} = {v!r} is not one of {', '.join(choices)}")
    if key in POSITIVE:
        for v in items:
            if v is not None and not v > 0:
                raise InputError(path, f"{key} must be positive, not {v!r}")


def config_from_dict(
    data: dict[str, Any], base: PipelineConfig | None = None, path: str = "config"
) -> tuple[PipelineConfig, int | None]:
    """``(PipelineConfig, seed or None)`` from a parsed TOML table, starting from ``base``
    (default: :class:`PipelineConfig`'s defaults). Errors name ``path``."""
    base = PipelineConfig() if base is None else base
    hints = typing.get_type_hints(PipelineConfig)
    fields = {f.name for f in dataclasses.fields(PipelineConfig)}
    changes: dict[str, Any] = {}
    seed = None
    for key, value in data.items():
        if key == "seed":
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise InputError(path, f"seed must be a non-negative integer, not {value!r}")
            seed = value
            continue
        if key not in fields:
            known = ", ".join(sorted(fields | set(EXTRA_KEYS)))
            raise InputError(path, f"unknown key {key!r} (known keys: {known})")
        v = _coerce(path, key, value, hints[key])
        _check_value(path, key, v)
        changes[key] = v
    cfg = dataclasses.replace(base, **changes)
    lo, hi = cfg.k_range
    if lo > hi or cfg.alpha_range[0] > cfg.alpha_range[1]:
        raise InputError(path, "k_range and alpha_range must be [low, high]")
    if (cfg.vmd_K is None) != (cfg.vmd_alpha is None):
        raise InputError(path, "vmd_K and vmd_alpha fix (K, alpha) together: give both or none")
    return cfg, seed


def check_config_dict(data: dict[str, Any], path: str = "config") -> None:
    """Check a stored configuration (model.json's ``config``) the way a file's keys are
    checked (type, allowed names, positivity); null where the field is optional is
    allowed, a missing key is its default, and an unknown one (written by another
    gyrolab) is ignored, as :meth:`PipelineConfig.from_dict` does."""
    hints = typing.get_type_hints(PipelineConfig)
    for key, value in data.items():
        if key not in hints:
            continue
        if value is None and type(None) in typing.get_args(hints[key]):
            continue
        _check_value(path, key, _coerce(path, key, value, hints[key]))


def load_config(
    path: str | Path, base: PipelineConfig | None = None
) -> tuple[PipelineConfig, int | None]:
    """Read FILE.toml → ``(PipelineConfig, seed or None)`` (see :func:`config_from_dict`)."""
    return config_from_dict(read_toml(path, "config file"), base, str(path))


def resolve_config(
    path: str | None, base: PipelineConfig, cli_seed: int | None
) -> tuple[PipelineConfig, int]:
    """The configuration and seed ``gyrolab compensate`` runs with: ``base`` (e.g.
    :data:`DEFAULT_CONFIG`) overridden by the file, the file's seed by ``--seed``."""
    cfg, seed = (base, None) if path is None else load_config(path, base)
    if cli_seed is not None:
        seed = cli_seed
    return cfg, 0 if seed is None else int(seed)
