"""Gyro-channel candidates: every deterministic gyro term the model lacks (each effect's
declared ``terms``), scored by ΔBIC of the low-frequency bins under a noise covariance
learned from the residual of the *saturated* model (docs/discrepancy.md, "Why a learned
covariance"), and their detection limits from the expected ΔBIC of their whitened
signatures.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gyrolab.sim.discrepancy import catalogue as cat
from gyrolab.sim.discrepancy import noise_fit as nf
from gyrolab.sim.discrepancy.catalogue import limit_entry
from gyrolab.sim.discrepancy.fitting import Fitted, Fitter
from gyrolab.sim.discrepancy.gls import CovWhitener
from gyrolab.sim.discrepancy.gyro_fit import (
    GyroFit,
    GyroStructure,
    design,
    effect_params,
    fit_structure,
    redundant,
    widen_form,
)
from gyrolab.sim.discrepancy.identify import LookAlike, combined, look_alike, of_fit
from gyrolab.sim.discrepancy.scored import Scored

GYRO_SIG = 10.0
"""ΔBIC above which a gyro-channel candidate is significant."""


def candidates(fx: Fitter, cur: Fitted, names: list[str] | None = None) -> list[str]:
    """The gyro terms that are candidates against ``cur``: not in its gyro structure (or
    ``names``), and not already columns of its design."""
    base = fx.gyro_struct(cur.structure)
    have = base.names if names is None else names
    return [
        n
        for n in cat.on_channel("gyro")
        if n not in have and not redundant(n, GyroStructure(have, base.theta), cur.ctx)
    ]


def judging_noises(
    fx: Fitter, cur: Fitted
) -> tuple[dict[str, GyroFit], list[tuple[CovWhitener, int]]]:
    """Each gyro candidate fitted alone (its shape scanned), and the whiteners of the noise
    models learned from the saturated model's residual (see :func:`score`), each with its
    parameter penalty (computed once per fit)."""
    if "judging" not in cur.memo:
        cur.memo["judging"] = _judging_noises(fx, cur)
    return cur.memo["judging"]


def _judging_noises(
    fx: Fitter, cur: Fitted
) -> tuple[dict[str, GyroFit], list[tuple[CovWhitener, int]]]:
    st = cur.structure
    base_struct = fx.gyro_struct(st)
    assert cur.whitener is not None
    fits: dict[str, GyroFit] = {}
    shaped = tuple(n for n in base_struct.names if cat.shape_of(n))
    for name in candidates(fx, cur):
        s2 = GyroStructure(base_struct.names + [name], dict(cur.gyro.struct.theta))
        own = (name,) if cat.shape_of(name) else ()
        fits[name] = fit_structure(s2, cur.ctx, scan=own, whitener=cur.whitener)
        if shaped:
            # the model's own shapes scanned again with the candidate: a term named first
            # took a shape that also covered the candidate's signature (issue 26: a 400 s
            # die lag + a hysteresis step named as a 195 s lag alone, the hysteresis at
            # ΔBIC −6.5 with the lag held, +36 with it re-scanned: τ 403 s, h and w true)
            joint = fit_structure(s2, cur.ctx, scan=own + shaped, whitener=cur.whitener)
            if fx.cov_fit(joint.struct, cur.ctx, cur.whitener).bic < (
                fx.cov_fit(fits[name].struct, cur.ctx, cur.whitener).bic
            ):
                fits[name] = joint
    # the saturated model: every candidate at the shape its own scan chose; of those that
    # change the temperature the others see (they cannot all hold at once) the one whose
    # own fit is best — left out, a real die lag stays in the residual, the noise model
    # learns it as a Gauss–Markov hump, and the lag and whatever comes with it no longer
    # score (issue 26: a 400 s lag + hysteresis named rate_random_walk)
    sat = [n for n in fits if cat.terms(n).temperature is None]
    temp = [n for n in fits if cat.terms(n).temperature is not None]
    if temp:
        sat.append(min(temp, key=lambda n: fits[n].bic))
    sat_theta = dict(cur.gyro.struct.theta)
    for n in sat:
        if cat.shape_of(n):
            sat_theta[n] = fits[n].struct.theta[n]
    satstruct = GyroStructure(list(base_struct.names) + sat, sat_theta)
    satfit = fx.cov_fit(satstruct, cur.ctx, cur.whitener)
    curve = nf.measured_allan(fx.d, cur.ctx.y - satfit.pred)
    has_k = st.has("rate_random_walk")
    learned = [nf.fit_cov_noise(curve, fx.d.bin_s, rrw=has_k)]
    if not has_k:
        learned.append(nf.fit_cov_noise(curve, fx.d.bin_s, rrw=True))
    cur.memo["learned"] = learned
    return fits, [(fx.whitener(c), fx.noise_penalty(c)) for c in learned]


def score(fx: Fitter, cur: Fitted) -> list[Scored]:
    """ΔBIC of each gyro term not in the model, every one judged with one noise model:
    the one learned from the residual of the *saturated* model (current terms plus every
    candidate, each at its own best shape). A missing slow term inflates the current
    residual's long-τ Allan curve, and a noise model learned from that would swallow the
    very terms being tested (two of them at once all the more); the saturated residual is
    free of them, and since the noise scale is profiled out of the BIC, only the learned
    *shape* of the spectrum matters. Unless the model has it, a random-walk alternative
    learned from the same residual competes (the better of the two for each model, its
    parameter counted): slow wander must not pass for a ramp or a step."""
    out = []
    fits, _ = judging_noises(fx, cur)

    def best_bic(struct: GyroStructure) -> tuple[float, int]:
        return _best_bic(fx, cur, struct)

    base_bic, base_noise = best_bic(cur.gyro.struct)
    for name, g in fits.items():
        form = "single"
        if cat.terms(name).wider is not None:
            g, form = widen_form(g, cur.ctx, name, lambda s: best_bic(s)[0])
        cand_bic, cand_noise = best_bic(g.struct)
        dbic = base_bic - cand_bic
        moved = {k: v for k, v in g.struct.theta.items() if cur.gyro.struct.theta.get(k, v) != v}
        if moved:
            # the current terms alone at the shapes the candidate's fit moved them to: what
            # moving them gains is not the candidate's evidence (a warm-up of two
            # opposite-sign exponentials taken at τ 1833 s and moved to 200 s beside any
            # candidate: every one scored 60–170 against the model at 1833 s, and a false
            # aging ramp was named)
            at = GyroStructure(cur.gyro.struct.names, {**cur.gyro.struct.theta, **moved})
            dbic = min(base_bic, best_bic(at)[0]) - cand_bic
        params = effect_params(g).get(name, {})
        out.append(
            Scored(
                name,
                "gyro",
                float(dbic),
                bool(dbic > GYRO_SIG),
                {
                    "delta_bic": float(dbic),
                    "params": params,
                    "noise_with_rrw": [bool(base_noise), bool(cand_noise)],
                    "form": form,
                    "model_shapes_moved": {
                        k: [v0, g.struct.theta[k]]
                        for k, v0 in cur.gyro.struct.theta.items()
                        if g.struct.theta.get(k, v0) != v0
                    },
                },
                theta=g.struct.theta.get(name),
                form={
                    k: v
                    for k, v in g.struct.theta.items()
                    if k == cat.form_key(cat.theta_owner(k))
                    or (k != name and cur.gyro.struct.theta.get(k) != v)
                },
                fit=g,
            )
        )
    return out


def partner(fx: Fitter, cur: Fitted, c: Scored) -> tuple[Scored, str] | None:
    """A significant candidate ``c`` whose own gap grew when added alone, with the other
    gyro candidate it needs: two terms whose signatures cancel on this profile score little
    alone, and the one that scores fits only part of its signature (issue 26: a 400 s die
    lag + a hysteresis step on a heating staircase, ΔBIC −3 and +18 alone, the hysteresis
    at half its size and its gap growing; +79 together). Each other candidate ``d`` is
    fitted beside ``c`` (both shapes scanned, the judging noise); the best pair by BIC is
    returned, as ``c``'s :class:`Scored` (its score the pair's ΔBIC over the current model,
    its ``fit`` the pair's) and ``d``, when each member is significant beside the other
    (ΔBIC of the pair over the pair less it > :data:`GYRO_SIG`); else None."""
    fits, _ = judging_noises(fx, cur)
    if c.fit is None or c.effect not in fits:
        return None
    base = cur.gyro.struct
    base_bic = _best_bic(fx, cur, base)[0]
    best: tuple[float, GyroFit, str, dict[str, float]] | None = None
    for d in fits:
        if d == c.effect or (
            cat.terms(d).temperature is not None and cat.terms(c.effect).temperature is not None
        ):
            continue
        theta = {**base.theta, **c.fit.struct.theta}
        if d in fits[d].struct.theta:
            theta[d] = fits[d].struct.theta[d]
        scan = tuple(n for n in (c.effect, d) if cat.shape_of(n))
        s2 = GyroStructure(base.names + [c.effect, d], theta)
        g = fit_structure(s2, cur.ctx, scan=scan, whitener=cur.whitener)
        b = _best_bic(fx, cur, g.struct)[0]
        cond = {
            n: _best_bic(
                fx, cur, GyroStructure([m for m in g.struct.names if m != n], g.struct.theta)
            )[0]
            - b
            for n in (c.effect, d)
        }
        if min(cond.values()) > GYRO_SIG and (best is None or b < best[0]):
            best = (b, g, d, cond)
    if best is None:
        return None
    b, g, d, cond = best
    dbic = base_bic - b
    prm = effect_params(g)
    scored = Scored(
        c.effect,
        "gyro",
        float(dbic),
        True,
        {
            **c.evidence,
            "delta_bic": float(dbic),
            "delta_bic_alone": c.score,
            "params": prm.get(c.effect, {}),
            "with": d,
            "with_params": prm.get(d, {}),
            "delta_bic_beside_other": cond,
        },
        theta=g.struct.theta.get(c.effect),
        form={k: v for k, v in g.struct.theta.items() if base.theta.get(k) != v},
        fit=g,
    )
    return scored, d


def _best_bic(fx: Fitter, cur: Fitted, struct: GyroStructure) -> tuple[float, int]:
    """BIC of a structure under the better of the judging noise models (its parameters
    counted), and which."""
    ln_n = math.log(cur.ctx.y.size)
    _, noises = judging_noises(fx, cur)
    bics = [fx.cov_fit(struct, cur.ctx, w).bic + extra * ln_n for w, extra in noises]
    i = int(np.argmin(bics))
    return bics[i], i


def judge(fx: Fitter, cur: Fitted) -> tuple[GyroFit, CovWhitener, float, nf.CovNoise]:
    """The current model's fit under the judging noise model it prefers, that noise's
    whitener, the innovation variance σ² (the scale the limits and the look-alike tests
    use) and the noise model itself."""
    if "judge" not in cur.memo:
        _, noises = judging_noises(fx, cur)
        ln_n = math.log(cur.ctx.y.size)
        fits = [(fx.cov_fit(cur.gyro.struct, cur.ctx, w), w, k) for w, k in noises]
        i = min(range(len(fits)), key=lambda j: fits[j][0].bic + fits[j][2] * ln_n)
        gfit, w, _ = fits[i]
        cur.memo["judge"] = (gfit, w, gfit.gls.rss / gfit.gls.n, cur.memo["learned"][i])
    return cur.memo["judge"]


def look_alikes(
    fx: Fitter, cur: Fitted, best: Scored, cands: list[Scored], near: list[str]
) -> list[LookAlike]:
    """The explanations the data cannot exclude beside ``best`` (:mod:`..identify`):
    every other gyro candidate with a positive score and, when ``best`` won in its wider
    form, its plain form plus another candidate; those in ``near`` (within the
    ambiguity margin of ``best``'s score) with their separations whatever they are.
    Ordered by the smaller of their two expected separations, the least separable first."""
    if best.channel != "gyro" or best.fit is None:
        return []
    _, w, sigma2, _ = judge(fx, cur)
    ctx = cur.ctx
    base_bic, _ = _best_bic(fx, cur, cur.gyro.struct)
    win = of_fit(best.effect, [best.effect], best.fit, **_evidence(best))
    rivals = [c for c in cands if c.channel == "gyro" and c.effect != best.effect and c.score > 0]
    others = [
        (of_fit(c.effect, [c.effect], c.fit, **_evidence(c)), best.score - c.score) for c in rivals
    ]
    if best.evidence.get("form", "single") != "single":
        base = fx.gyro_struct(cur.structure)
        for c in rivals:
            g = combined(base, best.fit, best.effect, c.effect, ctx, w)
            score = base_bic - _best_bic(fx, cur, g.struct)[0]
            label = f"{best.effect} (one component) + {c.effect}"
            members = [best.effect, c.effect]
            e = of_fit(label, members, g, delta_bic=float(score), params=effect_params(g))
            others.append((e, best.score - score))
    found = [
        look_alike(win, o, m, ctx, w, sigma2, near=o.members == [n] and n in near)
        for o, m in others
        for n in o.members[-1:]
    ]
    # the hardest to exclude first: the set is capped, and the proposal separates the first
    return sorted((a for a in found if a is not None), key=lambda a: min(a.sep_winner, a.sep_other))


def _evidence(c: Scored) -> dict[str, Any]:
    return {
        "delta_bic": c.score,
        "params": c.evidence.get("params"),
        "form": c.evidence.get("form"),
    }


def limits(fx: Fitter, cur: Fitted) -> dict[str, dict[str, Any]]:
    """For each gyro term not in ``cur``: the amplitude ``a`` at which the expected score
    of its whitened signature reaches :data:`GYRO_SIG` (limits.py), at the reference
    shape the effect declares; a term that changes the bias-setting temperature
    (``thermal_lag``) linearized, ``bias(T_d) ≈ bias(T_c) − τ·bias′(T_c)·dT_c/dt``."""
    ctx = cur.ctx
    base = cur.gyro.struct
    # the noise model the candidates are judged with (the saturated model's, the better
    # of it and its random-walk alternative for the current model)
    _, w, sigma2, _ = judge(fx, cur)
    n = ctx.y.size
    ln_n = math.log(n)
    X0, _ = design(base, ctx)
    s0 = np.sqrt(np.mean(X0 * X0, axis=0))
    s0[s0 == 0] = 1.0
    Q, _ = np.linalg.qr(w(X0 / s0))

    def energy(cols: np.ndarray) -> np.ndarray:
        z = w(cols.reshape(n, -1))
        z = z - Q @ (Q.T @ z)
        return (z * z).sum(axis=0)

    out: dict[str, dict[str, Any]] = {}
    for name in candidates(fx, cur, base.names):
        if cat.terms(name).temperature is not None:
            c = cur.gyro.coef()
            T = np.interp(ctx.t, ctx.grid_t, ctx.case_c) - 25.0
            slope = np.zeros_like(T)
            for i in range(1, 5):
                slope += i * c.get(f"bias_poly.c{i}", 0.0) * T ** (i - 1)
            slope += 3.0 * c.get("cubic_temp.c3", 0.0) * T**2
            x = -slope * np.interp(ctx.t, ctx.grid_t, ctx.dcase)
            e = float(energy(x)[0])
            k = 1
        else:
            th = dict(base.theta)
            at = cat.candidate(name).limit_at  # type: ignore[union-attr]
            shape = cat.shape_of(name)
            if shape is not None:
                th[name] = at[shape]
            X, cols = design(GyroStructure(base.names + [name], th), ctx)
            sel = [i for i, col in enumerate(cols) if col.startswith(name + ".")]
            en = energy(X[:, sel])
            e = float(np.mean(en))  # periodic: sin and cos averaged over the phase
            k = len(sel) + int(shape is not None)
        need = max(GYRO_SIG + k * ln_n - 1.0, 1e-9)
        lim = math.sqrt(need * sigma2 / e) if e > 0 else None
        out[name] = limit_entry(name, lim, "expected ΔBIC of the whitened signature")
    return out


def params(fx: Fitter, f: Fitted) -> dict[str, dict[str, float]]:
    """Fitted simulator parameters of every gyro term of ``f``."""
    return effect_params(f.gyro)
