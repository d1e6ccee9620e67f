"""``gyrolab compensate``: one run's model, or every unit's of a multi-unit run.

A multi-unit recording (docs/fleet.md) without ``--unit`` is fitted unit by unit, in
parallel, through :func:`gyrolab.batch.run_items` (a Dask LocalCluster of ``--workers``),
each unit by the single-run handler :func:`gyrolab.compensation.commands.compensate` with
its ``--unit``. The fan-out lives here, above both, so that compensation never imports the
batch engine that runs it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from gyrolab.batch import BatchOptions, Item, run_items
from gyrolab.compensation import commands
from gyrolab.compensation.commands import units_of
from gyrolab.compensation.config import PipelineConfig, resolve_config
from gyrolab.errors import InputError
from gyrolab.outputs import atomic_dir, check_output
from gyrolab.record.reader import list_units


def compensate(args: argparse.Namespace) -> int:
    """The ``gyrolab compensate`` handler (docs/cli.md)."""
    if getattr(args, "unit", None) is not None or not units_of(args.run):
        return commands.compensate(args)
    inputs = (args.run, args.validate, getattr(args, "config", None))
    check_output(args.out, args.force, inputs=inputs, kind="dir")
    # the single-run handler's default (tests and benchmarks set it there)
    base = getattr(args, "pipeline_config", None) or commands.DEFAULT_CONFIG
    cfg, seed = resolve_config(getattr(args, "config", None), base, getattr(args, "seed", None))
    return compensate_units(args, cfg, seed)


def compensate_units(args: argparse.Namespace, cfg: PipelineConfig, seed: int = 0) -> int:
    """``gyrolab compensate MULTI.mcap --out DIR``: one model directory per unit,
    ``DIR/<serial>``. DIR appears atomically with the units that were fitted; a unit that
    fails is named on stderr and the exit code is 1 (all failed: exit 2)."""
    inputs = (args.run, args.validate, getattr(args, "config", None))
    units = list_units(args.run)
    opt = BatchOptions(seed=seed, validate=args.validate, config=cfg)
    with atomic_dir(args.out, args.force, command="compensate", inputs=inputs) as tmp:
        items = [Item(Path(args.run), Path(tmp) / u, u) for u in units]
        results = run_items("compensate", items, opt, workers=getattr(args, "workers", None))
        if not any(r.status == "done" for r in results):
            raise InputError(
                args.run, "no unit could be fitted: " + "; ".join(r.error for r in results)
            )
    for r in results:
        where = Path(args.out) / str(r.unit)
        print(f"{r.unit}: {r.status} {where if r.status == 'done' else r.error}")
    failed = [r.unit for r in results if r.status == "failed"]
    print(
        f"{len(units) - len(failed)} of {len(units)} unit models written to {args.out}"
        + (f"; failed: {', '.join(map(str, failed))}" if failed else ""),
        file=sys.stderr,
    )
    return 1 if failed else 0
