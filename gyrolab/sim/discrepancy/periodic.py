"""Periodic content in the measurement (``periodic_content`` of ``discrepancy.json``).

A cycle in a gyro's output at a fixed period — an HVAC or chamber-compressor cycle, a
vibration source beating with the sample clock — belongs to the bench more often than to
the sensor: nothing in a MEMS gyro keeps wall-clock time. The workflow names it
``periodic`` when a sine fits (the model needs it), and states apart from the sensor
effects what the spectrum says about it, so that the user can check the bench:

* the periodogram of the low-frequency residual of the final model with its periodic
  terms put back (Hann window, one-sided PSD of the bins);
* at each peak in the ``periodic`` search band, its ratio ``z`` to the local level of the
  spectrum (a line in log-log over ±50 % of the frequency, at least ±40 bins, the peak's
  own ±2 bins left out: :func:`local_level`), and the false-alarm probability of so high
  a peak anywhere in the band: a periodogram ordinate of Gaussian noise over its local
  level is Exp(1), so one bin exceeds ``z`` with probability ``e^{−z}`` and any of the M
  band's bins with ``1 − (1 − e^{−z})^M``. The ratio is reported to the local median
  (``z·ln 2``, the median of Exp(1) being ln 2), as spectra are read by eye;
* the amplitude of the sine at the peak (least squares at that frequency).

A peak is reported when its false-alarm probability is below :data:`FAP` or the
``periodic`` effect was named near it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gyrolab.sim.discrepancy import catalogue as cat
from gyrolab.sim.discrepancy.fitting import Fitted
from gyrolab.sim.discrepancy.gyro_fit import design

FAP = 0.01
"""False-alarm probability below which a spectral peak is reported even when unnamed."""
NOTE = (
    "present in the measurement; check the bench (an HVAC or chamber-compressor cycle, a "
    "vibration source): a sensor effect keeps no wall-clock period"
)


def cycle_residual(f: Fitted) -> np.ndarray:
    """The final model's low-frequency residual with its periodic terms (declared
    ``scan="frequency"``) put back."""
    r = f.ctx.y - f.gyro.pred
    cycles = cycle_terms(f)
    if cycles:
        X, cols = design(f.gyro.struct, f.ctx)
        for i, col in enumerate(cols):
            if col.split(".")[0] in cycles:
                r = r + X[:, i] * f.gyro.gls.beta[i]
    return r


def spectrum(x: np.ndarray, bin_s: float) -> tuple[np.ndarray, np.ndarray]:
    """One-sided PSD (Hann window) of a series of ``bin_s`` bins: frequencies (Hz), PSD."""
    x = np.asarray(x, dtype=float) - float(np.mean(x))
    w = np.hanning(x.size)
    X = np.fft.rfft(x * w)
    p = 2.0 * bin_s * np.abs(X) ** 2 / float(np.sum(w * w))
    return np.fft.rfftfreq(x.size, bin_s)[1:], p[1:]


def local_level(
    freq: np.ndarray, p: np.ndarray, half_rel: float = 0.5, min_half: int = 40, guard: int = 2
) -> np.ndarray:
    """The spectrum's local level at each bin: a straight line fitted to ``ln p`` against
    ``ln f`` over ±``half_rel`` of the bin's index (at least ±``min_half`` bins), its own
    ±``guard`` bins left out, plus Euler's γ (``E[ln X] = −γ`` for X ~ Exp(1)): unbiased
    for a power-law background even where the window is cut at the lowest frequency."""
    lf, lp = np.log(freq), np.log(np.maximum(p, 1e-300))
    n = p.size
    cum = [np.concatenate([[0.0], np.cumsum(v)]) for v in (np.ones(n), lf, lp, lf * lf, lf * lp)]
    k = np.arange(n)
    h = np.maximum(min_half, (half_rel * (k + 1)).astype(int))
    lo, hi = np.maximum(0, k - h), np.minimum(n, k + h + 1)
    glo, ghi = np.maximum(lo, k - guard), np.minimum(hi, k + guard + 1)
    # sums over the window less the guard band, from prefix sums: O(n) in all
    s0, sx, sy, sxx, sxy = (c[hi] - c[lo] - (c[ghi] - c[glo]) for c in cum)
    b = (s0 * sxy - sx * sy) / np.maximum(s0 * sxx - sx * sx, 1e-300)
    a = (sy - b * sx) / s0
    return np.exp(a + b * lf + np.euler_gamma)


def cycle_terms(f: Fitted) -> list[str]:
    """The fit's terms that are cycles (declared ``scan="frequency"``)."""
    return [n for n in f.gyro.struct.names if cat.terms(n).scan == "frequency"]


def periodic_content(f: Fitted) -> list[dict[str, Any]]:
    """The spectral peaks of a fit's residual (cycles put back) worth a look (module
    docstring), strongest first."""
    ctx = f.ctx
    named = [f.gyro.struct.theta[n] for n in cycle_terms(f)]
    grids = [
        t.grid
        for n in cat.gyro_terms()
        if (t := cat.terms(n)).scan == "frequency" and t.grid is not None
    ]
    band = grids[0](ctx.duration_s, ctx.bin_s) if grids else None
    return spectral_peaks(cycle_residual(f), ctx.t, ctx.bin_s, band, named[0] if named else None)


def spectral_peaks(
    x: np.ndarray,
    t: np.ndarray,
    bin_s: float,
    band: np.ndarray | None = None,
    named_period_s: float | None = None,
) -> list[dict[str, Any]]:
    """Peaks of the spectrum of the series ``x`` (bins at times ``t``) between the
    shortest and longest periods of ``band`` (default: all) whose false-alarm
    probability is below :data:`FAP`, or near ``named_period_s`` (within 10 %): period,
    sine amplitude, ratio to the local median, false-alarm probability (module
    docstring); at most three, strongest first."""
    freq, p = spectrum(x, bin_s)
    periods = 1.0 / freq if band is None else np.asarray(band, dtype=float)
    f_lo, f_hi = 1.0 / float(np.max(periods)), 1.0 / float(np.min(periods))
    inside = (freq >= f_lo) & (freq <= f_hi)
    if inside.sum() < 3:
        return []
    level = local_level(freq, p)
    z_all = p / np.maximum(level, 1e-300)
    m = int(inside.sum())
    out = []
    idx = np.flatnonzero(inside)
    last = p.size - 1
    peaks = [k for k in idx if z_all[k] >= max(z_all[max(k - 1, 0)], z_all[min(k + 1, last)])]
    for k in sorted(peaks, key=lambda k: -z_all[k]):
        z = float(z_all[k])
        fap = -math.expm1(m * math.log1p(-math.exp(-z))) if z < 700 else 0.0
        period = 1.0 / freq[k]
        near = named_period_s is not None and abs(period / named_period_s - 1.0) < 0.1
        if fap >= FAP and not near:
            continue
        if near:  # the fitted period, finer than the periodogram's grid
            period = float(named_period_s)  # type: ignore[arg-type]
        wt = 2.0 * math.pi / period * np.asarray(t, dtype=float)
        A = np.column_stack([np.sin(wt), np.cos(wt), np.ones_like(wt)])
        c, *_ = np.linalg.lstsq(A, x, rcond=None)
        out.append(
            {
                "period_s": float(period),
                "amplitude_dps": float(math.hypot(c[0], c[1])),
                "peak_to_local_median": z * math.log(2.0),
                "false_alarm_probability": float(fap),
                "frequencies_searched": m,
                "named_periodic": bool(near),
                "note": NOTE,
            }
        )
        if len(out) == 3:
            break
    return out
