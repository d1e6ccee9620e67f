"""The ``gyrolab simulate`` command handler."""

from __future__ import annotations

import argparse
import math
import sys

from gyrolab.errors import InputError
from gyrolab.outputs import atomic_file, check_output
from gyrolab.profiles.profile import load_profile
from gyrolab.sim.family import unit_family
from gyrolab.sim.model import apply_effect_args, load_model, nominal_model
from gyrolab.sim.simulate import axis_physics, simulate_run

MAX_RATE_HZ = 100_000.0
MAX_UNITS = 256


def simulate(args: argparse.Namespace) -> int:
    """``gyrolab simulate --out RUN.mcap [--profile] [--model] [--rate] [--seed] [--effect]``.

    Everything is validated before anything is written; the recording appears atomically.
    """
    inputs = (args.profile, args.model, *(getattr(args, "axis_model", None) or []))
    check_output(args.out, args.force, inputs=inputs, kind="file")
    if not (math.isfinite(args.rate) and 0 < args.rate <= MAX_RATE_HZ):
        raise InputError("--rate", f"must be in (0, {MAX_RATE_HZ:g}] Hz, got {args.rate:g}")
    n_units = int(getattr(args, "units", 1) or 1)
    if not 1 <= n_units <= MAX_UNITS:
        raise InputError("--units", f"must be 1..{MAX_UNITS}, got {n_units}")
    profile = load_profile(args.profile)
    model = load_model(args.model) if args.model else nominal_model()
    try:
        model = apply_effect_args(model, list(args.effect or []))
    except (ValueError, TypeError) as e:
        raise InputError("--effect", str(e)) from None
    axis_models = [load_model(m) for m in getattr(args, "axis_model", None) or []]
    if len(axis_models) > 2:
        raise InputError("--axis-model", "a unit has at most 3 axes (give it at most twice)")
    try:
        axis_physics(model, axis_models, args.rate, args.seed, profile.ambient_c)
    except ValueError as e:
        raise InputError("--axis-model", str(e)) from None
    if axis_models and n_units > 1:
        raise InputError(
            "--units", "multi-axis units (--axis-model) in a multi-unit run are not supported yet"
        )
    units = unit_family(model, n_units, args.seed) if n_units > 1 else None
    with atomic_file(args.out, args.force, inputs=inputs) as tmp:
        summary = simulate_run(
            tmp,
            profile,
            model,
            rate_hz=args.rate,
            seed=args.seed,
            axis_models=axis_models,
            units=units,
        )
    print(
        f"wrote {args.out}: profile {profile.name}, {summary.duration_s / 3600:.2f} h, "
        f"{summary.samples} samples at {args.rate:g} Hz, seed {args.seed}, "
        f"effects {', '.join(model.effect_names()) or 'none'}"
        + (f", {1 + len(axis_models)} axes" if axis_models else "")
        + (f", units {', '.join(u.serial for u in units)}" if units else ""),
        file=sys.stdout,
    )
    return 0
