"""The play (backlash) operator over a series — the one kernel behind the simulator's
hysteresis effect (:mod:`gyrolab.sim.effects`) and the Prandtl–Ishlinskii branches of the
compensation (:mod:`gyrolab.compensation.hysteresis`).

Each sample moves the play's position ``p`` (°C) only as far as keeps the input inside
``[p − h, p + h]``::

    p_i = min(max(p_{i−1}, x_i − h_i), x_i + h_i),    out_i = (x_i − p_i) / h_i ∈ [−1, 1]

(Krasnosel'skii & Pokrovskii, *Systems with Hysteresis*, Springer 1989, §I.2; Brokate &
Sprekels, *Hysteresis and Phase Transitions*, Springer 1996, §2.3.)
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def play(temp: np.ndarray, p0: float, half: float, out: np.ndarray) -> float:  # pragma: no cover
    """Play operator of half-width ``half`` (°C) from position ``p0`` over ``temp`` (°C):
    ``out_i = (T_i − p_i)/half`` (written into ``out``); returns the last position."""
    p = p0
    for i in range(temp.size):
        x = temp[i]
        if p < x - half:
            p = x - half
        elif p > x + half:
            p = x + half
        out[i] = (x - p) / half
    return p


@numba.njit(cache=True, nogil=True)
def play_var(
    temp: np.ndarray, p0: float, half: np.ndarray, out: np.ndarray
) -> float:  # pragma: no cover
    """Play operator whose half-width varies per sample (``half[i]`` > 0), as :func:`play`."""
    p = p0
    for i in range(temp.size):
        x = temp[i]
        h = half[i]
        if p < x - h:
            p = x - h
        elif p > x + h:
            p = x + h
        out[i] = (x - p) / h
    return p


__all__ = ["play", "play_var"]
