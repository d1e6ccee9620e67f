"""What ``gyrolab simulate`` does: :func:`simulate_file` (called by :mod:`gyrolab.app.simulate`)."""

from __future__ import annotations

import math
import os

from gyrolab.errors import InputError
from gyrolab.outputs import atomic_file, check_output
from gyrolab.profiles.profile import load_profile
from gyrolab.sampling import DEFAULT_RATE_HZ
from gyrolab.sim.family import unit_family
from gyrolab.sim.model import apply_effect_args, load_sim_model, nominal_model
from gyrolab.sim.simulate import axis_physics, simulate_run

MAX_RATE_HZ = 100_000.0
MAX_UNITS = 256


def simulate_file(
    out: str | os.PathLike[str],
    profile_spec: str,
    *,
    model_path: str | None = None,
    axis_model_paths: tuple[str, ...] = (),
    rate_hz: float = DEFAULT_RATE_HZ,
    seed: int = 0,
    units: int = 1,
    effects: tuple[str, ...] = (),
    force: bool = False,
) -> str:
    """Simulate a run of ``profile_spec`` (paper | short | FILE.toml) into ``out``; returns
    the one-line summary. Everything is validated before anything is written; the
    recording appears atomically."""
    inputs = (profile_spec, model_path, *axis_model_paths)
    check_output(out, force, inputs=inputs, kind="file")
    if not (math.isfinite(rate_hz) and 0 < rate_hz <= MAX_RATE_HZ):
        raise InputError("--rate", f"must be in (0, {MAX_RATE_HZ:g}] Hz, got {rate_hz:g}")
    n_units = units
    if not 1 <= n_units <= MAX_UNITS:
        raise InputError("--units", f"must be 1..{MAX_UNITS}, got {n_units}")
    profile = load_profile(profile_spec)
    model = load_sim_model(model_path) if model_path else nominal_model()
    try:
        model = apply_effect_args(model, list(effects))
    except (ValueError, TypeError) as e:
        raise InputError("--effect", str(e)) from None
    axis_models = [load_sim_model(m) for m in axis_model_paths]
    if len(axis_models) > 2:
        raise InputError("--axis-model", "a unit has at most 3 axes (give it at most twice)")
    try:
        axis_physics(model, axis_models, rate_hz, seed, profile.ambient_c)
    except ValueError as e:
        raise InputError("--axis-model", str(e)) from None
    if axis_models and n_units > 1:
        raise InputError(
            "--units", "multi-axis units (--axis-model) in a multi-unit run are not supported yet"
        )
    family = unit_family(model, n_units, seed) if n_units > 1 else None
    with atomic_file(out, force, inputs=inputs) as tmp:
        summary = simulate_run(
            tmp,
            profile,
            model,
            rate_hz=rate_hz,
            seed=seed,
            axis_models=axis_models,
            units=family,
        )
    return (
        f"wrote {out}: profile {profile.name}, {summary.duration_s / 3600:.2f} h, "
        f"{summary.samples} samples at {rate_hz:g} Hz, seed {seed}, "
        f"effects {', '.join(model.effect_names()) or 'none'}"
        + (f", {1 + len(axis_models)} axes" if axis_models else "")
        + (f", units {', '.join(u.serial for u in family)}" if family else "")
    )
