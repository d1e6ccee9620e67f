"""Thermal model (rate limits, lags) and the stepping API's block-independence."""

from __future__ import annotations

import numpy as np
import pytest

from gyrolab.sim.model import SimModel, make_effect_spec, nominal_model
from gyrolab.sim.physics import Physics
from gyrolab.sim.thermal import ThermalParams


def air_trace(p: Physics, seconds: int) -> np.ndarray:
    return np.array([p.advance(int(p.rate_hz)).air_c for _ in range(seconds)])


def test_air_heats_at_most_at_the_heating_limit() -> None:
    tp = ThermalParams()
    p = Physics(SimModel(), rate_hz=1.0)
    p.set_setpoint(60.0)
    air = air_trace(p, 3600)
    rate = np.diff(air)  # °C per s
    assert rate.max() == pytest.approx(tp.heat_rate_c_per_s, rel=1e-9)
    assert air[-1] == pytest.approx(60.0, abs=0.01)


def test_cooling_slows_at_low_temperature() -> None:
    tp = ThermalParams()
    p = Physics(SimModel(), rate_hz=1.0, ambient_c=60.0)
    p.set_setpoint(-60.0)  # beyond the chamber's reach: it cools at its limit all the way
    air = air_trace(p, 20000)
    rate = -np.diff(air)
    at = lambda temp: rate[np.argmin(np.abs(air[:-1] - temp))]  # noqa: E731
    assert at(50.0) == pytest.approx(tp.cool_rate_c_per_s, rel=1e-6)
    assert at(0.0) < 0.6 * at(30.0)
    assert at(-30.0) < 0.5 * at(0.0)
    assert air.min() > tp.cool_floor_c  # never reaches the floor


def test_case_lags_air_first_order_and_die_lags_case() -> None:
    tp = ThermalParams()
    p = Physics(SimModel(), rate_hz=1.0)
    p.set_setpoint(35.0)
    rows = []
    for _ in range(3 * 3600):
        b = p.advance(1)
        rows.append((b.air_c, b.case_c, b.die_c))
    a = np.array(rows)
    assert np.all(a[600:, 1] < a[600:, 0] + tp.self_heating_c)  # case behind air (+ P·R)
    assert np.all(a[60:, 2] < a[60:, 1])  # die behind case while heating
    # long after, case = air + P·R_case
    p.advance(20 * 3600)
    assert p.case_c() == pytest.approx(35.0 + tp.self_heating_c, abs=0.01)


@pytest.mark.parametrize("rate_hz", [10.0, 100.0])
def test_bench_path_equals_scheduled_path(rate_hz: float) -> None:
    """Random advance sizes with setpoints written 'by a bench' give the same physics."""
    m = (
        nominal_model()
        .with_effect("rate_random_walk")
        .with_effect("outliers")
        .with_effect("hysteresis")
        .with_effect("quantization", q=1e-4)
        .with_effect("oven_overshoot")
    )
    changes = {0: 25.0, int(300 * rate_hz): 40.0, int(900 * rate_hz): 10.0}
    total = int(1500 * rate_hz)

    sched = Physics(m, rate_hz=rate_hz, seed=7)
    out_a = []
    while sched.index < total:
        if sched.index in changes:
            sched.set_setpoint(changes[sched.index])
        nxt = min([total] + [c for c in changes if c > sched.index])
        out_a.append(sched.advance(min(sched.block_n, nxt - sched.index)))

    bench = Physics(m, rate_hz=rate_hz, seed=7)
    rng = np.random.default_rng(1)
    out_b = []
    while bench.index < total:
        if bench.index in changes:
            bench.set_setpoint(changes[bench.index])
        nxt = min([total] + [c for c in changes if c > bench.index])
        n = int(min(rng.integers(1, 3 * bench.block_n), nxt - bench.index))
        out_b.append(bench.advance(n))
    ra = np.concatenate([b.rate_dps for b in out_a])
    rb = np.concatenate([b.rate_dps for b in out_b])
    np.testing.assert_array_equal(ra, rb)
    np.testing.assert_array_equal(
        np.concatenate([b.counts for b in out_a]), np.concatenate([b.counts for b in out_b])
    )
    assert (sched.chamber_c(), sched.case_c(), sched.die_c()) == (
        bench.chamber_c(),
        bench.case_c(),
        bench.die_c(),
    )
    assert sched.t == pytest.approx(1500.0)


def test_adding_an_effect_leaves_other_draws_unchanged() -> None:
    base = SimModel(effects=(make_effect_spec("arw"), make_effect_spec("bias_instability")))
    more = base.with_effect("rate_random_walk", K=0.0)  # adds a stream, contributes 0
    a = Physics(base, rate_hz=50.0, seed=3).advance(5000).rate_dps
    b = Physics(more, rate_hz=50.0, seed=3).advance(5000).rate_dps
    np.testing.assert_array_equal(a, b)
    c = Physics(base, rate_hz=50.0, seed=4).advance(5000).rate_dps
    assert not np.array_equal(a, c)


def test_block_counts_are_the_adc_of_the_rate() -> None:
    p = Physics(nominal_model(), rate_hz=100.0, seed=1)
    b = p.advance(250)
    assert b.counts.dtype == np.int32 and b.n == 250
    np.testing.assert_array_equal(b.counts, p.adc.dps_to_counts(b.rate_dps))
    assert np.max(np.abs(p.adc.counts_to_dps(b.counts) - b.rate_dps)) <= p.adc.lsb_dps
    assert (b.t0, b.first_index, p.index) == (0.0, 0, 250)
    assert p.advance(10).t0 == pytest.approx(2.5)


def test_flicker_stream_is_independent_of_request_sizes() -> None:
    from gyrolab.sim.noise import FlickerStream, effect_rng

    def make() -> FlickerStream:
        return FlickerStream(1.0, effect_rng(0, "bias_instability"), nfft=1 << 10, chunk=1 << 7)

    whole = make().value_at(0, 50_000, 100.0)  # spans many chunks in one request
    fl = make()
    rng = np.random.default_rng(0)
    parts, i = [], 0
    while i < 50_000:
        n = int(min(rng.integers(1, 3000), 50_000 - i))
        parts.append(fl.value_at(i, n, 100.0))
        i += n
    np.testing.assert_array_equal(whole, np.concatenate(parts))
    assert len(fl._chunks) <= 3  # chunks behind are dropped: bounded memory
