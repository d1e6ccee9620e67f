"""``gyrolab compensate --config FILE.toml``: the model settings from a TOML file.

Every field of :class:`~gyrolab.compensation.pipeline.PipelineConfig` is a top-level key of
the same name (documented in docs/compensation.md, "Configuration file"), plus ``seed``.
Values are checked against the field's type (TOML arrays for tuples, integers accepted where
a float is expected), against the allowed names of the keys that choose a method
(:data:`CHOICES`) and against positivity where a count or a duration is meant
(:data:`POSITIVE`). An unknown key, a wrong type or a bad value is an
:class:`~gyrolab.errors.InputError` naming the file and the key (one line, exit 2). A key
added to ``PipelineConfig`` is a config key at once; only a constraint on its values needs
a line here.

The file is read through :mod:`gyrolab.tomlfile`, the project's one TOML reader.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from pathlib import Path
from typing import Any

from gyrolab.errors import InputError

#: Keys that are not PipelineConfig fields.
EXTRA_KEYS = ("seed",)


def _choices() -> dict[str, tuple[str, ...]]:
    from gyrolab.compensation.fitness import CRITERIA
    from gyrolab.compensation.gabp import OPTIMIZERS
    from gyrolab.compensation.pipeline import DRIFT_MODELS

    return {
        "drift_model": DRIFT_MODELS,
        "bp_optimizer": OPTIMIZERS,
        "vmd_fitness": tuple(CRITERIA),
        "flp_criterion": ("aic", "mdl"),
        "baselines": ("poly", "bp"),  # each element
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
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise InputError(path, f"{key} must be a string, not {value!r}")
        return value
    raise InputError(path, f"{key}: values of type {_type_name(tp)} cannot be set from a file")


def _check_value(path: str, key: str, value: Any) -> None:
    choices = _choices().get(key)
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
    data: dict[str, Any], base: Any = None, path: str = "config"
) -> tuple[Any, int | None]:
    """``(PipelineConfig, seed or None)`` from a parsed TOML table, starting from ``base``
    (default: the pipeline's defaults). Errors name ``path``."""
    from gyrolab.compensation.pipeline import PipelineConfig

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


def load_config(path: str | Path, base: Any = None) -> tuple[Any, int | None]:
    """Read FILE.toml → ``(PipelineConfig, seed or None)`` (see :func:`config_from_dict`)."""
    from gyrolab.tomlfile import read_toml

    return config_from_dict(read_toml(path, "config file"), base, str(path))


def resolve_config(path: str | None, base: Any, cli_seed: int | None) -> tuple[Any, int]:
    """The configuration and seed ``gyrolab compensate`` runs with: ``base`` (the
    pipeline's defaults) overridden by the file, the file's seed by ``--seed``."""
    cfg, seed = (base, None) if path is None else load_config(path, base)
    if cli_seed is not None:
        seed = cli_seed
    return cfg, 0 if seed is None else int(seed)
