"""Prandtl–Ishlinskii hysteresis: a weighted sum of play (backlash) operators of several
widths on the die-temperature estimate ``F``, computed reading by reading.

A single play of width ``w`` (:mod:`gyrolab.compensation.causal_features`, ``S``) gives
a hysteresis loop whose branches switch over exactly ``w`` °C after a reversal; a gyro
whose hysteresis is several mechanisms with different widths (the break family's three
plays, 0.3–4 °C wide, whose widths also change with temperature: issue 23) switches
gradually. The Prandtl–Ishlinskii operator (Brokate & Sprekels, *Hysteresis and Phase
Transitions*, 1996, ch. 2; Kuhnen, *Eur. J. Control* 9 (2003) 407) superposes plays of a
fixed width grid ``W_j`` with weights fitted by linear least squares::

    p_{j,n} = min(max(p_{j,n−1}, F_n − W_j/2), F_n + W_j/2)   play position, °C
    S_{j,n} = (F_n − p_{j,n}) / (W_j/2)                        branch, −1 … +1
    H_n     = Σ_j h_j S_{j,n}                                  drift, °/s

At power-on every play starts displaced by the same ``δ`` (°C) below the die-temperature
estimate, ``p_{j,0} = F_0 − clip(δ, −W_j/2, W_j/2)``: the die warms ``δ`` above the case
by its own self-heating before the chamber moves, which the PT100 does not see — a narrow
play is then on its heating branch, a wide one part of the way (the single play's start
branch ``s₀`` of :class:`~gyrolab.compensation.causal_features.CausalParams` is the case
``δ = s₀ w/2`` of one play).
The same operations as the single play, in the same order: :func:`pi_step` (pure Python
floats, one reading) and :func:`pi_branches` (each play over a run by the play kernel
shared with the simulator, :func:`gyrolab.numerics.play.play`) agree bit for bit.
"""

from __future__ import annotations

import numpy as np

from gyrolab.numerics.play import play

#: the play widths of the operator, °C: spanning the single play's width grid
#: (:data:`gyrolab.compensation.structured.WIDTH_GRID_C`, 0.25–4 °C). Measured on the
#: break family against (0.25, 1, 2, 4) and (0.5, 3) (docs/results.md): the same within
#: ±0.01 of causal ÷ oracle per unit.
PI_WIDTHS_C = (0.5, 1.5, 4.0)


def pi_start(F0: float, widths: tuple[float, ...], offset_c: float = 0.0) -> np.ndarray:
    """The play positions at power-on (°C): ``F_0 − clip(δ, −W_j/2, W_j/2)``."""
    half = 0.5 * np.asarray(widths, dtype=float)
    return float(F0) - np.clip(float(offset_c), -half, half)


def pi_step(p: np.ndarray, F: float, widths: tuple[float, ...]) -> list[float]:
    """Advance the play positions ``p`` (°C, in place) by one die temperature ``F``;
    return the branches ``S_j``."""
    out = []
    for j, w in enumerate(widths):
        half = 0.5 * float(w)
        pj = float(p[j])
        if pj < F - half:
            pj = F - half
        elif pj > F + half:
            pj = F + half
        p[j] = pj
        out.append((F - pj) / half)
    return out


def pi_branches(
    F: np.ndarray, widths: tuple[float, ...], p: np.ndarray | None = None
) -> np.ndarray:
    """The branches ``S_j`` ``(N, m)`` of the plays of ``widths`` (°C) over die
    temperatures ``F`` (°C), from positions ``p`` (default: at ``F[0]``, δ = 0;
    updated in place)."""
    F = np.ascontiguousarray(F, dtype=np.float64)
    if p is None:
        p = pi_start(float(F[0]) if F.size else 0.0, widths)
    out = np.empty((F.size, len(widths)))
    for j, w in enumerate(widths):  # the plays are independent: one pass each
        p[j] = play(F, float(p[j]), 0.5 * float(w), out[:, j])
    return out


__all__ = ["PI_WIDTHS_C", "pi_branches", "pi_start", "pi_step"]
