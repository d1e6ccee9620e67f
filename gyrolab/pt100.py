"""PT100 platinum resistance thermometer, IEC 60751 Callendar–Van Dusen (CVD) equation.

Pure functions shared by the multimeter driver (resistance → temperature) and the
simulator (temperature → resistance). They live at package level so that neither
``acquisition`` nor ``sim`` has to import the other.

    R(t) = R0 · (1 + A·t + B·t²)                      for t ≥ 0 °C
    R(t) = R0 · (1 + A·t + B·t² + C·(t − 100)·t³)     for t < 0 °C

with A = 3.9083e-3 /°C, B = −5.775e-7 /°C², C = −4.183e-12 /°C⁴ (IEC 60751:2008),
valid from −200 °C to 850 °C. The inverse is exact (quadratic) above 0 °C and a few
Newton steps below (the C term is small), accurate to well under 1 µ°C.
"""

from __future__ import annotations

import math

import numpy as np

R0_OHM = 100.0
A = 3.9083e-3
B = -5.775e-7
C = -4.183e-12

_NEWTON_STEPS = 8  # converges in 2-3; the rest costs nothing and covers -200 °C


def cvd_resistance(t_c: float | np.ndarray, r0_ohm: float = R0_OHM) -> float | np.ndarray:
    """Resistance (Ω) of a platinum RTD at ``t_c`` (°C); ``r0_ohm`` is R at 0 °C."""
    if isinstance(t_c, (float, int)):  # scalar fast path: the simulator reads once a second
        x = float(t_c)
        r = 1.0 + A * x + B * x * x
        return r0_ohm * (r + C * (x - 100.0) * x**3 if x < 0.0 else r)
    t = np.asarray(t_c, dtype=float)
    r = 1.0 + A * t + B * t * t
    r = np.where(t < 0.0, r + C * (t - 100.0) * t**3, r)
    out = r0_ohm * r
    return float(out) if out.ndim == 0 else out


def _temperature_scalar(r: float) -> float:
    """Inverse CVD of a resistance ratio ``r = R/R0`` (scalar)."""
    if not r > 0.0:
        return math.nan
    t = (-A + math.sqrt(max(A * A - 4.0 * B * (1.0 - r), 0.0))) / (2.0 * B)
    if r < 1.0:
        for _ in range(_NEWTON_STEPS):
            f = 1.0 + A * t + B * t * t + C * (t - 100.0) * t**3 - r
            df = A + 2.0 * B * t + C * (4.0 * t**3 - 300.0 * t * t)
            t -= f / df
    return t


def cvd_temperature(r_ohm: float | np.ndarray, r0_ohm: float = R0_OHM) -> float | np.ndarray:
    """Temperature (°C) of a platinum RTD reading ``r_ohm`` (Ω): the inverse of
    :func:`cvd_resistance`. Resistances at or below zero give NaN.

    Closed form ``T = (−A + √(A² − 4B(1 − R/R0))) / 2B`` for R ≥ R0; below, Newton's method
    on the full equation starting from that root.
    """
    if isinstance(r_ohm, (float, int)):
        return _temperature_scalar(float(r_ohm) / r0_ohm)
    r = np.asarray(r_ohm, dtype=float) / r0_ohm
    with np.errstate(invalid="ignore"):
        # Quadratic branch: exact for t >= 0, the starting point below 0 °C.
        t = (-A + np.sqrt(A * A - 4.0 * B * (1.0 - r))) / (2.0 * B)
        neg = r < 1.0
        if np.any(neg):
            tn = t[neg] if t.ndim else t
            rn = r[neg] if r.ndim else r
            for _ in range(_NEWTON_STEPS):
                f = 1.0 + A * tn + B * tn * tn + C * (tn - 100.0) * tn**3 - rn
                df = A + 2.0 * B * tn + C * (4.0 * tn**3 - 300.0 * tn * tn)
                tn = tn - f / df
            if t.ndim:
                t = t.copy()
                t[neg] = tn
            else:
                t = tn
        t = np.where(r > 0.0, t, np.nan)
    return float(t) if t.ndim == 0 else t


# 4-wire resistance test current of the multimeters the project drives, by range (Ω → A):
# the full-scale voltage the ohms current source develops across the resistor on each range
# (the "Ohms Range / Voltage Across R" table of the service guides' Theory of Operation:
# 34401A Service Guide ch. 5, "DC Amplifier"; 34970A/34972A Service Guide ch. 5, "Internal
# DMM"), over the range: 100 mV on 100 Ω, 1 V on 1 kΩ…100 kΩ, 5 V on 1 MΩ
# (docs/instruments.md, "PT100 excitation current").
_OHMS_FULL_SCALE_V = {100.0: 0.1, 1e3: 1.0, 1e4: 1.0, 1e5: 1.0, 1e6: 5.0}
FRES_FAMILIES = ("34401A", "34970A", "34972A")
"""Meters whose ohms current source is documented by that table. The 34465A, the DAQ970A
and others are not (no cited source): their bench record must carry
``excitation_current_a`` for a fitted self-heating to be stated as θ."""


def fres_test_current_a(model: str, range_ohm: float | None) -> float | None:
    """The test current (A) a 4-wire resistance reading drives through the PT100 on
    ``range_ohm`` (None: the drivers' 1 kΩ range), for a meter of ``FRES_FAMILIES``; None
    when the meter or the range is not known. The self-heating it causes is
    ``θ·I²·R(T)`` (``rtd_self_heating``, docs/sim-model.md)."""
    if not any(f in str(model) for f in FRES_FAMILIES):
        return None
    r = 1e3 if range_ohm is None else float(range_ohm)
    v = _OHMS_FULL_SCALE_V.get(r)
    return None if v is None else v / r
