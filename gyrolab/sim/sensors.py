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

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from gyrolab.pt100 import R0_OHM, A, B, C, cvd_resistance, cvd_temperature

# One CVD implementation for the driver and the simulator (package level, see pt100.py).
CVD_A, CVD_B, CVD_C, PT100_R0 = A, B, C, R0_OHM
__all__ = ["AdcModel", "DieThermometer", "cvd_resistance", "cvd_temperature"]


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


@dataclass(frozen=True)
class DieThermometer:
    """The gyro's internal (die) temperature sensor as its register reports it::

        code = clip(round((T_die + δ_unit + σ·w − zero_c) / c_per_lsb), −2^(bits−1), 2^(bits−1) − 1)

    ``c_per_lsb`` and ``zero_c`` (°C per LSB, °C at code 0) and ``bits`` are the part's
    register format — default the ADIS16135's TEMP_OUT: 16-bit two's complement, 0.0058 °C
    per LSB typical, 0 °C = 0x0000 (ADIS16135 data sheet, Tables 12–13; docs/instruments.md).
    ``offset_sd_c`` (°C, 1σ) is the spread of the unit's own offset δ_unit from the die
    (drawn once per unit), ``noise_c`` (°C rms) the white noise w of each reading: simulator
    parameters (docs/sim-model.md), not the data sheet's.
    """

    c_per_lsb: float = 0.0058
    zero_c: float = 0.0
    bits: int = 16
    offset_sd_c: float = 0.5
    noise_c: float = 0.02

    def codes(self, die_c: np.ndarray, offset_c: float, w: np.ndarray) -> np.ndarray:
        """Register codes (int16 for 16 bits) of die temperatures ``die_c`` (°C), with the
        unit's offset ``offset_c`` and standard-normal draws ``w``."""
        fs = 1 << (int(self.bits) - 1)
        t = np.asarray(die_c, dtype=float) + offset_c + self.noise_c * np.asarray(w, dtype=float)
        c = np.rint((t - self.zero_c) / self.c_per_lsb)
        return np.clip(c, -fs, fs - 1).astype(np.int32)

    def to_celsius(self, codes: np.ndarray) -> np.ndarray:
        """°C of register codes, as the bench software converts them."""
        return self.zero_c + np.asarray(codes, dtype=float) * self.c_per_lsb
