"""``gyrolab simulate``: run a profile through :class:`~gyrolab.sim.physics.Physics` to MCAP.

A loop over :meth:`Physics.advance` in 1 s blocks (aligned to whole seconds since power-on),
split where the profile changes the setpoint. Per block it writes ``/gyro/adc`` (the codes)
and ``/gyro/rate`` (the codes converted back exactly as a bench converts them), and at 1 Hz
``/temperature/pt100`` (DMM reading and its IEC 60751 inverse) and ``/oven/state``. Memory
is one block plus the flicker generator's chunk, whatever the run's length.

Recordings are reproducible: the run start defaults to 2021-04-20T00:00:00Z and nothing
else in the file depends on the wall clock, so the same seed gives the same bytes.
"""

from __future__ import annotations

import datetime as dt
import os
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import IO, Any

import numpy as np

from gyrolab.profiles.profile import Profile
from gyrolab.progress import progress
from gyrolab.record.metadata import BenchMetadata, RunMetadata
from gyrolab.record.writer import RecordingWriter
from gyrolab.sim.bench.dmm_scpi import IDN as DMM_IDN
from gyrolab.sim.family import Unit
from gyrolab.sim.model import SimModel
from gyrolab.sim.physics import Physics
from gyrolab.sim.sensors import AdcModel, cvd_temperature

DEFAULT_START = "2021-04-20T00:00:00Z"

# What the simulated file says about its instruments (docs/recording-format.md, ``bench``):
# no driver ran, the simulator's model made the readings (``driver = "simulate"``); the
# thermometer answers with the simulated bench's 34401A identity.
SIM_DRIVER = "simulate"
SIM_UNIT_MODEL = "dual-mass tuning-fork MEMS gyroscope (simulated)"
SIM_UNIT_SERIAL = "SIM-GYRO-0001"


@dataclass
class SimSummary:
    """What a simulation wrote."""

    duration_s: float
    samples: int
    blocks: int
    steps: int


def _start_ns(start_time: str) -> int:
    ts = dt.datetime.fromisoformat(start_time.replace("Z", "+00:00"))
    if ts.tzinfo is None:
        ts = ts.replace(tzinfo=dt.timezone.utc)
    return int(round(ts.timestamp())) * 1_000_000_000 + ts.microsecond * 1000


def run_metadata(profile: Profile, seed: int, start_time: str) -> RunMetadata:
    """The ``run`` record of a simulated run (unpaced: ``speed`` "max")."""
    return RunMetadata(
        source="simulate",
        start_time=start_time,
        profile=profile.to_dict(),
        operator="gyrolab simulate",
        unit_serial=SIM_UNIT_SERIAL,
        unit_model=SIM_UNIT_MODEL,
        bench_name="sim",
        seed=int(seed),
        speed="max",
    )


def adc_metadata(adc: AdcModel, rate_hz: float) -> dict[str, Any]:
    """``bench.adc`` of a simulated ADC: the keys every ADC table has, and the conversion."""
    return {
        "driver": SIM_DRIVER,
        "sample_rate_hz": float(rate_hz),
        **adc.to_dict(),
        "dps_per_count": adc.vref_v / adc.full_scale / adc.gain_v_per_dps,
    }


def bench_metadata(model: SimModel, rate_hz: float) -> BenchMetadata:
    """The ``bench`` record of a simulated run: the simulated instruments; no bench limits,
    safe state or recorder table apply."""
    return BenchMetadata(
        name="sim",
        simulated=True,
        multimeter={
            "driver": SIM_DRIVER,
            "model": "34401A",
            "idn": DMM_IDN,
            "r0_ohm": 100.0,
            "wiring": "4-wire",
            "standard": "IEC 60751",
            "on": "case",
        },
        oven={"driver": SIM_DRIVER, "model": "Watlow F4 (simulated)"},
        adc=adc_metadata(model.sensors.adc, rate_hz),
    )


def provenance(model: SimModel, seed: int) -> dict[str, Any]:
    """The ``sim_provenance`` record: the generating model. Never read by discrepancy."""
    return {
        "seed": int(seed),
        "effects": [e.name for e in model.effects],
        "model_toml": model.to_toml(),
    }


def simulate_run(
    out: str | os.PathLike[str] | IO[bytes],
    profile: Profile,
    model: SimModel,
    *,
    rate_hz: float = 100.0,
    seed: int = 0,
    start_time: str = DEFAULT_START,
    show_progress: bool = True,
    axis_models: Sequence[SimModel] = (),
    units: list[Unit] | None = None,
) -> SimSummary:
    """Simulate ``profile`` with ``model`` and write the recording to ``out``.

    Steps with a stability rule are held past their minimum duration until the PT100 slope
    over ``stable_window_s`` is below ``stable_slope_c_per_min`` (checked once a second),
    or ``max_extra_s`` has passed.

    ``axis_models`` makes a 2- or 3-axis unit: ``model`` is axis x, the others y (and z),
    each with its own effects and parameters on the same case (:func:`axis_physics`).

    ``units`` (from :func:`gyrolab.sim.family.unit_family`): several single-axis units in
    the one chamber, written in the multi-unit layout (docs/recording-format.md), each with
    its own model and noise seed; ``model`` then gives only the shared chamber's metadata,
    the profile's stability rule watches the first unit's PT100 and the chamber air is that
    of the first unit's physics (the family shares the chamber's parameters, so every unit's
    physics has the same air).
    """
    if units is not None and axis_models:
        raise ValueError("multi-axis units in a multi-unit run are not supported yet")
    if units is None:
        serials: list[str | None] = [None]
        fleet = [Physics(model, rate_hz=rate_hz, seed=seed, ambient_c=profile.ambient_c)]
        extras = [axis_physics(model, axis_models, rate_hz, seed, profile.ambient_c)]
    else:
        serials = [u.serial for u in units]
        fleet = [
            Physics(u.model, rate_hz=rate_hz, seed=u.seed, ambient_c=profile.ambient_c)
            for u in units
        ]
        extras = [[] for _ in units]
    phys, extra = fleet[0], extras[0]  # the chamber and the stability rule: the first unit
    every = [p for ph, ex in zip(fleet, extras, strict=True) for p in (ph, *ex)]
    bn = phys.block_n
    rate = phys.rate_hz
    run_meta = run_metadata(profile, seed, start_time)
    bench_meta = bench_metadata(model, rate)
    if extra:
        run_meta.axes = 1 + len(extra)
        assert bench_meta.adc is not None
        bench_meta.adc["axes"] = 1 + len(extra)
    if units is not None:
        run_meta.unit_serial = ""  # the units' serials are the run's `units`
        bench_meta.units = {
            u.serial: {"adc": adc_metadata(u.model.sensors.adc, rate)} for u in units
        }
    w = RecordingWriter(
        out,
        start_time_ns=_start_ns(start_time),
        run=run_meta,
        bench=bench_meta,
        units=None if units is None else [u.serial for u in units],
    )
    n_blocks = 0
    try:
        if units is None:
            w.write_metadata("sim_provenance", provenance(model, seed))
        else:
            w.write_metadata(
                "sim_provenance",
                {
                    u.serial: {**provenance(u.model, u.seed), "family_seed": int(seed)}
                    for u in units
                },
            )
        if extra:
            w.write_metadata(
                "sim_provenance_axes",
                {"axes": 1 + len(extra), "models_toml": [m.to_toml() for m in axis_models]},
            )
        w.write_event(0.0, "run_started", -1, detail=f"profile {profile.name}")
        w.write_log(
            0.0,
            "info",
            "simulator",
            f"simulating profile {profile.name} at {rate:g} Hz, seed {seed}",
        )
        steps = profile.steps
        step = 0
        step_start = 0
        for p in every:
            p.set_setpoint(steps[0].setpoint_c)
        w.write_event(0.0, "step_started", 0, steps[0].setpoint_c, steps[0].label)
        pt_hist: deque[tuple[float, float]] = deque()
        bar = progress(total=round(profile.duration_s), desc="simulate", unit="s")
        done = False
        while not done:
            idx = phys.index
            t_now = phys.t
            for serial, ph in zip(serials, fleet, strict=True):
                r_ohm = ph.pt100_ohm()
                t_unit = float(cvd_temperature(r_ohm))
                w.write_pt100(t_now, r_ohm, t_unit, unit=serial)
                if ph is phys:
                    t_c = t_unit
            w.write_oven(t_now, phys.setpoint_c, phys.chamber_c(), "run")
            s = steps[step]
            if s.stable_slope_c_per_min is not None:
                pt_hist.append((t_now, t_c))
                while pt_hist and pt_hist[0][0] < t_now - s.stable_window_s:
                    pt_hist.popleft()
            # samples in this block, cut where the step's minimum duration ends
            end_block = (idx // bn + 1) * bn
            parts_counts: list[list[np.ndarray]] = [[] for _ in fleet]
            pos = idx
            while pos < end_block:
                # at least one sample per step, so every step is seen by the recording
                min_end = step_start + max(1, int(round(s.duration_s * rate)))
                cut = min(end_block, min_end) if pos < min_end else end_block
                for parts, ph, ex in zip(parts_counts, fleet, extras, strict=True):
                    blk = ph.advance(cut - pos)
                    if ex:
                        cols = [blk.counts] + [p.advance(cut - pos).counts for p in ex]
                        parts.append(np.column_stack(cols))
                    else:
                        parts.append(blk.counts)
                pos = cut
                ended = pos == min_end and s.stable_slope_c_per_min is None
                if s.stable_slope_c_per_min is not None and pos >= min_end and pos == end_block:
                    ended = _stable(pt_hist, s) or (pos - min_end) >= s.max_extra_s * rate
                    if ended and _stable(pt_hist, s):
                        w.write_event(pos / rate, "soaked", step, s.setpoint_c)
                if ended:
                    w.write_event(pos / rate, "step_ended", step, s.setpoint_c)
                    step += 1
                    step_start = pos
                    pt_hist.clear()
                    if step == len(steps):
                        done = True
                        break
                    s = steps[step]
                    for p in every:
                        p.set_setpoint(s.setpoint_c)
                    w.write_event(pos / rate, "step_started", step, s.setpoint_c, s.label)
            for serial, ph, parts in zip(serials, fleet, parts_counts, strict=True):
                counts = parts[0] if len(parts) == 1 else np.concatenate(parts)
                w.write_adc_block(idx / rate, ph.period, idx, counts, unit=serial)
                dps = ph.adc.counts_to_dps(counts)
                w.write_rate_block(idx / rate, ph.period, idx, dps, unit=serial)
            n_blocks += 1
            bar.update(1)
        bar.close()
        t_end = phys.t
        w.write_oven(t_end, phys.setpoint_c, phys.chamber_c(), "standby")
        w.write_event(t_end, "run_ended", -1, detail="profile complete")
        w.write_log(t_end, "info", "simulator", f"done: {phys.index} samples, {t_end:.0f} s")
    finally:
        w.close()
    return SimSummary(t_end, phys.index, n_blocks, len(steps))


def axis_physics(
    model: SimModel,
    axis_models: Sequence[SimModel],
    rate_hz: float,
    seed: int,
    ambient_c: float,
) -> list[Physics]:
    """The :class:`Physics` of axes y (and z) of a multi-axis unit.

    One case, one oven, one ADC: every axis shares ``model``'s thermal and sensor parameters and
    oven/PT100 effects (``oven_overshoot``, ``rtd_self_heating``), so all axes see the same
    case temperature; gyro effects (bias polynomial, noise, die lag, ...) are per axis.
    Axis k draws its noise from seed ``seed + 7919·k`` so axes are independent while axis x
    is exactly the single-axis unit of ``seed``."""
    if len(axis_models) > 2:
        raise ValueError("a unit has at most 3 axes")
    shared = ("oven_overshoot", "rtd_self_heating")
    out = []
    for k, m in enumerate(axis_models, start=1):
        if (
            m.thermal != model.thermal
            or m.sensors != model.sensors
            or any(m.get(n) != model.get(n) for n in shared)
        ):
            raise ValueError(
                f"axis {k}: thermal, sensor ([sensors]) parameters and {', '.join(shared)} "
                "must equal axis x's (one case, one oven, one ADC)"
            )
        out.append(Physics(m, rate_hz=rate_hz, seed=seed + 7919 * k, ambient_c=ambient_c))
    return out


def _stable(hist: deque[tuple[float, float]], s: Any) -> bool:
    """PT100 slope over the window below the step's threshold (°C/min)."""
    if len(hist) < 3 or hist[-1][0] - hist[0][0] < 0.99 * s.stable_window_s:
        return False
    a = np.asarray(hist)
    slope = np.polyfit(a[:, 0], a[:, 1], 1)[0] * 60.0
    return abs(slope) < s.stable_slope_c_per_min
