"""The discrepancy loop: fit the current model, compare, localize, name, add, repeat —
selection only. What a candidate is comes from the catalogue each effect declares beside
its physics (``sim/effects.py``, :mod:`gyrolab.sim.candidate`); fitting a structure is
:mod:`.fitting`; scoring and detection limits are the channels' (:mod:`.channels`).

Channels and their candidate effects (each scored against the current model by a
likelihood criterion on the data it lives in):

=================  ==========================================  ==================
channel            candidates                                  score
=================  ==========================================  ==================
sample             ``outliers`` (spike tail),                  LR, lattice rule
                   ``quantization`` (value lattice)
temperature        ``oven_overshoot`` (oven PV),               ΔBIC
                   ``rtd_self_heating`` (PT100)
gyro, < 0.01 Hz    every declared gyro term: ``cubic_temp``    ΔBIC, learned
                   ``thermal_rate`` ``thermal_lag``            covariance
                   ``hysteresis`` ``warmup`` ``aging_ramp``
                   ``periodic``
gyro noise         ``rate_random_walk`` (Allan curve)          Δχ²
=================  ==========================================  ==================

``ΔBIC = BIC(current) − BIC(current + candidate)``. Each iteration looks at the channels in
that order (sample-level effects depend on no fit; the temperatures feed the gyro
regressors; the deterministic fit feeds the Allan curve of the residual) and adds the best
candidate of the first channel that has a significant one whose own gap metric shrinks.
Candidates whose score is within :data:`AMBIGUITY_MARGIN` of the best are reported with it
as an ``ambiguous`` set (at most three, best first): the data cannot tell them apart, and
the best is the one added. After each addition the earlier gyro choices are revisited
(drop and swap moves). The loop stops when no channel has a significant candidate.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gyrolab.sim.discrepancy import catalogue as cat
from gyrolab.sim.discrepancy.channels import gyro, noise, sample, temperature
from gyrolab.sim.discrepancy.data import BenchData
from gyrolab.sim.discrepancy.fitting import Fitted, Fitter, Structure, ThermalFits
from gyrolab.sim.discrepancy.gyro_fit import GyroStructure, fit_structure
from gyrolab.sim.discrepancy.identify import Explanation, LookAlike, look_alike, of_fit
from gyrolab.sim.discrepancy.limits import detection_limits
from gyrolab.sim.discrepancy.localize import localize
from gyrolab.sim.discrepancy.periodic import periodic_content
from gyrolab.sim.discrepancy.scored import Scored
from gyrolab.sim.discrepancy.separate import Proposal, propose
from gyrolab.sim.model import SimModel

AMBIGUITY_MARGIN = 10.0
"""Candidates within this many score units of the best are reported as ambiguous."""
MAX_ITER = 6
CHANNELS = (sample, temperature, gyro, noise)
"""The channels in the order an iteration looks at them (module docstring)."""


class Workflow:
    """Runs the discrepancy analysis of one recording against a starting model.
    ``thermal``: chamber and case fits to share (another axis of the same bench)."""

    def __init__(
        self, data: BenchData, model: SimModel, thermal: ThermalFits | None = None
    ) -> None:
        self.d = data
        self.model0 = model
        self.fitter = Fitter(data, model, thermal)

    def start(self) -> Structure:
        """The starting model's structure, its shapes (and wider forms) as it has them."""
        names0 = self.model0.effect_names()
        st = Structure(
            [n for n in names0 if n != "thermal_lag"]
            + (["thermal_lag"] if "thermal_lag" in names0 else [])
        )
        for n in names0:
            shape = cat.shape_of(n)
            if shape is not None:
                st.theta[n] = float(self.model0.get(n).params[shape])  # type: ignore[union-attr]
        for n in names0:
            wider = cat.terms(n).wider if cat.is_gyro_term(n) else None
            p = self.model0.get(n).params  # type: ignore[union-attr]
            if wider is not None and p.get(wider.present, 0.0) != 0.0:
                st.theta[f"{n}.{wider.param}"] = float(p[wider.param])
        ovs = self.model0.get("oven_overshoot")
        if ovs is not None:
            st.overshoot = (ovs.params["overshoot"], ovs.params["period_s"])
        return st

    # ----------------------------------------------------------------- the loop
    def choose(self, cur: Fitted) -> tuple[list[Scored], Choice | None, list[dict[str, Any]]]:
        """One iteration's choice: every channel's candidates (until a channel has an
        acceptable one), the accepted candidate with its ambiguous set, its look-alikes
        (:mod:`.identify`) and the refit model (or None), and the significant ones
        rejected because their own gap grew."""
        cands: list[Scored] = []
        rejected: list[dict[str, Any]] = []
        for channel in CHANNELS:
            cs = channel.score(self.fitter, cur)
            cands += cs
            cur.memo["scored"] = cands
            sig = sorted([c for c in cs if c.significant], key=lambda c: -c.score)
            # the best significant candidate whose own gap metric shrinks when added
            # (issue 18: an effect is judged by the gap that belongs to it)
            while sig:
                best, amb = select(sig)
                new = cur.structure.plus(best.effect)
                if best.theta is not None:
                    new.theta[best.effect] = float(best.theta)
                new.theta.update(best.form)
                nxt = self.fitter.fit(new)
                key = cat.gap_of(best.effect)
                if nxt.gaps[key] < cur.gaps[key]:
                    alikes = gyro.look_alikes(self.fitter, cur, best, cs, amb[1:])
                    return cands, Choice(best, amb, nxt, alikes, cur), rejected
                rejected.append(
                    {
                        "effect": best.effect,
                        "gap_metric": key,
                        "gap_metric_before_after": [cur.gaps[key], nxt.gaps[key]],
                    }
                )
                pair = self.with_partner(cur, best, key)
                if pair is not None:
                    rejected[-1]["added_with"] = pair.partner
                    return cands, pair, rejected
                sig = [c for c in sig if c is not best]
        return cands, None, rejected

    def with_partner(self, cur: Fitted, c: Scored, key: str) -> Choice | None:
        """A gyro candidate whose own gap grew, added with the candidate it needs
        (:func:`~.channels.gyro.partner`) when the pair shrinks that gap."""
        if c.channel != "gyro":
            return None
        found = gyro.partner(self.fitter, cur, c)
        if found is None:
            return None
        pair, d = found
        new = cur.structure.plus(c.effect).plus(d)
        new.theta.update(pair.form)
        nxt = self.fitter.fit(new)
        if nxt.gaps[key] >= cur.gaps[key]:
            return None
        return Choice(pair, [c.effect], nxt, [], cur, partner=d)

    def run(self, log: Any = None) -> Result:
        t_start = time.perf_counter()
        cur = self.fitter.fit(self.start())
        first = cur
        found: list[str] = []
        ambiguous: list[list[str]] = []
        looks: list[tuple[list[str], Choice]] = []
        steps: list[dict[str, Any]] = []
        for it in range(MAX_ITER):
            cands, accepted, rejected = self.choose(cur)
            entry: dict[str, Any] = {
                "iteration": it,
                "model_effects": list(cur.structure.effects),
                "gap": dict(cur.gaps),
                "localize": localize(self.d, cur),
                "candidates": [c.to_json() for c in cands],
            }
            if rejected:
                entry["rejected_gap_grew"] = rejected
            if accepted is None:
                entry["added"] = None
                steps.append(entry)
                break
            best, amb, nxt = accepted.best, accepted.ambiguous, accepted.fit
            key = cat.gap_of(best.effect)
            gone = {r["effect"] for r in rejected}
            amb = [a for a in amb[1:] if a not in gone]
            for a in accepted.look_alikes:  # look-alikes the data cannot exclude
                amb += [m for m in a.other.members if m not in amb and m != best.effect]
            entry["added"] = best.effect
            if accepted.partner:
                entry["added_with"] = accepted.partner
            entry["ambiguous_with"] = amb[:2]
            if accepted.look_alikes:
                entry["look_alikes"] = [a.to_json() for a in accepted.look_alikes]
            entry["gap_metric"] = key
            entry["gap_metric_before_after"] = [cur.gaps[key], nxt.gaps[key]]
            found.append(best.effect)
            if accepted.partner:
                found.append(accepted.partner)
            amb = [best.effect] + entry["ambiguous_with"]
            if len(amb) > 1:
                ambiguous.append(amb)
                looks.append((amb, accepted))
            if log:
                log(
                    f"iteration {it + 1}: added {best.effect}"
                    + (f" (ambiguous: {amb})" if len(amb) > 1 else "")
                )
            cur = nxt
            # revisit earlier choices: drop-one and swap moves among the gyro terms
            revised = self.revisit(cur, found, best.effect, accepted.partner)
            if revised is not None:
                cur, moves = revised
                entry["revisions"] = moves
                for mv in moves:
                    if mv["move"] == "drop":
                        found.remove(mv["effect"])
                    else:
                        found[found.index(mv["effect"])] = mv["to"]
                    ambiguous = [s for s in ambiguous if mv["effect"] not in s]
                    looks = [lk for lk in looks if mv["effect"] not in lk[0]]
                    if log:
                        log(f"iteration {it + 1}: revised {mv}")
            steps.append(entry)
        model = self.updated_model(cur)
        ambiguity = [self.ambiguity(s, c, model, i + 1) for i, (s, c) in enumerate(looks)]
        if accepted is None:  # the last iteration scored every candidate against ``cur``
            for amb_set in self.absorbed(cur, cands, steps, found, ambiguous):
                amb_set.k = len(ambiguity) + 1
                ambiguity.append(self.with_proposal(amb_set, model))
                ambiguous.append(amb_set.members)
        return Result(
            effects_found=found,
            ambiguous=ambiguous,
            gap_before=first.gaps,
            gap_after=cur.gaps,
            steps=steps,
            model=model,
            first=first,
            final=cur,
            detection_limits=detection_limits(self.fitter, cur),
            elapsed_s=time.perf_counter() - t_start,
            ambiguity=ambiguity,
            periodic_content=periodic_content(cur),
            temperature_source=self.d.temperature_source,
        )

    def ambiguity(self, members: list[str], c: Choice, model: SimModel, k: int) -> Ambiguity:
        """An ambiguous set with the evidence of each member and, where look-alikes were
        tested, the profile proposed to separate the winner from the first of them."""
        evidence = {
            x.effect: {"delta_bic": x.score, "params": x.evidence.get("params")}
            for x in c.candidates
            if x.effect in members
        }
        proposal = None
        if c.look_alikes:
            noise = gyro.judge(self.fitter, c.before)[3]
            proposal = propose(self.d, model, noise, c.look_alikes[0], self.fitter.poly_order)
            proposal.file = f"separating_profile_{k}.toml"
        return Ambiguity(members, evidence, [a.to_json() for a in c.look_alikes], proposal)

    def absorbed(
        self,
        cur: Fitted,
        cands: list[Scored],
        steps: list[dict[str, Any]],
        found: list[str],
        sets: list[list[str]],
    ) -> list[Ambiguity]:
        """Sets for evidence a named term took (docs/discrepancy.md, "Look-alike effects"):
        a gyro candidate C that was significant before a gyro term E was named, and still
        has positive evidence with E in the model (0 < ΔBIC ≤ the naming rule), is a
        member the data cannot exclude beside E: the set ``[E, C]`` (E alone, or E and
        C), with each one's evidence. Not when a set already holds both."""
        out: list[Ambiguity] = []
        scores = [{c["effect"]: c["score"] for c in st["candidates"]} for st in steps]
        _, w, sigma2, _ = gyro.judge(self.fitter, cur)
        for c in cands:
            if c.channel != "gyro" or c.fit is None or not 0.0 < c.score <= gyro.GYRO_SIG:
                continue
            took: tuple[float, int, str] | None = None  # (evidence taken, step, by whom)
            for i, st in enumerate(steps[:-1]):
                e = st.get("added")
                before = scores[i].get(c.effect, 0.0)
                after = scores[i + 1].get(c.effect, before)
                if e in found and cat.is_gyro_term(e) and before > gyro.GYRO_SIG:
                    if took is None or before - after > took[0]:
                        took = (before - after, i, e)
            if took is None or any({took[2], c.effect} <= set(s) for s in sets):
                continue
            _, i, e = took
            shaped = (e,) if cat.shape_of(e) else ()
            winner = Explanation(e, [e], cur.gyro.struct, np.asarray(cur.gyro.gls.beta), shaped)
            other = of_fit(f"{e} + {c.effect}", [e, c.effect], c.fit, delta_bic=c.score)
            look = look_alike(winner, other, -c.score, cur.ctx, w, sigma2, near=True)
            assert look is not None  # near: kept whatever the separations
            evidence = {
                e: {"delta_bic": scores[i][e], "params": gyro.params(self.fitter, cur).get(e)},
                c.effect: {
                    "delta_bic": c.score,
                    "delta_bic_before": scores[i][c.effect],
                    "params": c.evidence.get("params"),
                    "below_naming_rule": True,
                },
            }
            out.append(
                Ambiguity([e, c.effect], evidence, [look.to_json()], None, look=look, before=cur)
            )
        return out

    def with_proposal(self, a: Ambiguity, model: SimModel) -> Ambiguity:
        """``a`` with the profile proposed to separate its look-alike."""
        if a.look is not None and a.before is not None:
            noise = gyro.judge(self.fitter, a.before)[3]
            a.proposal = propose(self.d, model, noise, a.look, self.fitter.poly_order)
            a.proposal.file = f"separating_profile_{a.k}.toml"
        return a

    # ------------------------------------------------------------- revisiting
    def _struct_bic(self, cur: Fitted, names: list[str], scan: tuple[str, ...]) -> tuple:
        """BIC of a gyro structure under the current learned noise model."""
        assert cur.whitener is not None
        theta = {k: v for k, v in cur.gyro.struct.theta.items() if cat.theta_owner(k) in names}
        g = fit_structure(GyroStructure(names, theta), cur.ctx, scan=scan, whitener=cur.whitener)
        return self.fitter.cov_fit(g.struct, cur.ctx, cur.whitener).bic, g.struct.theta

    def revisit(
        self, cur: Fitted, found: list[str], newest: str, partner: str | None = None
    ) -> tuple[Fitted, list[dict[str, Any]]] | None:
        """After an addition, test each earlier-added gyro term: **drop** it when the model
        without it is within :data:`~.channels.gyro.GYRO_SIG` of the model with it (the
        newer terms explain what it did), **swap** it for another gyro term not in the
        model when that scores better by more than that. One move (the best) per call; the
        refit model and the moves, or None."""
        earlier = [e for e in found if cat.is_gyro_term(e) and e not in (newest, partner)]
        if not earlier:
            return None
        sig = gyro.GYRO_SIG
        names = self.fitter.gyro_struct(cur.structure).names
        others = gyro.candidates(self.fitter, cur, names)
        bic_now = self.fitter.cov_fit(cur.gyro.struct, cur.ctx, cur.whitener).bic  # type: ignore[arg-type]
        best_move: tuple[float, dict[str, Any], list[str], dict[str, float]] | None = None
        for e in earlier:
            without = [n for n in names if n != e]
            b_drop, th = self._struct_bic(cur, without, ())
            if b_drop - bic_now < sig:
                gain = sig - (b_drop - bic_now)
                if best_move is None or gain > best_move[0]:
                    best_move = (gain, {"move": "drop", "effect": e}, without, th)
            for c in others:
                swapped = [n if n != e else c for n in names]
                b_sw, th = self._struct_bic(cur, swapped, (c,) if cat.shape_of(c) else ())
                gain = bic_now - b_sw - sig
                if gain > 0 and (best_move is None or gain > best_move[0]):
                    best_move = (gain, {"move": "swap", "effect": e, "to": c}, swapped, th)
        if best_move is None:
            return None
        _, mv, new_names, th = best_move
        effects = [n for n in cur.structure.effects if not cat.is_gyro_term(n) or n in new_names]
        effects += [n for n in new_names if n not in effects and n != "bias_poly"]
        st = Structure(effects, {**cur.structure.theta, **th}, cur.structure.overshoot)
        for k in list(st.theta):
            if cat.theta_owner(k) == mv["effect"]:
                st.theta.pop(k)
        return self.fitter.fit(st), [mv]

    def updated_model(self, f: Fitted) -> SimModel:
        """The starting model updated with ``f``: every channel's fitted parameters."""
        params: dict[str, dict[str, float]] = {}
        for channel in (gyro, noise, sample, temperature):
            params.update(channel.params(self.fitter, f))
        return self.fitter.updated_model(f, params)


@dataclass
class Choice:
    """An iteration's accepted candidate: its score, ambiguous set (by score), refit model,
    look-alikes, and the model it was chosen against."""

    best: Scored
    ambiguous: list[str]
    fit: Fitted
    look_alikes: list[LookAlike]
    before: Fitted
    partner: str | None = None
    """The gyro term added with ``best`` (a pair whose signatures cancel alone)."""

    @property
    def candidates(self) -> list[Scored]:
        return self.before.memo.get("scored", [self.best])


@dataclass
class Ambiguity:
    """An ambiguous set of ``discrepancy.json`` with its evidence and proposed profile."""

    members: list[str]
    evidence: dict[str, Any]
    look_alikes: list[dict[str, Any]]
    proposal: Proposal | None
    look: LookAlike | None = None
    """The look-alike a proposal is still to be made for (:meth:`Workflow.absorbed`)."""
    before: Fitted | None = None
    """The model its noise was judged on."""
    k: int = 0
    """Its number among the run's sets."""

    def to_json(self) -> dict[str, Any]:
        return {
            "set": self.members,
            "evidence": self.evidence,
            "look_alikes": self.look_alikes,
            "proposed_profile": self.proposal.to_json() if self.proposal else None,
        }


def select(significant: list[Scored]) -> tuple[Scored, list[str]]:
    """The best of one channel's significant candidates, and the set it cannot be told
    apart from: every candidate within :data:`AMBIGUITY_MARGIN` of the best score (best
    first, at most three)."""
    ranked = sorted(significant, key=lambda c: -c.score)
    best = ranked[0]
    amb = [best.effect] + [c.effect for c in ranked[1:] if best.score - c.score < AMBIGUITY_MARGIN]
    return best, amb[:3]


@dataclass
class Result:
    """Outcome of a discrepancy analysis (docs/cli.md ``discrepancy.json`` contract)."""

    effects_found: list[str]
    ambiguous: list[list[str]]
    gap_before: dict[str, float]
    gap_after: dict[str, float]
    steps: list[dict[str, Any]]
    model: SimModel
    first: Fitted
    final: Fitted
    detection_limits: dict[str, dict[str, Any]]
    elapsed_s: float
    ambiguity: list[Ambiguity] = field(default_factory=list)
    """Each ambiguous set's evidence and proposed separating profile."""
    periodic_content: list[dict[str, Any]] = field(default_factory=list)
    """Cycles in the measurement and their spectral significance (:mod:`.periodic`)."""
    temperature_source: str = "pt100"
    """What the temperature channel measured: a PT100 on the case, or a die sensor."""

    def to_json(self) -> dict[str, Any]:
        return {
            "effects_found": self.effects_found,
            "ambiguous": self.ambiguous,
            "temperature_source": self.temperature_source,
            "ambiguity": [a.to_json() for a in self.ambiguity],
            "periodic_content": self.periodic_content,
            "gap_before": self.gap_before,
            "gap_after": self.gap_after,
            "steps": self.steps,
            "detection_limits": self.detection_limits,
            "chamber_cooling": {"form": self.final.oven.form, "smooth": self.final.oven.smooth},
            "elapsed_s": self.elapsed_s,
        }


def run_discrepancy(data: BenchData, model: SimModel | None = None, log: Any = None) -> Result:
    """Analyse ``data`` against ``model`` (default: the simulator's nominal model)."""
    from gyrolab.sim.model import nominal_model

    return Workflow(data, model or nominal_model()).run(log)
