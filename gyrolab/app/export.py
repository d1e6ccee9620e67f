"""``gyrolab export`` and ``gyrolab convert``: a model or a recording written in another
tool's format, typed options in, what was written printed."""

from __future__ import annotations

import sys

from gyrolab.app.options import ConvertOptions, ExportOptions
from gyrolab.convert import convert_recording
from gyrolab.export.commands import export as export_model


def export(opts: ExportOptions) -> int:
    """The ``gyrolab export`` command (docs/export.md)."""
    outs = export_model(
        opts.model,
        opts.format,
        opts.out,
        kind=opts.kind,
        instance=opts.instance,
        device_id=opts.device_id,
        run=opts.run,
        rostopic=opts.rostopic,
        log_options=opts.log.read_log_kwargs(),
        force=opts.force,
    )
    print(f"wrote {', '.join(str(o) for o in outs)}", file=sys.stderr)
    return 0


def convert(opts: ConvertOptions) -> int:
    """The ``gyrolab convert`` command (docs/convert.md)."""
    res = convert_recording(
        opts.run,
        opts.to,
        opts.out,
        force=opts.force,
        unit=opts.unit,
        log_options=opts.log.read_log_kwargs(),
    )
    print(f"wrote {res['out']}: {res['rows']} samples ({res['gaps']} gap(s)) as {res['format']}")
    return 0
