"""The next experiment: a profile that separates look-alike explanations
(docs/discrepancy.md, "Look-alike effects").

For an ambiguous pair (:class:`~.identify.LookAlike`), each profile of a small library
built from the run's own setpoints — the run with a 2 h soak at its end, a heating
staircase, an up-and-down cycle, four full-range cycles, a long soak at room temperature,
slow ramps, the run again — is simulated through the fitted thermal chain (the updated
model, deterministic), both explanations are evaluated on its bins at their fitted
amplitudes and shapes, and the expected separation (:func:`~.identify.separation`, both
ways, the other's shape at its best) is computed with the noise model this run taught.
The proposal is the shortest profile whose smaller separation reaches :data:`TARGET`,
else the one that separates best (then flagged: ``expected_to_separate`` is false when
even its smaller separation stays below the look-alike threshold
:data:`~.identify.SEPARATION` — no profile of the library tells the two apart at this
run's noise, and the report says so rather than promise it); it is an ordinary profile
(docs/profiles.md) that ``gyrolab simulate --profile`` and
``gyrolab acquire`` run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from gyrolab.profiles.profile import Profile, Step
from gyrolab.sim.discrepancy.data import BenchData, choose_bin_s
from gyrolab.sim.discrepancy.gls import CovWhitener, bin_noise_autocov
from gyrolab.sim.discrepancy.gyro_fit import GyroContext
from gyrolab.sim.discrepancy.identify import SEPARATION, LookAlike, separation
from gyrolab.sim.discrepancy.noise_fit import CovNoise
from gyrolab.sim.model import SimModel
from gyrolab.sim.physics import Physics

TARGET = 50.0
"""Smaller expected separation (ΔBIC) a proposed profile should reach: twice the
look-alike threshold of a 2.5-σ test, so that the new run names one of the two."""
RAMP_C_PER_MIN = 0.5
MAX_CYCLES = 12
"""Most full-range cycles a proposal repeats to reach :data:`TARGET` (38.5 h)."""


@dataclass
class Proposal:
    """A proposed separating profile and what it is expected to show."""

    profile: Profile
    separation: dict[str, float]
    """Expected ΔBIC of each explanation over the other, had it generated the new run."""
    considered: dict[str, float]
    """Every library profile's deciding separation (:func:`deciding`), by name."""
    decides: float = 0.0
    """The proposed profile's deciding separation."""
    file: str = "separating_profile.toml"
    """Its name in the output directory."""

    @property
    def expected_to_separate(self) -> bool:
        """Whether the new run is expected to tell them apart: the deciding separation
        reaches the look-alike threshold."""
        return self.decides >= SEPARATION

    def toml(self) -> str:
        """The profile as a PROFILE.toml (docs/profiles.md)."""
        import tomli_w

        return tomli_w.dumps(self.profile.to_dict())

    def to_json(self) -> dict[str, Any]:
        return {
            "file": self.file,
            "name": self.profile.name,
            "description": self.profile.description,
            "duration_h": self.profile.duration_s / 3600.0,
            "expected_separation": self.separation,
            "deciding_separation": self.decides,
            "expected_to_separate": self.expected_to_separate,
            "considered": self.considered,
            "profile": self.profile.to_dict(),
        }


def _ramp(a: float, b: float, label: str) -> list[Step]:
    """A setpoint ramp at :data:`RAMP_C_PER_MIN` as 60 s setpoint steps."""
    n = max(1, int(round(abs(b - a) / RAMP_C_PER_MIN)))
    return [Step(round(a + (b - a) * (i + 1) / n, 2), 60.0, label) for i in range(n)]


def library(d: BenchData) -> list[Profile]:
    """The candidate profiles, within the setpoints this run used (module docstring)."""
    sps = [s.setpoint_c for s in d.steps] or [25.0]
    lo, hi, room = float(min(sps)), float(max(sps)), float(sps[0])
    own = [Step(s.setpoint_c, max(s.t1 - s.t0, 1.0), "as run") for s in d.steps]
    third = (hi - lo) / 3.0
    out = [
        Profile("repeat", tuple(own), description="the same profile again"),
        Profile(
            "soak-at-end",
            tuple(own + [Step(own[-1].setpoint_c, 7200.0, "2 h soak at the end")]),
            description="the same profile with a 2 h soak at its last setpoint",
        ),
        Profile(
            "heating-staircase",
            (
                Step(room, 3600.0, "power-on"),
                Step(lo, 7200.0, "cold start"),
                Step(lo + third, 3600.0, "up"),
                Step(lo + 2 * third, 3600.0, "up"),
                Step(hi, 5400.0, "up"),
                Step(room, 3600.0, "back"),
            ),
            description="a heating staircase: every temperature revisited on the other branch",
        ),
        Profile(
            "up-down",
            (
                Step(room, 3600.0, "power-on"),
                Step(hi, 5400.0, "hot"),
                Step(lo, 9000.0, "cold"),
                Step(hi, 9000.0, "hot again"),
                Step(room, 3600.0, "back"),
            ),
            description="up, down and up again over the whole range",
        ),
        cycles(lo, hi, room, 4),
        Profile(
            "long-soak",
            (Step(room, 6 * 3600.0, "6 h at one temperature"),),
            description="6 h at one temperature: no rate, no branch change",
        ),
        Profile(
            "slow-ramps",
            tuple(
                [Step(room, 3600.0, "power-on")]
                + _ramp(room, hi, "ramp up")
                + [Step(hi, 3600.0, "hot")]
                + _ramp(hi, lo, "ramp down")
                + [Step(lo, 3600.0, "cold")]
                + _ramp(lo, room, "ramp up")
            ),
            description=f"ramps at {RAMP_C_PER_MIN} °C/min over the whole range",
        ),
    ]
    return out


def cycles(lo: float, hi: float, room: float, n: int) -> Profile:
    """``n`` full-range cycles, 1.5 h at each end, after an hour at ``room``."""
    words = {4: "four", 8: "eight"}
    return Profile(
        "cycles" if n == 4 else f"cycles-{n}",
        tuple(
            [Step(room, 3600.0, "power-on"), Step(lo, 5400.0, "cold")]
            + [Step(sp, 5400.0, x) for _ in range(n) for sp, x in ((hi, "hot"), (lo, "cold"))]
        ),
        description=f"{words.get(n, n)} full-range cycles, 1.5 h at each end: every branch "
        f"change and rate {n} times over",
    )


def deciding(look: LookAlike, s_ab: float, s_ba: float) -> float:
    """The separation that decides between the two: the smaller one; but when the winner
    is part of the other (``E`` against ``E + C``) only the larger explanation's, since
    had the winner alone generated the run BIC prefers it by the other's extra parameters
    on every profile (its separation is that penalty, whatever the profile)."""
    if set(look.winner.members) < set(look.other.members):
        return s_ba
    return min(s_ab, s_ba)


def thermal_context(model: SimModel, profile: Profile, poly_order: int) -> GyroContext:
    """The gyro terms' context of ``profile`` run through ``model``'s thermal chain: case
    temperature and its rate on a 1 s grid, bins as the workflow would choose them."""
    phys = Physics(model, rate_hz=1.0, seed=0, ambient_c=profile.ambient_c)
    case = []
    for s in profile.steps:
        phys.set_setpoint(s.setpoint_c)
        blk = phys.advance(int(round(s.duration_s)))
        case.append(blk.case_trace)
    case_c = np.concatenate(case)
    grid_t = np.arange(case_c.size, dtype=float)
    dur = float(case_c.size)
    bin_s = choose_bin_s(dur)
    t = np.arange(bin_s / 2.0, dur - bin_s / 2.0 + 1e-9, bin_s)
    return GyroContext(
        t=t,
        y=np.zeros(t.size),
        grid_t=grid_t,
        case_c=case_c,
        dcase=np.gradient(case_c),
        duration_s=dur,
        bin_s=bin_s,
        poly_order=poly_order,
    )


def _whitener(noise: CovNoise, ctx: GyroContext) -> tuple[CovWhitener, float]:
    r = bin_noise_autocov(
        ctx.t.size,
        ctx.bin_s,
        noise.n_white,
        noise.b_floor,
        noise.k_rrw,
        noise.gm_sigma,
        noise.gm_tau_s,
    )
    return CovWhitener(r), 1.0  # an absolute covariance: whitened noise has unit variance


def propose(
    d: BenchData, model: SimModel, noise: CovNoise, look: LookAlike, poly_order: int
) -> Proposal:
    """The profile that best separates ``look``'s two explanations (module docstring)."""
    deterministic = replace(model, effects=tuple(e for e in model.effects if e.name in THERMAL))
    a, b = look.winner, look.other

    def evaluate(prof: Profile) -> tuple[float, float, float, float, Profile]:
        ctx = thermal_context(deterministic, prof, poly_order)
        w, s2 = _whitener(noise, ctx)
        s_ab, _ = separation(a, b, ctx, w, s2, wider=True)
        s_ba, _ = separation(b, a, ctx, w, s2, wider=True)
        return (deciding(look, s_ab, s_ba), prof.duration_s, s_ab, s_ba, prof)

    rows = [evaluate(prof) for prof in library(d)]
    good = [r for r in rows if r[0] >= TARGET]
    four = next(r for r in rows if r[4].name == "cycles")
    if not good and four[0] > 0:
        # the cycles repeated until they reach the target: each cycle adds about as
        # much evidence (issue 26: four cycles expected 30 for a 120 s lag against a
        # rate term under real noise, and did not separate them)
        n = min(MAX_CYCLES, max(5, math.ceil(4 * 1.2 * TARGET / four[0])))
        sps = [s.setpoint_c for s in d.steps] or [25.0]
        more = evaluate(cycles(float(min(sps)), float(max(sps)), float(sps[0]), n))
        rows.append(more)
        good = [r for r in rows if r[0] >= TARGET]
    best = min(good, key=lambda r: r[1]) if good else max(rows, key=lambda r: r[0])
    sep, _, s_ab, s_ba, prof = best
    caveat = (
        ""
        if sep >= SEPARATION
        else f"; not expected to separate them (below {SEPARATION:.0f}): no profile of the "
        "library tells them apart at this noise"
    )
    named = Profile(
        f"separate-{'-'.join(a.members)}-from-{'-'.join(b.members)}",
        prof.steps,
        prof.ambient_c,
        f"{prof.description}; proposed by gyrolab discrepancy to tell {a.label} from "
        f"{b.label} (expected ΔBIC {s_ab:.0f} and {s_ba:.0f}{caveat})",
    )
    return Proposal(
        named,
        {f"{a.label} over {b.label}": s_ab, f"{b.label} over {a.label}": s_ba},
        {r[4].name: r[0] for r in rows},
        sep,
    )


THERMAL = ("oven_overshoot", "rtd_self_heating")
"""Effects that shape the thermal chain a proposed profile is simulated through."""
