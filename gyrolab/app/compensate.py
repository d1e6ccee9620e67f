"""``gyrolab compensate`` and ``gyrolab apply``: typed options in, the model or the
compensated recording out, the summary printed.

A multi-unit recording (docs/fleet.md) without a unit is fitted unit by unit, in parallel,
through :func:`gyrolab.batch.run_items` (a Dask LocalCluster of ``workers``), each unit by
the single-run call :func:`gyrolab.compensation.commands.compensate` with its unit. The
fan-out lives here, above both, so that compensation never imports the batch engine that
runs it.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from gyrolab.app.options import ApplyOptions, CompensateOptions
from gyrolab.batch import BatchOptions, Item, run_items
from gyrolab.compensation import commands
from gyrolab.compensation.apply_command import apply as apply_model
from gyrolab.compensation.commands import units_of
from gyrolab.compensation.config import PipelineConfig, resolve_config
from gyrolab.compensation.guards import check_also_prior
from gyrolab.errors import InputError
from gyrolab.outputs import atomic_dir, check_output
from gyrolab.record.reader import list_units


def compensate(opts: CompensateOptions) -> int:
    """The ``gyrolab compensate`` command (docs/cli.md): one model directory, or one per
    unit of a multi-unit run."""
    t_start = time.perf_counter()
    run = str(opts.run)
    check_also_prior(opts.also, opts.prior)  # before the prior is read
    if opts.unit is None and units_of(run):
        if opts.prior is not None:  # each unit is tested against the prior on its own
            raise InputError(run, "--prior fits one unit of a multi-unit run: name it with --unit")
        check_output(opts.out, opts.force, inputs=_inputs(opts), kind="dir")
        # the single-run call's default (tests and benchmarks set it there)
        cfg, seed = resolve_config(opts.config, commands.DEFAULT_CONFIG, opts.seed)
        return compensate_units(opts, cfg, seed)
    prior = None
    if opts.prior is not None:
        from gyrolab.app.prior import load_prior

        prior = load_prior(opts.prior)
    summary = commands.compensate(
        run,
        opts.out,
        validate=opts.validate,
        config=opts.config,
        seed=opts.seed,
        unit=opts.unit,
        log_options=opts.log.read_log_kwargs(),
        force=opts.force,
        run_label=opts.run_label,
        validate_label=opts.validate_label,
        prior=prior,
        also=[str(a) for a in opts.also],
    )
    print(summary)
    total = time.perf_counter() - t_start
    print(f"model written to {opts.out} in {total:.1f} s", file=sys.stderr)
    return 0


def _inputs(opts: CompensateOptions) -> tuple[str | None, ...]:
    paths = (opts.run, opts.validate, opts.config, *opts.also)
    return tuple(None if p is None else str(p) for p in paths)


def compensate_units(opts: CompensateOptions, cfg: PipelineConfig, seed: int = 0) -> int:
    """``gyrolab compensate MULTI.mcap --out DIR``: one model directory per unit,
    ``DIR/<serial>``. DIR appears atomically with the units that were fitted; a unit that
    fails is named on stderr and the exit code is 1 (all failed: exit 2)."""
    run = str(opts.run)
    units = list_units(run)
    validate = None if opts.validate is None else str(opts.validate)
    also = tuple(str(a) for a in opts.also)
    opt = BatchOptions(seed=seed, validate=validate, config=cfg, also=also)
    with atomic_dir(opts.out, opts.force, command="compensate", inputs=_inputs(opts)) as tmp:
        items = [Item(Path(run), Path(tmp) / u, u) for u in units]
        results = run_items("compensate", items, opt, workers=opts.workers)
        if not any(r.status == "done" for r in results):
            raise InputError(run, "no unit could be fitted: " + "; ".join(r.error for r in results))
    for r in results:
        where = Path(opts.out) / str(r.unit)
        print(f"{r.unit}: {r.status} {where if r.status == 'done' else r.error}")
    failed = [r.unit for r in results if r.status == "failed"]
    print(
        f"{len(units) - len(failed)} of {len(units)} unit models written to {opts.out}"
        + (f"; failed: {', '.join(map(str, failed))}" if failed else ""),
        file=sys.stderr,
    )
    return 1 if failed else 0


def apply(opts: ApplyOptions) -> int:
    """The ``gyrolab apply`` command: :func:`gyrolab.compensation.apply_command.apply`."""
    units = apply_model(opts.model, opts.run, opts.out, opts.force, unit=opts.unit)
    which = ""
    if units != [None]:  # a multi-unit run: which of its units
        which = f" (unit{'s' if len(units) > 1 else ''} {', '.join(map(str, units))} compensated)"
    print(f"compensated recording written to {opts.out}{which}", file=sys.stderr)
    return 0
