"""How a run ended and what it covered, read from what the recording holds.

The outcome comes from ``/profile/event`` (``run_ended``, ``aborted`` with its reason,
``safe_state`` verified or ``FAILED``) and, for a file that went through ``gyrolab
recover``, from its ``recovery`` metadata record (docs/recording-format.md); a run resumed
after an interruption (its segments: the ``run`` record's ``segments``) says when it was
interrupted and resumed. Coverage is
the temperature range the chamber air (oven process value, safe-state readings excluded)
and the gyro case (PT100) reached, against the range of the profile's setpoints, and the
gyro samples and gaps. Nothing here is computed that the recording does not say.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gyrolab.record.reader import Recording
from gyrolab.report.text import hms

#: Outcome statuses, most to least orderly.
STATUSES = ("complete", "aborted", "interrupted", "recovered", "incomplete")


@dataclass
class Outcome:
    """How the run ended. ``status`` is one of :data:`STATUSES`."""

    status: str
    reason: str
    safe_state: str  # "verified" | "failed" | "not recorded" | "not applicable"
    safe_state_detail: str = ""
    end_t: float | None = None
    recovery: dict[str, Any] | None = None
    # a resumed run's continuations: each {"segment", "file", "after_t", "at_t", "step"}
    resumptions: list[dict[str, Any]] = field(default_factory=list)

    @property
    def line(self) -> str:
        """The header's outcome line, e.g. ``aborted — over-temperature …; safe state verified``."""
        failed = self.safe_state_detail.removeprefix("FAILED").lstrip(": ")
        safe = {
            "verified": f"oven in safe state ({self.safe_state_detail})",
            "failed": f"oven safe state FAILED ({failed})",
            "not recorded": "oven safe state not confirmed",
            "not applicable": "simulated run (no oven)",
        }[self.safe_state]
        if self.status == "recovered":
            assert self.recovery is not None
            return f"{self.recovery.get('account', 'recovered')} — {self.reason}"
        return f"{self.status} — {self.reason}; {safe}{self.resumed_text}"

    @property
    def resumed_text(self) -> str:
        """``; interrupted at … and resumed at …`` for each continuation ("" if none)."""
        parts = [
            f"interrupted after {hms(r['after_t'])}, resumed at {hms(r['at_t'])} in "
            f"{r.get('file', 'segment ' + str(r.get('segment')))} (step "
            f"{int(r.get('step', -1)) + 1} re-soaked; the gap is not filled in)"
            for r in self.resumptions
        ]
        return "".join(f"; {p}" for p in parts)

    @property
    def clean(self) -> bool:
        """Complete, and the safe state (where there is an oven) verified."""
        return self.status == "complete" and self.safe_state in ("verified", "not applicable")


def run_outcome(rec: Recording) -> Outcome:
    """The outcome of ``rec`` from its events and its ``recovery`` record."""
    end: dict[str, Any] | None = None
    safe: dict[str, Any] | None = None
    for e in rec.events:
        ev = e.get("event")
        if ev in ("run_ended", "aborted"):
            end = e
        elif ev == "safe_state":
            safe = e
    if safe is not None:
        detail = str(safe.get("detail", ""))
        safe_state = "failed" if detail.startswith("FAILED") else "verified"
    else:
        detail = ""
        simulated = rec.run.get("source") == "simulate"  # no chamber, no safe state
        safe_state = "not applicable" if simulated else "not recorded"
    if end is None:
        status, reason = "incomplete", "the run's end was not recorded"
    elif end.get("event") == "run_ended":
        status, reason = "complete", str(end.get("detail") or "profile complete")
    else:
        reason = str(end.get("detail") or "no reason recorded")
        status = "interrupted" if reason.startswith("interrupted") else "aborted"
    recovery = rec.metadata.get("recovery")
    if isinstance(recovery, dict):
        if end is None:
            reason = "the recording was cut short (crash or power loss) and salvaged"
            rc = rec.bench.get("recorder")
            if isinstance(rc, dict) and isinstance(rc.get("flush_every_s"), (int, float)):
                reason += (
                    f"; data not yet flushed at the crash (≤ {rc['flush_every_s']:g} s plus "
                    "one ADC block) is not counted"
                )
        else:
            reason = f"the run had ended ({status}: {reason}); the file was salvaged"
        status = "recovered"
    return Outcome(
        status=status,
        reason=reason,
        safe_state=safe_state,
        safe_state_detail=detail,
        end_t=None if end is None else float(end.get("t", math.nan)),
        recovery=recovery if isinstance(recovery, dict) else None,
        resumptions=[s for s in (rec.run.get("segments") or [])[1:] if "at_t" in s],
    )


@dataclass
class Coverage:
    """Temperatures reached (°C) against the profile's, and the gyro samples and gaps."""

    profile_c: tuple[float, float] | None
    chamber_c: tuple[float, float] | None
    case_c: tuple[float, float] | None
    samples: int
    rate_hz: float
    duration_s: float
    gaps: int
    samples_missing: int
    gap_s: float
    notes: list[str] = field(default_factory=list)

    def fraction(self, which: str = "case") -> float:
        """Share of the profile's setpoint span that ``which`` ("case"/"chamber") covered."""
        got = self.case_c if which == "case" else self.chamber_c
        if self.profile_c is None or got is None:
            return math.nan
        lo, hi = self.profile_c
        if hi <= lo:
            return 1.0 if got[0] <= lo <= got[1] else 0.0
        return max(0.0, min(hi, got[1]) - max(lo, got[0])) / (hi - lo)

    def temperature_line(self) -> str:
        def rng(r: tuple[float, float] | None) -> str:
            return "—" if r is None else f"{r[0]:.1f} … {r[1]:.1f} °C"

        line = f"chamber {rng(self.chamber_c)}, gyro case {rng(self.case_c)}"
        if self.profile_c is not None:
            line += f" for a profile of {rng(self.profile_c)}"
            f = self.fraction("case")
            if math.isfinite(f):
                line += f" (gyro case covered {100 * f:.1f} % of it)"
        return line

    def samples_line(self) -> str:
        return (
            f"{self.samples:,} at {self.rate_hz:g} Hz over {self.duration_s / 3600:.2f} h; "
            f"{self.gaps} gap(s), {self.samples_missing:,} samples missing "
            f"({self.gap_s:.1f} s)"
        )


def _range(x: np.ndarray) -> tuple[float, float] | None:
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    return (float(x.min()), float(x.max())) if x.size else None


def profile_setpoints(rec: Recording) -> list[float]:
    """The setpoints of the profile stored in the ``run`` metadata (empty if none)."""
    prof = rec.run.get("profile")
    if not isinstance(prof, dict):
        return []
    steps = prof.get("step", prof.get("steps", []))
    out = []
    for s in steps if isinstance(steps, list) else []:
        if isinstance(s, dict) and isinstance(s.get("setpoint_c"), (int, float)):
            out.append(float(s["setpoint_c"]))
    return out


def run_coverage(rec: Recording) -> Coverage:
    """Temperature ranges reached and the gyro stream's samples and gaps."""
    rate = rec.rate
    assert rate is not None and rate.t.size
    sps = profile_setpoints(rec)
    in_run = np.array([m != "safe" for m in rec.oven_mode], dtype=bool)
    if in_run.size != rec.oven_pv_c.size:
        in_run = np.ones(rec.oven_pv_c.size, dtype=bool)
    gaps = rate.gaps()
    missing = sum(n for _, n in gaps)
    n_gaps = len(gaps)
    # A stream that stopped (or never started) leaves no jump in the sample index: the
    # acquisition logs it as a gap up to the end of the run (data.t_end); count those too.
    for m in rec.logs:
        d = m.get("data")
        if m.get("kind") == "gap" and isinstance(d, dict) and "t_end" in d:
            n_gaps += 1
            missing += int(d.get("n_missing", 0))
    return Coverage(
        profile_c=(min(sps), max(sps)) if sps else None,
        chamber_c=_range(rec.oven_pv_c[in_run]),
        case_c=_range(rec.pt100_c),
        samples=int(rate.t.size),
        rate_hz=float(rate.rate_hz),
        duration_s=float(rate.t[-1] - rate.t[0] + rate.period),
        gaps=n_gaps,
        samples_missing=int(missing),
        gap_s=float(missing * rate.period),
    )
