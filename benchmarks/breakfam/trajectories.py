"""Chamber trajectories of the break family: per-second setpoints and the temperature the
unit rests at before power-on (t = 0). Written here, not taken from gyrolab's profiles."""

from __future__ import annotations

import numpy as np

NAMES = ("staircase", "heating", "random", "fastramp", "coldstart", "slowramp")
#: calibration-only trajectories (never held out) and the trajectory of NAMES each
#: extends (that one is not held out either)
CALIBRATIONS = {
    "staircase_ramps": "staircase",
    "staircase_upramp": "staircase",
    "staircase_midcycle": "staircase",
    "staircase_centrecycle": "staircase",
    "staircase_ramps15": "staircase",
    "staircase_ramps3c": "staircase",
    "staircase_ramps_coldtail": "staircase",
}


def _steps(parts: list[tuple[float, float]]) -> np.ndarray:
    """Per-second setpoints from (setpoint °C, hold s) pairs."""
    return np.concatenate([np.full(int(d), float(s)) for s, d in parts])


def _ramp(a: float, b: float, c_per_min: float) -> np.ndarray:
    n = int(abs(b - a) / c_per_min * 60.0)
    return np.linspace(a, b, max(n, 1))


def trajectory(name: str, seed: int = 0) -> tuple[np.ndarray, float]:
    """``(setpoints at 1 Hz, rest temperature °C)`` of trajectory ``name``:

    * ``staircase`` — 1 h at 25 °C after power-on, 1 h at 60, then 10 °C steps down to
      −40 held 1 h each (13 h: the paper's cooling staircase, re-made);
    * ``heating`` — the same steps upward from −40 (13 h);
    * ``random`` — setpoints uniform in −40…60 held 20–90 min (10 h, per ``seed``);
    * ``fastramp`` — ±3 °C/min ramps between −40 and 60 (the chamber caps cooling at
      1.5 °C/min) with 30 min soaks (≈ 7 h);
    * ``coldstart`` — rests at −35 °C unpowered, powered on cold: 1 h at −35, 1 °C/min to
      50, 2 h, then steps 20, −10, 40 of 1 h (≈ 7 h);
    * ``slowramp`` — a 0.3 °C/min triangle 25 → 60 → −40 → 25 (≈ 12 h);
    * ``staircase_ramps`` (calibration only) — the staircase, then one fast-ramp cycle:
      −40 → 60 at 3 °C/min, 30 min, 60 → −40, 30 min (≈ 14 h): the rates a fast ramp
      needs, which the staircase's one heating step does not show;
    * ``staircase_upramp`` (calibration only) — the staircase, then its first half-cycle:
      −40 → 60 at 3 °C/min, 30 min (≈ 13 h);
    * ``staircase_midcycle`` (calibration only) — the same cycle and chamber time as
      ``staircase_ramps``, inside the staircase after its hour at 60 °C: 60 → −40 at
      3 °C/min, 30 min, −40 → 60, 30 min, then the steps 50 … −40 (≈ 14 h): the cold end
      and the fast heating then each lie in more than one of the blocked CV's segments;
    * ``staircase_centrecycle`` (calibration only) — the staircase with a cycle after its
      20 °C hour, past the warm-up and away from the cold end: 20 → 60 at 3 °C/min,
      30 min, 60 → −40, 30 min, −40 → 10, then the steps 10 … −40 (≈ 14 h);
    * ``staircase_ramps15`` (calibration only) — ``staircase_ramps`` at 1.5 °C/min, the
      rate the chamber can cool at (≈ 15 h);
    * ``staircase_ramps3c`` (calibration only) — the staircase, then −40 → 60 at 3 °C/min,
      30 min, 60 → −40 at 1.5 °C/min (what the chamber can cool at), 30 min (≈ 14.7 h):
      the fast heating, and the cold end in a second CV segment;
    * ``coldcal`` (calibration only, a second power-on appended to a calibration:
      ``break_suite.py --cold-power-on``) — rests at −20 °C unpowered, powered on cold:
      1 h at −20, 2 °C/min to 40, 1 h, 1.5 °C/min to −10, 30 min (≈ 3.6 h). Not the
      held-out ``coldstart`` (−35 °C, 1 °C/min);
    * ``staircase_ramps_coldtail`` (calibration only) — ``staircase_ramps``, then 2 °C/min
      to −20 and ``coldcal``'s program without its power cycle (≈ 17.8 h): the control
      of ``--cold-power-on`` — the same chamber program and hours, one power-on.
    """
    if name == "staircase":
        sp = [(25.0, 3600.0), (60.0, 3600.0)] + [(60.0 - 10.0 * i, 3600.0) for i in range(1, 11)]
        return _steps(sp), 25.0
    if name == "heating":
        sp = [(25.0, 3600.0), (-40.0, 3600.0)] + [(-40.0 + 10.0 * i, 3600.0) for i in range(1, 11)]
        return _steps(sp), 25.0
    if name == "random":
        rng = np.random.default_rng([41, seed])
        parts, total = [(25.0, 3600.0)], 3600.0
        while total < 10 * 3600.0:
            d = float(rng.uniform(20.0, 90.0)) * 60.0
            parts.append((float(np.round(rng.uniform(-40.0, 60.0), 1)), d))
            total += d
        return _steps(parts), 25.0
    if name == "fastramp":
        seg = [np.full(3600, 25.0), _ramp(25.0, 60.0, 3.0), np.full(1800, 60.0)]
        seg += [_ramp(60.0, -40.0, 3.0), np.full(1800, -40.0), _ramp(-40.0, 60.0, 3.0)]
        seg += [np.full(1800, 60.0), _ramp(60.0, -40.0, 3.0), np.full(1800, -40.0)]
        seg += [_ramp(-40.0, 25.0, 3.0), np.full(3600, 25.0)]
        return np.concatenate(seg), 25.0
    if name in ("staircase_ramps", "staircase_upramp"):
        sp, rest = trajectory("staircase")
        cyc = [_ramp(-40.0, 60.0, 3.0), np.full(1800, 60.0)]
        if name == "staircase_ramps":
            cyc += [_ramp(60.0, -40.0, 3.0), np.full(1800, -40.0)]
        return np.concatenate([sp, *cyc]), rest
    if name == "staircase_midcycle":
        head = _steps([(25.0, 3600.0), (60.0, 3600.0)])
        cyc = [_ramp(60.0, -40.0, 3.0), np.full(1800, -40.0), _ramp(-40.0, 60.0, 3.0)]
        cyc += [np.full(1800, 60.0)]
        tail = _steps([(60.0 - 10.0 * i, 3600.0) for i in range(1, 11)])
        return np.concatenate([head, *cyc, tail]), 25.0
    if name == "staircase_centrecycle":
        head = _steps([(25.0, 3600.0)] + [(60.0 - 10.0 * i, 3600.0) for i in range(0, 5)])
        cyc = [_ramp(20.0, 60.0, 3.0), np.full(1800, 60.0), _ramp(60.0, -40.0, 3.0)]
        cyc += [np.full(1800, -40.0), _ramp(-40.0, 10.0, 3.0)]
        tail = _steps([(10.0 - 10.0 * i, 3600.0) for i in range(0, 6)])
        return np.concatenate([head, *cyc, tail]), 25.0
    if name in ("staircase_ramps15", "staircase_ramps3c"):
        sp, rest = trajectory("staircase")
        up = 1.5 if name == "staircase_ramps15" else 3.0
        cyc = [_ramp(-40.0, 60.0, up), np.full(1800, 60.0), _ramp(60.0, -40.0, 1.5)]
        return np.concatenate([sp, *cyc, np.full(1800, -40.0)]), rest
    if name == "staircase_ramps_coldtail":
        sp, rest = trajectory("staircase_ramps")
        cold, _ = trajectory("coldcal")
        return np.concatenate([sp, _ramp(-40.0, -20.0, 2.0), cold]), rest
    if name == "coldcal":
        seg = [np.full(3600, -20.0), _ramp(-20.0, 40.0, 2.0), np.full(3600, 40.0)]
        seg += [_ramp(40.0, -10.0, 1.5), np.full(1800, -10.0)]
        return np.concatenate(seg), -20.0
    if name == "coldstart":
        seg = [np.full(3600, -35.0), _ramp(-35.0, 50.0, 1.0), np.full(7200, 50.0)]
        seg += [_steps([(20.0, 3600.0), (-10.0, 3600.0), (40.0, 3600.0)])]
        return np.concatenate(seg), -35.0
    if name == "slowramp":
        seg = [np.full(1800, 25.0), _ramp(25.0, 60.0, 0.3), _ramp(60.0, -40.0, 0.3)]
        seg += [_ramp(-40.0, 25.0, 0.3), np.full(1800, 25.0)]
        return np.concatenate(seg), 25.0
    raise ValueError(f"unknown trajectory {name!r}")
