"""Resuming an interrupted run (``gyrolab acquire --resume RUN.mcap``): where its
continuation starts, and whether the bench is the one that ran it.

A run cut short — ``kill -9``, a power cut, a fault, SIGINT — is continued by a new file,
the next *segment* of the same run (docs/recording-format.md, "Segments"): same profile,
same bench, same units. :func:`resume_point` reads the run so far (every segment, through
the reader) and says where the continuation starts:

* the step to run is the first one the run did not end (``step_ended``): the step that was
  running is re-soaked from its beginning, the steps before are not repeated;
* the continuation's run clock starts after the run's last message, later by the time the
  bench was down (the wall time since the last segment was last written, × the simulated
  bench's speed), never less than 1 s: the interruption is a gap on the one run clock;
* each stream's samples go on from the run index its time says, so the interruption is a
  gap in the sample index, logged as such (``RateRecorder``, cause ``run interrupted``) and
  never filled in.

:func:`bench_differences` compares the bench the continuation connected to with the first
segment's: its name, whether it is simulated, each instrument's driver, model and serial
(what ``describe()`` recorded), the units' serials and the ADC's axes and sample rate.
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gyrolab.errors import InputError
from gyrolab.record.format import TOPIC_EVENT, TOPIC_RATE
from gyrolab.record.reader import (
    file_metadata,
    iter_blocks,
    iter_messages,
    list_units,
    opened,
    read_metadata,
)
from gyrolab.record.reader import segments as run_segments

#: The shortest interruption put on the run clock between two segments (s).
MIN_GAP_S = 1.0


@dataclass(frozen=True)
class ResumePoint:
    """Where the continuation of the run ``previous`` ends starts (module doc).

    ``step``: the step to run first (0-based; re-soaked); ``after_t``: the run time of the
    last message of the segments so far; ``at_t``: the run time the continuation starts;
    ``next_index``: per unit (None: the single unit) the run index after its last sample
    and that index's run time (``(index, t)``: where its samples would have gone on);
    ``start_time_ns``: the run's time origin (Unix ns: every segment's log times count from
    it); ``run``/``bench``: the first segment's records."""

    previous: Path
    run_id: str
    segment: int
    step: int
    after_t: float
    at_t: float
    start_time_ns: int
    next_index: dict[str | None, tuple[int, float]]
    run: dict[str, Any]
    bench: dict[str, Any]
    events: list[dict[str, Any]] = field(default_factory=list)

    @property
    def resumed(self) -> dict[str, Any]:
        """The continuation's ``run.resumed`` record."""
        return {"after_t": round(self.after_t, 6), "at_t": round(self.at_t, 6), "step": self.step}

    @property
    def previous_segment(self) -> dict[str, Any]:
        """The continuation's ``run.previous_segment`` record."""
        return {"file": self.previous.name, "segment": self.segment - 1, "run_id": self.run_id}


def resume_point(path: str | os.PathLike[str], now_s: float | None = None) -> ResumePoint:
    """Where the continuation of the run whose last segment is ``path`` starts; an
    :class:`InputError` if there is nothing to resume (the profile was complete) or the
    file is not an acquired run. ``now_s``: the Unix time now (default: the clock's)."""
    p = Path(path)
    meta = read_metadata(p)
    run, bench = meta.get("run", {}), meta.get("bench", {})
    if run.get("source") != "acquire":
        raise InputError(p, "is not an acquired run (gyrolab acquire wrote none of it)")
    last_run = file_metadata(p).get("run", {})  # this segment's own record
    steps = (run.get("profile") or {}).get("step") or (run.get("profile") or {}).get("steps")
    if not isinstance(steps, list) or not steps:
        raise InputError(p, "its run record has no profile steps to resume")
    start_ns: int | None = None
    events: list[dict[str, Any]] = []
    for _topic, log_ns, data in iter_messages(p, [TOPIC_EVENT]):
        e = json.loads(data)
        if start_ns is None:
            start_ns = log_ns - round(float(e["t"]) * 1e9)
        events.append(e)
    if start_ns is None:
        raise InputError(p, "has no profile event: the run never started; start it again")
    if any(e.get("event") == "run_ended" for e in events):
        raise InputError(p, "the profile was complete: nothing to resume")
    ended = [int(e["step"]) for e in events if e.get("event") == "step_ended"]
    step = max(ended) + 1 if ended else 0
    if step >= len(steps):
        raise InputError(p, "every step of the profile ended: nothing to resume")
    end_ns = 0
    for seg in run_segments(p):
        with opened(seg) as reader:
            summary = reader.get_summary()
            stats = summary.statistics if summary is not None else None
            if stats is None:
                raise InputError(seg, "has no summary section; try `gyrolab recover`")
            end_ns = max(end_ns, int(stats.message_end_time))
    serials: list[str | None] = list(list_units(p)) or [None]
    next_index = {u: _next_index(p, u) for u in serials}
    # The run's last message, or the end of its last block of samples (a block's log
    # time is its first sample's), whichever is later.
    after_t = max([(end_ns - start_ns) / 1e9] + [t for _i, t in next_index.values()])
    down_s = (time.time() if now_s is None else now_s) - _last_written(p, meta)
    speed = run.get("speed")
    scale = float(speed) if isinstance(speed, (int, float)) and speed > 0 else 1.0
    gap = max(MIN_GAP_S, down_s * scale) if speed != "max" else MIN_GAP_S
    return ResumePoint(
        previous=p,
        run_id=str(last_run.get("run_id") or run.get("run_id") or ""),
        segment=int(last_run.get("segment") or 1) + 1,
        step=step,
        after_t=after_t,
        at_t=after_t + gap,
        start_time_ns=start_ns,
        next_index=next_index,
        run=run,
        bench=bench,
        events=events,
    )


def _last_written(path: Path, meta: dict[str, Any]) -> float:
    """When the run last wrote to its file (Unix s): the file's, or — a file ``gyrolab
    recover`` wrote — the cut file's it names, if it is still beside it."""
    rec = meta.get("recovery") or (meta.get("run", {}).get("segments") or [{}])[-1].get("recovery")
    if isinstance(rec, dict) and rec.get("source"):
        src = path.parent / str(rec["source"])
        if src.is_file():
            return src.stat().st_mtime
    return path.stat().st_mtime


def _next_index(path: Path, unit: str | None) -> tuple[int, float]:
    """The run index after the last ``/gyro/rate`` sample of ``unit`` and its run time
    (``(0, 0.0)``: no sample)."""
    nxt, t_next = 0, 0.0
    for t0, period, first, values in iter_blocks(path, TOPIC_RATE, unit=unit):
        n = int(values.shape[0])
        if int(first) + n > nxt:
            nxt, t_next = int(first) + n, float(t0) + n * float(period)
    return nxt, t_next


# Per instrument of the bench record: what must be the same for it to be the same bench.
IDENTITY_KEYS = ("driver", "model", "serial", "idn")


def bench_differences(first: dict[str, Any], now: dict[str, Any]) -> list[str]:
    """What differs between the first segment's ``bench`` record and the bench the
    continuation connected to (module doc); empty: the same bench."""
    out: list[str] = []
    for key in ("name", "simulated"):
        if first.get(key) != now.get(key):
            out.append(f"bench {key}: {first.get(key)!r} then, {now.get(key)!r} now")
    roles = sorted(k for k in set(first) | set(now) if isinstance(first.get(k, now.get(k)), dict))
    for role in roles:
        if role in ("limits", "safe_state", "recorder", "suspend", "units"):
            continue
        a, b = first.get(role) or {}, now.get(role) or {}
        for k in IDENTITY_KEYS:
            if a.get(k) != b.get(k) and (k in a or k in b):
                out.append(f"{role} {k}: {a.get(k)!r} then, {b.get(k)!r} now")
        for k in ("axes", "sample_rate_hz"):
            if k in a and not _same(a.get(k), b.get(k)):
                out.append(f"{role} {k}: {a.get(k)!r} then, {b.get(k)!r} now")
    ua, ub = first.get("units") or {}, now.get("units") or {}
    if list(ua) != list(ub):
        out.append(f"unit serials: {list(ua)} then, {list(ub)} now")
    return out


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return math.isclose(float(a), float(b))
    return a == b
