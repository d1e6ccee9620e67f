"""``gyrolab acquire --resume RUN.mcap``: what the continuation of an interrupted run is
asked to do, from the run itself (gyrolab/acquisition/resume.py says where it starts).

The run's file as the interruption left it is taken as it is when it reads; a file cut
short (``kill -9``, a power cut: no footer) is first salvaged by ``gyrolab recover`` into
``<stem>.recovered.mcap`` beside it (the cut file is kept as evidence, never written), and
the continuation continues that. The profile is the run's (its ``run`` record); a
simulated bench is the one that ran it (seed, units, units on their internal sensor,
drivers, speed: from the recording); a lab bench is the BENCH.toml given, checked against
the first segment once connected.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gyrolab.acquisition.resume import ResumePoint, resume_point
from gyrolab.errors import GyrolabError, InputError
from gyrolab.instruments import registry

# The bench record's instrument tables and the driver role each was opened in.
_ROLES = (("multimeter", "thermometer"), ("oven", "chamber"), ("adc", "rate_stream"))
_ROLES += (("scanner", "multi_thermometer"),)


@dataclass(frozen=True)
class ResumeSettings:
    """What the continuation runs: ``point`` (where), ``profile`` (the run's, as a
    table), and for a simulated bench its ``seed``, ``units``, ``internal`` (1-based units
    on their internal sensor), ``drivers`` (those not the default), ``speed`` and
    ``axis_models`` (a 2- or 3-axis unit: its other axes' SIM_MODEL.toml texts, as
    ``--axis-model`` gave them)."""

    point: ResumePoint
    profile: dict[str, Any]
    simulated: bool
    seed: int = 0
    units: int = 0
    internal: tuple[int, ...] = ()
    drivers: tuple[str, ...] = ()
    speed: float | None = None
    axis_models: tuple[str, ...] = ()


def resume_settings(path: str | Path, force: bool = False) -> ResumeSettings:
    """The continuation of the run whose last segment (or cut file) is ``path``."""
    src = Path(path)
    try:
        point = resume_point(src)
    except InputError as e:
        if "gyrolab recover" not in str(e):
            raise
        point = resume_point(_recovered(src, force))
    run, bench = point.run, point.bench
    settings: dict[str, Any] = {"point": point, "profile": run["profile"]}
    if not (bench.get("simulated") and bench.get("name") == "sim"):
        # a lab bench's axes are its BENCH.toml's ([rate_stream] axes), checked once connected
        return ResumeSettings(simulated=False, **settings)
    units = list(run.get("units") or [])
    per_unit = bench.get("units") or {}
    internal = tuple(
        k
        for k, s in enumerate(units, start=1)
        if (per_unit.get(s) or {}).get("temperature_source") == "internal"
    )
    drivers = tuple(
        str(bench[table]["driver"])
        for table, role in _ROLES
        if isinstance(bench.get(table), dict)
        and bench[table].get("driver") not in (None, registry.DEFAULT_DRIVER[role])
    )
    speed = run.get("speed")
    return ResumeSettings(
        simulated=True,
        seed=int(run.get("seed") or 0),
        units=len(units),
        internal=internal,
        drivers=drivers,
        speed=float(speed) if isinstance(speed, (int, float)) else None,
        axis_models=_axis_models(point),
        **settings,
    )


def _axis_models(point: ResumePoint) -> tuple[str, ...]:
    """The other axes' models of a simulated multi-axis run, from its first segment's
    ``sim_provenance_axes`` record (what ``--axis-model`` gave; docs/recording-format.md);
    () for a single-axis run."""
    from gyrolab.record.reader import read_metadata

    axes = int(point.run.get("axes", 1) or 1)
    if axes <= 1:
        return ()
    texts = (read_metadata(point.previous).get("sim_provenance_axes") or {}).get("models_toml")
    if not (isinstance(texts, list) and len(texts) == axes - 1):
        raise InputError(
            point.previous,
            f"a {axes}-axis simulated run without its axes' models (sim_provenance_axes): "
            "cannot be resumed",
        )
    return tuple(str(t) for t in texts)


def _recovered(src: Path, force: bool) -> Path:
    """``src`` (cut short) salvaged beside it; the recovered file's path."""
    from gyrolab.record.recover import recover_recording

    out = src.with_name(f"{src.stem}.recovered.mcap")
    try:
        rep = recover_recording(src, out, force=force)
    except GyrolabError as e:
        raise InputError(src, f"cannot be resumed: {e}") from None
    print(
        f"gyrolab acquire --resume: {src.name} was cut short; {rep.account()} into {out}",
        file=sys.stderr,
    )
    return out


def _stem(name: str) -> str:
    """A segment's run stem: its name without ``.mcap``, ``.recovered`` and ``.segK``."""
    stem = name.removesuffix(".mcap").removesuffix(".recovered")
    base, _, last = stem.rpartition(".seg")
    return base if base and last.isdigit() else stem


def continuation_path(point: ResumePoint) -> Path:
    """Where a continuation is written when ``--out`` is not given: beside the segment it
    continues, ``<run stem>.seg<N>.mcap`` (the stem without an earlier ``.segK`` or
    ``.recovered``)."""
    return point.previous.with_name(f"{_stem(point.previous.name)}.seg{point.segment}.mcap")


def last_continuation(path: str | Path) -> Path | None:
    """The continuation ``acquire --resume path`` wrote beside it (no ``--out``): the
    newest ``<stem>.segN.mcap`` whose run's segments include ``path`` or its salvaged
    copy; None when there is none (the continuation never started)."""
    from gyrolab.record.reader import segments

    src = Path(path)
    previous = {src.name, f"{_stem(src.name)}.recovered.mcap"}
    found: list[tuple[float, Path]] = []
    for f in src.parent.glob(f"{_stem(src.name)}.seg*.mcap"):
        try:
            earlier = {p.name for p in segments(f)[:-1]}
        except Exception:  # a file that does not read is not the continuation
            continue
        if earlier & previous:
            found.append((f.stat().st_mtime, f))
    return max(found)[1] if found else None
