"""Sensors of the simulated bench: the PT100 (IEC 60751) and the gyro's ADC.

PT100, Callendar–Van Dusen (IEC 60751:2008, §4.2)::

    R(T) = R0 [1 + A T + B T²]                    T ≥ 0 °C
    R(T) = R0 [1 + A T + B T² + C (T − 100) T³]    T < 0 °C

with A = 3.9083e-3 /°C, B = −5.775e-7 /°C², C = −4.183e-12 /°C⁴, R0 = 100 Ω. The inverse is
the quadratic's root above 0 °C and Newton's method (from that root) below.

ADC: a bipolar converter of ``bits`` bits and reference ``vref_v`` digitises the gyro's
analogue output ``v = offset_v + gain_v_per_dps · Ω``::

    counts = clip(round(v / vref_v · 2^(bits−1)), −2^(bits−1), 2^(bits−1) − 1)
    Ω      = (counts · vref_v / 2^(bits−1) − offset_v) / gain_v_per_dps
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

CVD_A = 3.9083e-3
CVD_B = -5.775e-7
CVD_C = -4.183e-12
PT100_R0 = 100.0


def cvd_resistance(t_c: np.ndarray | float, r0: float = PT100_R0) -> np.ndarray | float:
    """PT100 resistance (Ω) at temperature ``t_c`` (°C), IEC 60751 Callendar–Van Dusen."""
    if isinstance(t_c, (float, int)):  # scalar fast path: one reading per second
        x = float(t_c)
        r = 1.0 + CVD_A * x + CVD_B * x * x
        return r0 * (r + CVD_C * (x - 100.0) * x**3 if x < 0.0 else r)
    t = np.asarray(t_c, dtype=float)
    r = 1.0 + CVD_A * t + CVD_B * t * t
    r = np.where(t < 0.0, r + CVD_C * (t - 100.0) * t**3, r)
    out = r0 * r
    return float(out) if out.ndim == 0 else out


def cvd_temperature(r_ohm: np.ndarray | float, r0: float = PT100_R0) -> np.ndarray | float:
    """Temperature (°C) of a PT100 reading ``r_ohm`` (Ω): inverse of :func:`cvd_resistance`.

    Closed form ``T = (−A + √(A² − 4B(1 − R/R0))) / 2B`` for R ≥ R0; below, Newton's method
    on the full equation starting from that root (converges to < 1e-9 °C in a few steps).
    """
    if isinstance(r_ohm, (float, int)):
        return _cvd_temperature_scalar(float(r_ohm) / r0)
    r = np.asarray(r_ohm, dtype=float) / r0
    t = (-CVD_A + np.sqrt(np.maximum(CVD_A * CVD_A - 4.0 * CVD_B * (1.0 - r), 0.0))) / (2.0 * CVD_B)
    neg = r < 1.0
    if np.any(neg):
        tn = t[neg] if t.ndim else t
        rn = r[neg] if r.ndim else r
        for _ in range(8):
            f = 1.0 + CVD_A * tn + CVD_B * tn**2 + CVD_C * (tn - 100.0) * tn**3 - rn
            df = CVD_A + 2.0 * CVD_B * tn + CVD_C * (4.0 * tn**3 - 300.0 * tn**2)
            tn = tn - f / df
        if t.ndim:
            t = t.copy()
            t[neg] = tn
        else:
            t = tn
    return float(t) if np.ndim(t) == 0 else t


def _cvd_temperature_scalar(r: float) -> float:
    t = (-CVD_A + math.sqrt(max(CVD_A * CVD_A - 4.0 * CVD_B * (1.0 - r), 0.0))) / (2.0 * CVD_B)
    if r < 1.0:
        for _ in range(8):
            f = 1.0 + CVD_A * t + CVD_B * t * t + CVD_C * (t - 100.0) * t**3 - r
            df = CVD_A + 2.0 * CVD_B * t + CVD_C * (4.0 * t**3 - 300.0 * t * t)
            t -= f / df
    return t


@dataclass(frozen=True)
class AdcModel:
    """The gyro's ADC: ``bits``-bit bipolar, reference ``vref_v`` (V), front-end gain
    ``gain_v_per_dps`` (V per °/s, the gyro scale factor) and offset ``offset_v`` (V)."""

    bits: int = 24
    vref_v: float = 2.5
    gain_v_per_dps: float = 0.01
    offset_v: float = 0.0

    def __post_init__(self) -> None:
        if not (2 <= int(self.bits) <= 32):
            raise ValueError("adc bits must be 2..32")
        if not (self.vref_v > 0 and np.isfinite(self.vref_v)):
            raise ValueError("adc vref_v must be > 0")
        if not (self.gain_v_per_dps != 0 and np.isfinite(self.gain_v_per_dps)):
            raise ValueError("adc gain_v_per_dps must be non-zero")
        if not np.isfinite(self.offset_v):
            raise ValueError("adc offset_v must be finite")

    @property
    def full_scale(self) -> int:
        """2^(bits−1): counts per ``vref_v``."""
        return 1 << (int(self.bits) - 1)

    @property
    def lsb_dps(self) -> float:
        """One count in °/s."""
        return self.vref_v / self.full_scale / abs(self.gain_v_per_dps)

    def dps_to_counts(self, rate_dps: np.ndarray) -> np.ndarray:
        """ADC codes (int32) of a rate in °/s (saturating at the converter's range)."""
        fs = self.full_scale
        v = self.offset_v + self.gain_v_per_dps * np.asarray(rate_dps, dtype=float)
        c = np.rint(v * (fs / self.vref_v))
        return np.clip(c, -fs, fs - 1).astype(np.int32)

    def counts_to_dps(self, counts: np.ndarray) -> np.ndarray:
        """Rate in °/s of ADC codes, as the bench software converts them."""
        c = np.asarray(counts, dtype=float)
        return (c * (self.vref_v / self.full_scale) - self.offset_v) / self.gain_v_per_dps

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["conversion"] = "rate_dps = (counts * vref_v / 2**(bits-1) - offset_v) / gain_v_per_dps"
        return d
