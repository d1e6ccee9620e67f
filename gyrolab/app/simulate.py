"""``gyrolab simulate`` and ``gyrolab discrepancy``: the simulator's two commands, typed
options in, the one-line summary printed."""

from __future__ import annotations

from gyrolab.app.options import DiscrepancyOptions, SimulateOptions


def simulate(opts: SimulateOptions) -> int:
    """The ``gyrolab simulate`` command (docs/sim-model.md)."""
    # each command imports its own stack only (the discrepancy's is not the simulator's)
    from gyrolab.sim.commands import simulate_file

    line = simulate_file(
        opts.out,
        opts.profile,
        model_path=opts.model,
        axis_model_paths=opts.axis_models,
        rate_hz=opts.rate_hz,
        seed=opts.seed,
        units=opts.units,
        effects=opts.effects,
        force=opts.force,
    )
    print(line)
    return 0


def discrepancy(opts: DiscrepancyOptions) -> int:
    """The ``gyrolab discrepancy`` command (docs/discrepancy.md)."""
    from gyrolab.sim.discrepancy.commands import discrepancy as run_discrepancy

    print(run_discrepancy(opts.run, opts.out, model=opts.model, unit=opts.unit, force=opts.force))
    return 0
