"""The registry of drift-model families and of their exported kinds.

A family module (:mod:`gyrolab.compensation.drift_model` says what it implements)
declares ``FAMILIES`` (its :class:`~gyrolab.compensation.drift_model.Family` entries) and
``KINDS`` (its :class:`~gyrolab.compensation.drift_model.SpecKind` entries); adding it to
:data:`MODULES` below makes it a family of ``gyrolab compensate`` (the key
``causal_families`` of ``--config``), loadable from a model directory, and exportable
(``gyrolab export --format json|c``) — nothing else changes (docs/compensation.md,
"Adding a drift-model family"). :func:`register` does the same at run time (the test
``tests/test_adding_a_drift_model.py`` defines a family in the test alone).

Lookups by name: :func:`family` (a family in the selection and in model.json's
``causal_model.family``), :func:`spec_kind` (an exported ``MODEL``'s ``kind``).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from gyrolab.compensation import causal_models, pi_models, temperature_model
from gyrolab.compensation.drift_model import Family, SpecKind

#: The built-in family modules: each declares FAMILIES and KINDS.
MODULES = (causal_models, pi_models, temperature_model)

_FAMILIES: dict[str, Family] = {}
_KINDS: dict[str, SpecKind] = {}


def register(families: Iterable[Family] = (), kinds: Iterable[SpecKind] = ()) -> None:
    """Add families and exported kinds (a name registered twice is a ``ValueError``)."""
    for f in families:
        if f.name in _FAMILIES:
            raise ValueError(f"drift-model family {f.name!r} is already registered")
        _FAMILIES[f.name] = f
    for k in kinds:
        if k.kind in _KINDS:
            raise ValueError(f"exported model kind {k.kind!r} is already registered")
        _KINDS[k.kind] = k


def unregister(families: Iterable[Family] = (), kinds: Iterable[SpecKind] = ()) -> None:
    """Remove what :func:`register` added (a test's own family)."""
    for f in families:
        _FAMILIES.pop(f.name, None)
    for k in kinds:
        _KINDS.pop(k.kind, None)


for _m in MODULES:
    register(getattr(_m, "FAMILIES", ()), _m.KINDS)


def names() -> tuple[str, ...]:
    """Every registered family, simplest first (the selection's tie order)."""
    return tuple(sorted(_FAMILIES, key=lambda n: (_FAMILIES[n].rank, n)))


def _lookup(table: dict[str, Any], name: str, what: str) -> Any:
    try:
        return table[name]
    except KeyError:
        raise ValueError(f"unknown {what} {name!r} (known: {', '.join(sorted(table))})") from None


def family(name: str) -> Family:
    """The family ``name`` (``ValueError`` naming the known ones when there is none)."""
    return _lookup(_FAMILIES, name, "drift-model family")


def spec_kind(kind: str) -> SpecKind:
    """The exported kind ``kind`` (``ValueError`` naming the known ones)."""
    return _lookup(_KINDS, kind, "exported model kind")


__all__ = ["MODULES", "family", "names", "register", "spec_kind", "unregister"]
