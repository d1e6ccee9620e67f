"""The candidate catalogue as the workflow reads it: every effect's declaration
(:mod:`gyrolab.sim.candidate`, beside its physics in ``sim/effects.py``), looked up by name.

Nothing here names an effect: the vocabulary is whatever ``sim.effects.EFFECTS`` holds when
a function is called, so an effect registered later (a test's, a plug-in's) is a candidate
too.
"""

from __future__ import annotations

from typing import Any

from gyrolab.sim.candidate import Candidate, GyroTerms
from gyrolab.sim.effects import EFFECTS


def candidate(name: str) -> Candidate | None:
    """How ``name`` is looked for (None: never a candidate, e.g. ``bias_poly``)."""
    cls = EFFECTS.get(name)
    return None if cls is None else cls.candidate


def on_channel(channel: str) -> list[str]:
    """Effects scored on ``channel``, in vocabulary order."""
    return [n for n, c in EFFECTS.items() if c.candidate and c.candidate.channel == channel]


def gap_of(name: str) -> str:
    """The gap metric that belongs to ``name`` (it must shrink when ``name`` is added)."""
    c = candidate(name)
    return c.gap if c is not None else "lf_residual_rms_dps"


def is_gyro_term(name: str) -> bool:
    """Whether ``name`` is a deterministic gyro term (has fit terms)."""
    cls = EFFECTS.get(name)
    return cls is not None and cls.terms is not None


def gyro_terms() -> list[str]:
    """Every deterministic gyro term (``bias_poly`` and ``thermal_lag`` included)."""
    return [n for n in EFFECTS if is_gyro_term(n)]


def terms(name: str) -> GyroTerms:
    """The fit terms of gyro term ``name``."""
    t = EFFECTS[name].terms
    if t is None:
        raise KeyError(f"{name} is not a gyro term")
    return t


def shape_of(name: str) -> str | None:
    """The nonlinear (scanned) simulator parameter of gyro term ``name``, or None."""
    return terms(name).shape if is_gyro_term(name) else None


def form_key(name: str) -> str | None:
    """The ``theta`` key of ``name``'s wider form (``<name>.<param>``), or None."""
    w = terms(name).wider if is_gyro_term(name) else None
    return None if w is None else f"{name}.{w.param}"


def theta_owner(key: str) -> str:
    """The effect a ``theta`` key belongs to (its own name, or ``<name>.<param>``)."""
    return key.split(".")[0]


def shape_values(name: str, theta: dict[str, float]) -> dict[str, float]:
    """Shape parameters of gyro term ``name`` (simulator names) from a structure's
    ``theta``: the held ones, the scanned one (``theta[name]``) and the wider form's
    (``theta["<name>.<param>"]``, or its neutral value when the plain form is used)."""
    t = terms(name)
    out = dict(t.fixed)
    if t.shape is not None:
        out[t.shape] = theta[name]
    if t.wider is not None:
        key = f"{name}.{t.wider.param}"
        if key in theta:
            out[t.wider.param] = theta[key]
        elif t.wider.neutral is not None:
            out[t.wider.param] = t.wider.neutral
    return out


def limit_entry(
    name: str, value: float | None, method: str, at: dict[str, float] | None = None
) -> dict[str, Any]:
    """A ``detection_limits`` entry of ``discrepancy.json``: the parameter the effect
    declares its limit in, its unit, the value (None: not computable here), how it was
    computed, and the reference shape it is stated at (``at``: the effect's declared one,
    or the channel's)."""
    cls = EFFECTS[name]
    c = cls.candidate
    if c is None or c.limit is None:
        raise KeyError(f"{name} states no detection limit")
    e: dict[str, Any] = {
        "parameter": c.limit,
        "unit": cls.PARAMS[c.limit].unit,
        "limit": value,
        "method": method,
    }
    if at or c.limit_at:
        e["at"] = dict(at or c.limit_at)
    return e
