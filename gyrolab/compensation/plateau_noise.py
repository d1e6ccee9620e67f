"""Noise terms per temperature plateau: ARW and bias instability at each soaked step.

A temperature test holds the gyro at a ladder of temperatures; its noise (angle random walk
N, bias instability B, IEEE 952) is a function of temperature. For each profile step that
the recording's ``/profile/event`` topic shows ending (``step_started`` ... ``step_ended``,
the step soaked), the *soaked segment* is the tail of the step in which the PT100 stays
within ``tol_c`` of its final value (the median of the step's last tenth): the gyro case has
settled, so the segment is a static test at one temperature. On the segment's rate samples
(gaps stay gaps: NaN, :func:`~gyrolab.numerics.phase.gap_filled`) the overlapping
Allan deviation (:func:`~gyrolab.numerics.allan.allan_deviation`) and the slope-rule
noise terms (:func:`~gyrolab.numerics.noise_terms.noise_terms`) give N and B, with B's
one-sigma interval from the curve's bounds at the tau of the minimum.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gyrolab.numerics.allan import allan_deviation
from gyrolab.numerics.noise_terms import FLICKER_FLOOR, filter_corner_tau, noise_terms
from gyrolab.numerics.phase import gap_filled
from gyrolab.record.reader import Recording

__all__ = ["Plateau", "plateau_noise", "soaked_segments"]


@dataclass(frozen=True)
class Plateau:
    """Noise of one soaked step (rate in deg/s)."""

    step: int
    setpoint_c: float
    t_start: float  #: s since run start, first sample of the soaked segment
    t_end: float
    temperature_c: float  #: mean PT100 over the segment
    temperature_span_c: float  #: max - min PT100 over the segment
    n_samples: int
    missing: int  #: samples missing (gaps) in the segment
    arw_deg_per_sqrt_h: float
    bias_instability_deg_per_h: float
    bi_lo_deg_per_h: float
    bi_hi_deg_per_h: float
    tau_b_s: float

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def soaked_segments(
    rec: Recording, tol_c: float = 0.5, min_s: float = 60.0
) -> list[tuple[int, float, float, float]]:
    """``(step, setpoint_c, t_start, t_end)`` of each soaked step segment (see module doc)."""
    starts: dict[int, tuple[float, float]] = {}
    out: list[tuple[int, float, float, float]] = []
    for ev in sorted(rec.events, key=lambda e: float(e.get("t", 0.0))):
        step = int(ev.get("step", -1))
        if ev.get("event") == "step_started":
            starts[step] = (float(ev["t"]), float(ev.get("setpoint_c", np.nan)))
        elif ev.get("event") == "step_ended" and step in starts:
            t0, sp = starts.pop(step)
            t1 = float(ev["t"])
            sel = (rec.pt100_t >= t0) & (rec.pt100_t <= t1)
            tt, cc = rec.pt100_t[sel], rec.pt100_c[sel]
            if tt.size < 3:
                continue
            final = float(np.median(cc[tt >= t1 - 0.1 * (t1 - t0)]))
            off = np.flatnonzero(np.abs(cc - final) > tol_c)
            # settled from the reading after the last one outside the band
            ts = t0 if off.size == 0 else float(tt[min(off[-1] + 1, tt.size - 1)])
            if t1 - ts >= min_s:
                out.append((step, sp, ts, t1))
    return out


def plateau_noise(rec: Recording, tol_c: float = 0.5, min_s: float = 60.0) -> list[Plateau]:
    """ARW and bias instability of every soaked segment of a recording (rate in deg/s)."""
    rate = rec.require_rate()
    out: list[Plateau] = []
    for step, sp, t0, t1 in soaked_segments(rec, tol_c, min_s):
        sel = (rate.t >= t0) & (rate.t < t1)
        if np.count_nonzero(sel) < 64:
            continue
        y = gap_filled(rate.index[sel], rate.values[sel])
        r = allan_deviation(y, rate.rate_hz, taus="octave")
        # ARW always read, as metrics, above the sensor's own filter corner
        nt = noise_terms(
            r, method="slope", slope_tol=None, tau_min=filter_corner_tau(y, rate.rate_hz)
        )
        i_b = int(np.argmin(np.abs(r.taus - nt.tau_b)))
        psel = (rec.pt100_t >= t0) & (rec.pt100_t <= t1)
        pc = rec.pt100_c[psel]
        out.append(
            Plateau(
                step=step,
                setpoint_c=sp,
                t_start=t0,
                t_end=t1,
                temperature_c=float(pc.mean()) if pc.size else float("nan"),
                temperature_span_c=float(np.ptp(pc)) if pc.size else float("nan"),
                n_samples=int(np.count_nonzero(sel)),
                missing=int(np.isnan(y).sum()),
                arw_deg_per_sqrt_h=60.0 * nt.N,
                bias_instability_deg_per_h=3600.0 * nt.B,
                bi_lo_deg_per_h=3600.0 * float(r.dev_lo[i_b]) / FLICKER_FLOOR,
                bi_hi_deg_per_h=3600.0 * float(r.dev_hi[i_b]) / FLICKER_FLOOR,
                tau_b_s=nt.tau_b,
            )
        )
    return out
