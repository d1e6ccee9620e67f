"""Bench arrays straight from the simulator's stepping API, for the battery and the tests.

:func:`simulate_bench` follows ``gyrolab simulate``'s recording loop (1 s blocks; the
PT100 and the oven read once a second at each block's start; the rate stream is the ADC
codes converted back) without encoding an MCAP file, and hands the arrays to
:func:`gyrolab.sim.discrepancy.data.from_arrays`, the same reduction the CLI applies to a
recording. Profiles with stability rules are not supported here (the battery uses fixed
step durations).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from gyrolab.profiles.profile import Profile
from gyrolab.sim.discrepancy.data import BenchData, from_arrays
from gyrolab.sim.model import SimModel
from gyrolab.sim.physics import Physics
from gyrolab.sim.sensors import cvd_temperature


def simulate_bench(
    model: SimModel,
    profile: Profile,
    rate_hz: float = 10.0,
    seed: int = 0,
    post: Callable[[np.ndarray, float], np.ndarray] | None = None,
    temperature: str = "pt100",
) -> BenchData:
    """Simulate ``profile`` with ``model`` and reduce it as a recording would be.

    ``post(rate, dt)``, when given, transforms the whole rate stream (°/s, taken before
    the bench ADC) before it is stored, e.g.
    :func:`gyrolab.sim.discrepancy.reallike.digital_output`. ``temperature="die"``: the
    unit's internal sensor (its register, offset and noise: ``Physics.die_sensor_codes``)
    is the temperature channel instead of a PT100, as ``acquire --internal-temperature``
    records it."""
    phys = Physics(model, rate_hz=rate_hz, seed=seed, ambient_c=profile.ambient_c)
    bn = phys.block_n
    starts = profile.step_starts()
    ends = starts + np.array([s.duration_s for s in profile.steps])
    n_sec = int(round(ends[-1]))
    rate = np.empty(n_sec * bn)
    pt_ohm = np.empty(n_sec)
    die = np.empty(n_sec)
    ov_sp = np.empty(n_sec)
    ov_pv = np.empty(n_sec)
    step = 0
    for k in range(n_sec):
        while step + 1 < len(profile.steps) and k >= starts[step + 1]:
            step += 1
        phys.set_setpoint(profile.steps[step].setpoint_c)
        pt_ohm[k] = phys.pt100_ohm()
        die[k] = phys.die_c()
        ov_sp[k] = phys.setpoint_c
        ov_pv[k] = phys.chamber_c()
        blk = phys.advance(bn)
        # a post-transform stands for a digital gyro's own output stage: it gets the rate
        # before the bench ADC (whose lattice would otherwise sit under its own)
        out = blk.rate_dps if post is not None else phys.adc.counts_to_dps(blk.counts)
        rate[k * bn : (k + 1) * bn] = out
    t = np.arange(n_sec, dtype=float)
    pt_c = np.asarray(cvd_temperature(pt_ohm), dtype=float)
    if temperature == "die":
        pt_c = phys.die_sensor.to_celsius(phys.die_sensor_codes(die))
    if post is not None:
        rate = post(rate, 1.0 / phys.rate_hz)
    # the recording stores the rate as float32
    rate32 = rate.astype(np.float32).astype(np.float64)
    d = from_arrays(0.0, 1.0 / phys.rate_hz, rate32, t, pt_c, t, ov_sp, ov_pv)
    d.temperature_source = temperature
    return d
