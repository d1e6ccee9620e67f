"""Does a compensation keep real rotation? Known rotations to inject into a static run,
and the share of their angle a compensated output keeps.

A temperature compensation must remove drift and nothing else: a gyro that is turned
must report the turn. Each event is a rate profile ω(t) (°/s) added to a static run; the
angle kept is

    kept = Σ (y_with − y_without) Δt  /  Σ ω Δt

where ``y_with``/``y_without`` are the compensated outputs of the run with and without
the event (each on its own time grid Δt: the full rate for a causal output, 3.6 s for
the paper's offline reconstruction), integrated over the whole run — whatever a method
smears in time still counts. 1 means the whole angle is kept.

Events (:func:`rotation_events`), at time ``t0`` into the run:

* ``index 90°`` — a step in angle: 9 °/s for 10 s (a turntable indexing move);
* ``pulse 1 min``, ``pulse 5 min``, ``pulse 15 min`` — 1 °/s held for that long;
* ``random 20 min`` — band-limited random motion over 20 min: 0.5 °/s mean (a net turn of
  600°, so that the ratio is well defined) plus white noise through a 4th-order
  Butterworth low-pass at 0.5 Hz scaled to 1 °/s rms (seeded).
"""

from __future__ import annotations

import numpy as np


def rotation_events(t: np.ndarray, t0: float, seed: int = 0) -> dict[str, np.ndarray]:
    """Rate profiles (°/s) on the sample times ``t`` (s), each starting at ``t0``."""
    from scipy.signal import butter, sosfilt

    t = np.asarray(t, dtype=float)
    rate_hz = 1.0 / float(np.median(np.diff(t)))

    def box(length_s: float, rate: float) -> np.ndarray:
        return np.where((t >= t0) & (t < t0 + length_s), rate, 0.0)

    ev = {
        "index 90°": box(10.0, 9.0),
        "pulse 1 min": box(60.0, 1.0),
        "pulse 5 min": box(300.0, 1.0),
        "pulse 15 min": box(900.0, 1.0),
    }
    on = (t >= t0) & (t < t0 + 1200.0)
    w = np.random.default_rng(seed).standard_normal(int(on.sum()))
    sos = butter(4, min(0.5, 0.4 * rate_hz), fs=rate_hz, output="sos")
    x = sosfilt(sos, w)
    r = np.zeros_like(t)
    r[on] = 0.5 + x / np.sqrt(np.mean(x * x))
    ev["random 20 min"] = r
    return ev


def angle_kept(
    y_with: np.ndarray, y_without: np.ndarray, dt: float, omega: np.ndarray, dt_omega: float
) -> float:
    """Share of the injected angle ``Σ ω Δt_ω`` that ``Σ (y_with − y_without) Δt`` keeps."""
    injected = float(np.sum(omega) * dt_omega)
    return float(np.sum(np.asarray(y_with) - np.asarray(y_without)) * dt) / injected
