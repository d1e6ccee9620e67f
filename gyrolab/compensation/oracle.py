"""The oracle: a simulated run minus its true deterministic drift.

No temperature model can do better than remove the drift exactly; what is left — white
noise, 1/f bias instability, the ADC's steps — is the floor every compensation is
measured against (issue 11). The truth is known only for a recording written by
``gyrolab simulate``: its ``sim_provenance`` record holds the generating model and seed,
its ``bench.adc`` the sample rate, and its ``/profile/event`` messages the exact time (to the
sample) each setpoint step started. Replaying those setpoints through
:class:`~gyrolab.sim.physics.Physics` with the model's *deterministic* effects only
(every effect but those that are part of the noise floor, ``Effect.is_noise()``: the
stochastic ones and the output's quantization) gives the same thermal history and the
drift without noise:

    oracle(t) = raw(t) − drift_det(t)

For any other recording (acquired on a bench, real or simulated: the setpoint reached the
physics over a wire at times the recording does not hold exactly) there is no oracle and
:func:`oracle_rate` returns ``None``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from gyrolab.compensation.evaluate import drift_pp_table, series_metrics
from gyrolab.errors import InputError
from gyrolab.numerics.averaging import block_average
from gyrolab.record.format import TOPIC_EVENT, TOPIC_RATE
from gyrolab.record.metadata import BenchMetadata
from gyrolab.record.reader import read_recording


def deterministic_drift(
    model_toml: str, rate_hz: float, n: int, steps: list[tuple[float, float]], ambient_c: float
) -> np.ndarray:
    """The deterministic part of a simulated gyro's output (°/s) at samples ``0..n−1``:
    ``steps`` = (start time s, setpoint °C) in time order."""
    import tomllib

    from gyrolab.sim.effects import EFFECTS
    from gyrolab.sim.model import SimModel
    from gyrolab.sim.physics import Physics

    model = SimModel.from_dict(tomllib.loads(model_toml))
    for name in model.effect_names():
        if EFFECTS[name].is_noise():
            model = model.without_effect(name)
    phys = Physics(model, rate_hz=rate_hz, seed=0, ambient_c=ambient_c)
    out = np.empty(n)
    pos = 0
    bounds = [int(round(t * rate_hz)) for t, _ in steps[1:]] + [n]
    for (_, sp), end in zip(steps, bounds, strict=True):
        end = min(max(end, pos), n)
        phys.set_setpoint(sp)
        if end > pos:
            out[pos:end] = phys.advance(end - pos).rate_dps
            pos = end
    if pos < n:
        out[pos:] = phys.advance(n - pos).rate_dps
    return out


def oracle_rate(rec: Any) -> np.ndarray | None:
    """``raw − true deterministic drift`` at the recording's full rate (°/s), or ``None``
    when the recording is not a ``gyrolab simulate`` output (module docstring)."""
    prov = rec.metadata.get("sim_provenance")
    if getattr(rec, "unit", None) and isinstance(prov, dict):  # a multi-unit run: per serial
        prov = prov.get(rec.unit)
    run = rec.run or {}
    if not isinstance(prov, dict) or run.get("source") != "simulate" or rec.rate is None:
        return None
    steps = [
        (float(e["t"]), float(e["setpoint_c"]))
        for e in rec.events
        if e.get("event") == "step_started" and "setpoint_c" in e
    ]
    rate_hz = BenchMetadata.from_dict(rec.bench or {}).sample_rate_hz(getattr(rec, "unit", None))
    if not steps or "model_toml" not in prov or rate_hz is None:
        return None
    profile = run.get("profile")
    ambient = float(profile.get("ambient_c", 25.0) if isinstance(profile, dict) else 25.0)
    raw = np.asarray(rec.rate.values, dtype=float)
    idx = np.rint(np.asarray(rec.rate.t) * rate_hz).astype(np.int64)
    if idx.size == 0 or idx[0] < 0:
        return None
    drift = deterministic_drift(str(prov["model_toml"]), rate_hz, int(idx[-1]) + 1, steps, ambient)
    return raw - drift[idx]


def oracle_block_means(rec: Any, block_s: float) -> np.ndarray | None:
    """:func:`oracle_rate` averaged to the compensation's ``block_s`` grid (or ``None``)."""
    o = oracle_rate(rec)
    if o is None:
        return None
    assert rec.rate is not None
    return block_average(rec.rate.t, o, block_s, rec.rate.period)[1]


def add_oracle(
    metrics: dict[str, Any], path: str, block_s: float, unit: str | None = None
) -> np.ndarray | None:
    """Add ``oracle`` (the five metrics) and its 100 s p-p to ``metrics`` when ``path`` is
    a ``gyrolab simulate`` recording; return the oracle's block means (``None``: none)."""
    try:
        rec = read_recording(path, topics=[TOPIC_RATE, TOPIC_EVENT], unit=unit)
    except InputError:  # a user's log (ROS bag, DataFlash, …): no simulation truth
        return None
    ob = oracle_block_means(rec, block_s)
    if ob is None:
        return None
    n = int(metrics.get("n_points", ob.size))
    ob = ob[:n]
    metrics["oracle"] = series_metrics(ob, block_s)
    metrics.setdefault("drift_pp_100s_deg_per_s", {}).update(
        drift_pp_table({"oracle": ob}, block_s)
    )
    return ob
