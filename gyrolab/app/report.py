"""``gyrolab report`` and ``gyrolab fleet``: typed options in, the record written, its
outcome and verdict printed."""

from __future__ import annotations

import sys
from pathlib import Path

from gyrolab.app.options import FleetOptions, ReportOptions
from gyrolab.outputs import check_output
from gyrolab.record.reader import select_unit
from gyrolab.report.commands import write_report
from gyrolab.report.fleet_record import write_fleet
from gyrolab.report.spec_limits import Line


def report(opts: ReportOptions) -> int:
    """The ``gyrolab report`` command (docs/report.md)."""
    check_output(opts.out, opts.force, inputs=(opts.run, opts.model, opts.spec), kind="dir")
    unit = select_unit(opts.run, opts.unit)
    metrics = write_report(
        opts.run,
        opts.out,
        opts.model,
        opts.force,
        spec=opts.spec,
        operator=opts.operator,
        serial=opts.unit_serial,
        log_options=opts.log.read_log_kwargs(),
        unit=unit,
    )
    print(f"run outcome: {metrics['outcome']['line']}", file=sys.stderr)
    for name, m in metrics.get("axes", {"": metrics}).items():
        if "verdict" in m:
            v = m["verdict"]
            axis = f" (axis {name})" if name else ""
            print(
                f"verdict{axis}: {v['verdict']} (metric limits on the {v['series']} output)",
                file=sys.stderr,
            )
            for line in (Line(**d) for d in v["lines"]):
                if not line.passed:  # what failed, its value and its limit
                    print(f"  {line.text()}", file=sys.stderr)
    print(f"report written to {Path(opts.out) / 'index.html'}", file=sys.stderr)
    return 0


def fleet(opts: FleetOptions) -> int:
    """The ``gyrolab fleet`` command (docs/fleet.md)."""
    spec = None if opts.spec is None else str(opts.spec)
    models = [str(m) for m in opts.models]
    if opts.part_number is not None or opts.since is not None:
        from gyrolab.app.runs import catalogue_models

        models += catalogue_models(opts.catalogue, opts.part_number, opts.since)
    doc = write_fleet(models, opts.out, spec, opts.force)
    y = doc.get("yield")
    print(
        f"{doc['n_units']} units, {len(doc['outliers'])} outlier flag(s)"
        + (f", yield {y['passed']}/{y['total']}" if y else "")
        + f"; fleet record written to {Path(opts.out) / 'index.html'}",
        file=sys.stderr,
    )
    return 0
