"""``gyrolab batch``: typed options in, one single-run command per recording on Dask
(:mod:`gyrolab.batch`), one line per item printed."""

from __future__ import annotations

from gyrolab.app.options import BatchCommandOptions
from gyrolab.batch import BatchOptions, run_batch, summary


def batch(opts: BatchCommandOptions) -> int:
    """The ``gyrolab batch`` command (docs/fleet.md): exit 1 when any item failed."""
    items = BatchOptions(
        seed=opts.seed,
        config_file=None if opts.config is None else str(opts.config),
        models=None if opts.models is None else str(opts.models),
        sim_model=None if opts.sim_model is None else str(opts.sim_model),
        force=opts.force,
        threads=opts.threads,
    )
    results = run_batch(
        opts.task,
        opts.runs,
        opts.out,
        options=items,
        scheduler=opts.scheduler,
        workers=opts.workers,
    )
    print(summary(results))
    return 1 if any(r.status == "failed" for r in results) else 0
