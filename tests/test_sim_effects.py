"""Each effect's signature, measured on the output of :class:`gyrolab.sim.physics.Physics`."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gyrolab.sim.model import SimModel, make_effect_spec
from gyrolab.sim.physics import Physics


def model(*effects: tuple[str, dict[str, float]], **thermal: float) -> SimModel:
    m = SimModel(effects=tuple(make_effect_spec(n, p) for n, p in effects))
    return m.with_thermal(**thermal) if thermal else m


def run(
    m: SimModel,
    seconds: float,
    rate_hz: float,
    *,
    seed: int = 0,
    schedule: list[tuple[float, float]] | None = None,
) -> tuple[np.ndarray, None, Physics]:
    """Output (°/s, before the ADC) of ``seconds`` of simulation; schedule = [(t, SP)]."""
    p = Physics(m, rate_hz=rate_hz, seed=seed)
    n_total = int(round(seconds * rate_hz))
    changes = sorted((int(round(t * rate_hz)), sp) for t, sp in (schedule or []))
    out = []
    while p.index < n_total:
        while changes and changes[0][0] <= p.index:
            p.set_setpoint(changes.pop(0)[1])
        nxt = min([n_total] + [c for c, _ in changes if c > p.index])
        out.append(p.advance(min(nxt - p.index, 20_000)).rate_dps)  # big blocks: fast tests
    return np.concatenate(out), None, p


def oadev(x: np.ndarray, fs: float, ms: np.ndarray) -> np.ndarray:
    """Overlapping Allan deviation of rate samples ``x`` at τ = m / fs."""
    c = np.concatenate([[0.0], np.cumsum(x)])
    res = []
    for m in ms:
        a = (c[m:] - c[:-m]) / m
        d = a[m:] - a[:-m]
        res.append(math.sqrt(0.5 * float(np.mean(d * d))))
    return np.array(res)


def slope(taus: np.ndarray, ad: np.ndarray) -> float:
    return float(np.polyfit(np.log(taus), np.log(ad), 1)[0])


def test_arw_is_the_minus_half_line_at_n() -> None:
    n_arw, fs = 0.1, 100.0
    y, _, _ = run(model(("arw", {"N": n_arw})), 1800, fs)
    ms = np.array([1, 10, 100, 1000])
    ad = oadev(y, fs, ms)
    taus = ms / fs
    assert slope(taus, ad) == pytest.approx(-0.5, abs=0.05)
    n_est = ad * np.sqrt(taus) * 60.0  # (°/s)·√s → °/√h
    assert np.all(np.abs(n_est / n_arw - 1) < 0.10)


def test_bias_instability_is_a_flat_floor_at_b() -> None:
    b_dph, fs = 2.0, 10.0
    ms = np.array([50, 100, 300, 1000, 3000])
    ads = []
    for seed in range(4):
        y, _, _ = run(model(("bias_instability", {"B": b_dph})), 6 * 3600, fs, seed=seed)
        ads.append(oadev(y, fs, ms) * 3600.0)
    ad = np.sqrt(np.mean(np.square(ads), axis=0))  # average Allan variance over seeds
    assert np.all(np.abs(ad / b_dph - 1) < 0.20), ad
    assert abs(slope(ms / fs, ad)) < 0.1  # flat: neither white (−½) nor RRW (+½)


def test_rate_random_walk_is_the_plus_half_line() -> None:
    k, fs = 20.0, 1.0
    ms = np.array([10, 30, 100, 300])
    ads = []
    for seed in range(4):
        y, _, _ = run(model(("rate_random_walk", {"K": k})), 8 * 3600, fs, seed=seed)
        ads.append(oadev(y, fs, ms))
    ad = np.sqrt(np.mean(np.square(ads), axis=0))
    taus = ms / fs
    assert slope(taus, ad) == pytest.approx(0.5, abs=0.1)
    k_est = ad / np.sqrt(taus / 3.0) * 3600.0 * 60.0  # → °/h/√h
    assert np.median(k_est) == pytest.approx(k, rel=0.25)


def test_quantization_has_allan_slope_minus_one_and_steps_of_q() -> None:
    q, fs = 0.01, 100.0
    m = model(
        ("bias_poly", {"c0": 0.01234, "c1": 0, "c2": 0}),
        ("arw", {"N": 0.001}),
        ("quantization", {"q": q}),
    )
    y, _, _ = run(m, 600, fs)
    assert np.allclose(y / q, np.rint(y / q), atol=1e-9)  # every output a multiple of q
    assert y.mean() == pytest.approx(0.01234, abs=1e-4)  # angle is carried, nothing lost
    ms = np.array([1, 2, 4, 8, 16])
    ad = oadev(y, fs, ms)
    assert slope(ms / fs, ad) == pytest.approx(-1.0, abs=0.12)
    # The error the quantizer adds, with an input that spans many steps per sample
    # (ARW σ = q/2 per sample, so the carried angle error is uniform): σ(τ) = √3 Q / τ,
    # Q = q Δt / √12 (IEEE 952 angle quantization).
    dither = ("arw", {"N": 0.5 * q * 60 / math.sqrt(fs)})
    yq, _, _ = run(model(dither, ("quantization", {"q": q})), 600, fs, seed=1)
    y0, _, _ = run(model(dither), 600, fs, seed=1)
    ade = oadev(yq - y0, fs, ms)
    assert slope(ms / fs, ade) == pytest.approx(-1.0, abs=0.05)
    expect = math.sqrt(3) * (q / fs / math.sqrt(12)) / (ms / fs)
    assert np.all(np.abs(ade / expect - 1) < 0.10)


def test_thermal_rate_scales_with_dtdt() -> None:
    k = 3e-3  # °/s per °C/min
    sched = [(0.0, 25.0), (600.0, 45.0), (4200.0, 5.0)]
    y, _, p = run(model(("thermal_rate", {"k": k})), 8000, 10.0, schedule=sched)
    y2, _, _ = run(model(("thermal_rate", {"k": 2 * k})), 8000, 10.0, schedule=sched)
    np.testing.assert_allclose(y2, 2 * y, rtol=1e-12, atol=1e-15)
    # recover k from the case temperature the block returns
    pp = Physics(model(("thermal_rate", {"k": k})), rate_hz=10.0)
    case, out = [], []
    for t0, sp in [(0, 25.0), (600, 45.0), (4200, 5.0)]:
        pp.set_setpoint(sp)
        end = {0: 600, 600: 4200, 4200: 8000}[t0]
        for _ in range((end - t0) * 10):
            out.append(pp.advance(1).rate_dps[0])
            case.append(pp.case_c())
    case_arr = np.array([25.0] + case[:-1])
    dtdt = np.gradient(case_arr, 0.1) * 60.0  # °C/min
    sel = np.abs(dtdt) > 0.05
    fit = np.polyfit(dtdt[sel], np.array(out)[sel], 1)[0]
    assert fit == pytest.approx(k, rel=0.02)
    assert np.abs(y).max() > 0.2 * k  # the rate really moved


def test_warmup_decays_exponentially_from_a() -> None:
    a, tau = 0.01, 300.0
    y, _, _ = run(model(("warmup", {"A": a, "tau_s": tau})), 1500, 10.0)
    t = np.arange(y.size) / 10.0
    assert y[0] == pytest.approx(a)
    assert y[int(tau * 10)] == pytest.approx(a / math.e, rel=1e-6)
    fit = np.polyfit(t, np.log(y), 1)
    assert -1 / fit[0] == pytest.approx(tau, rel=1e-6)


def test_aging_ramp_is_linear_in_time() -> None:
    r = 2e-3  # °/s per hour
    y, _, _ = run(model(("aging_ramp", {"r": r})), 7200, 1.0)
    t_h = np.arange(y.size) / 3600.0
    fit = np.polyfit(t_h, y, 1)
    assert fit[0] == pytest.approx(r, rel=1e-9)
    assert abs(fit[1]) < 1e-12


def test_periodic_has_its_line_at_one_over_p() -> None:
    amp, period = 0.002, 600.0
    y, _, _ = run(model(("periodic", {"A": amp, "period_s": period})), 6000, 2.0)
    spec = np.abs(np.fft.rfft(y)) * 2 / y.size
    f = np.fft.rfftfreq(y.size, 0.5)
    k = int(np.argmax(spec))
    assert f[k] == pytest.approx(1 / period, rel=1e-6)
    assert spec[k] == pytest.approx(amp, rel=1e-3)


def test_hysteresis_separates_heating_and_cooling_branches() -> None:
    h = 0.004
    m = model(("hysteresis", {"h": h, "width_c": 1.0}))
    # heat 25 → 45 then cool back to 5: pass through 30..40 °C both ways
    p = Physics(m, rate_hz=1.0)
    temps, outs = [], []
    for sp, dur in ((45.0, 9000), (5.0, 12000)):
        p.set_setpoint(sp)
        for _ in range(dur // 10):
            temps.append(p.case_c())
            outs.append(p.advance(10).rate_dps[0])
    temps_a, outs_a = np.array(temps), np.array(outs)
    heating = np.arange(temps_a.size) < 900
    band = (temps_a > 30) & (temps_a < 40)
    assert np.allclose(outs_a[band & heating], +h / 2)
    assert np.allclose(outs_a[band & ~heating], -h / 2)


def test_thermal_lag_makes_the_bias_follow_a_lagged_die() -> None:
    c1, tau = 1e-3, 900.0
    poly = ("bias_poly", {"c0": 0.0, "c1": c1, "c2": 0.0})
    sched = [(0.0, 50.0)]
    y_case, _, _ = run(model(poly), 4000, 1.0, schedule=sched)
    y_die, _, p = run(model(poly, ("thermal_lag", {"tau_s": tau})), 4000, 1.0, schedule=sched)
    t_case = 25 + y_case / c1
    t_die = 25 + y_die / c1
    # the die is a first-order lag of the case with τ: integrate and compare
    ref = np.empty_like(t_case)
    ref[0] = t_case[0]
    for i in range(1, ref.size):
        ref[i] = ref[i - 1] + (t_case[i - 1] - ref[i - 1]) * (1 - math.exp(-1 / tau))
    np.testing.assert_allclose(t_die, ref, atol=1e-6)
    assert np.max(t_case - t_die) > 3.0  # a real lag, not a rounding
    assert p.die_c() < p.case_c()


def test_outliers_are_sparse_spikes_of_the_given_height() -> None:
    amp, per_h, fs = 0.05, 200.0, 100.0
    base = ("arw", {"N": 0.01})
    y0, _, _ = run(model(base), 3600, fs, seed=4)
    y1, _, _ = run(
        model(base, ("outliers", {"rate_per_h": per_h, "amplitude": amp})), 3600, fs, seed=4
    )
    d = y1 - y0  # per-effect streams: adding outliers leaves the ARW draws unchanged
    spikes = np.flatnonzero(d != 0)
    assert np.allclose(np.abs(d[spikes]), amp)
    assert abs(spikes.size - per_h) < 4 * math.sqrt(per_h)
    assert 0.3 < np.mean(d[spikes] > 0) < 0.7


def test_oven_overshoot_overshoots_then_settles() -> None:
    os_frac, period = 0.2, 900.0
    m = model(("oven_overshoot", {"overshoot": os_frac, "period_s": period}))
    p = Physics(m, rate_hz=1.0)  # a 1 °C step at t = 100 s: the rate limits do not bind
    air = []
    for i in range(6000):
        if i == 100:
            p.set_setpoint(26.0)
        p.advance(1)
        air.append(p.chamber_c())
    air_a = np.array(air)
    assert air_a.max() - 26.0 == pytest.approx(os_frac * 1.0, rel=0.1)
    t_peak = int(np.argmax(air_a)) - 100
    assert t_peak == pytest.approx(period / 2, rel=0.1)
    assert air_a[-1] == pytest.approx(26.0, abs=0.01)
    # the nominal first-order oven never goes beyond the setpoint
    p0 = Physics(model(), rate_hz=1.0)
    p0.set_setpoint(26.0)
    air0 = [p0.advance(1).air_c for _ in range(3000)]
    assert max(air0) <= 26.0 + 1e-9
    assert air0[-1] == pytest.approx(26.0, abs=1e-3)


def test_rtd_self_heating_reads_high_by_the_offset() -> None:
    """I²·R(T)·θ: the reading is high by ``offset_c·R(T)/R0`` (0.4 °C at 0 °C)."""
    from gyrolab.pt100 import R0_OHM
    from gyrolab.sim.sensors import cvd_resistance, cvd_temperature

    off = 0.4
    p = Physics(model(("rtd_self_heating", {"offset_c": off})), rate_hz=1.0, seed=2)
    q = Physics(model(), rate_hz=1.0, seed=2)
    p.set_setpoint(-20.0)
    q.set_setpoint(-20.0)
    diffs, expected = [], []
    for _ in range(50):
        p.advance(60)
        q.advance(60)
        diffs.append(cvd_temperature(p.pt100_ohm()) - p.case_c())
        expected.append(off * float(cvd_resistance(p.case_c())) / R0_OHM)
        assert cvd_temperature(q.pt100_true_ohm()) == pytest.approx(q.case_c(), abs=1e-9)
    assert np.mean(diffs) == pytest.approx(np.mean(expected), abs=0.01)
    assert abs(np.mean(diffs) - off) > 0.02  # away from 0 °C it is not the constant
