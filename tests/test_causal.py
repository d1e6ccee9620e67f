"""Causal drift models: the firmware state machine equals the offline evaluation; the
family selection; rotation survives the causal output; the headline metric keys."""

from __future__ import annotations

import numpy as np
import pytest

from gyrolab.compensation.causal_features import (
    CausalParams,
    features,
    initial_state,
    reading_features,
    step,
)


@pytest.mark.parametrize(
    "tau,s0,shift,kappa,die",
    [
        (0.0, 0.0, 0.0, 0.0, 0.0),
        (12.0, 1.0, 0.0, 0.0, 0.0),
        (600.0, -0.5, 0.0, 0.0, 0.0),
        (300.0, 0.0, 0.8, 0.0, 0.0),
        (300.0, 0.0, 0.8, 0.01, 0.0),
        (60.0, 1.0, 0.0, -0.2, 0.0),  # the width at its floor below 20.5 °C
        (450.0, 0.0, 0.5, 0.0, 3.0),  # the die's own self-heating
        (0.0, 1.0, 0.0, 0.0, 2.0),  # ... with no lag: a constant rise
    ],
)
def test_step_equals_vectorised_features_bit_for_bit(
    tau: float, s0: float, shift: float, kappa: float, die: float
) -> None:
    rng = np.random.default_rng(3)
    n = 3000
    T = 25.0 + np.cumsum(rng.normal(0.0, 0.05, n))
    dt = rng.uniform(0.5, 1.5, n)
    dt[0] = 0.0
    p = CausalParams(
        tau_s=tau,
        width_c=0.7,
        warmup_tau_s=500.0,
        start_branch=s0,
        self_heating_c=shift,
        width_temp_per_c=kappa,
        die_heating_c=die,
    )
    X = features(T, dt, p)
    assert X[0, 2] == pytest.approx(s0)  # the play starts on its power-on branch
    s = initial_state(T[0], 0.0, p)
    Y = np.array([step(s, float(T[i]), float(dt[i]), p) for i in range(n)])
    assert np.array_equal(X, Y)
    # the state carried across two calls equals one call over the whole run
    s2 = initial_state(T[0], 0.0, p)
    Z = np.vstack([features(T[:1234], dt[:1234], p, s2), features(T[1234:], dt[1234:], p, s2)])
    assert np.array_equal(X, Z)


def test_features_restart_at_each_power_on() -> None:
    # a calibration of two runs on one time axis: with the second run's power-on given,
    # the features of each stretch are those of that run alone, bit for bit (the state
    # at rest again, the time since power-on from that power-on), the plays of
    # structured_pi's features too
    from gyrolab.compensation.pi_models import pi_features

    rng = np.random.default_rng(5)
    ta, tb = np.arange(0.0, 4000.0), np.arange(0.0, 3000.0)
    Ta = 25.0 + np.cumsum(rng.normal(0.0, 0.05, ta.size))
    Tb = -20.0 + np.cumsum(rng.normal(0.0, 0.05, tb.size))
    p = CausalParams(tau_s=300.0, width_c=1.0, warmup_tau_s=600.0, die_heating_c=2.0)
    on = 4000.0 + 1e6
    t, T = np.r_[ta, tb + on], np.r_[Ta, Tb]
    X = reading_features(t, T, p, power_ons=(on,))
    assert np.array_equal(X, np.vstack([reading_features(ta, Ta, p), reading_features(tb, Tb, p)]))
    assert not np.array_equal(X, reading_features(t, T, p))  # one power-on: not the same
    w = (0.5, 2.0)
    Y = pi_features(t, T, p, w, 0.3, (on,))
    alone = [pi_features(ta, Ta, p, w, 0.3), pi_features(tb, Tb, p, w, 0.3)]
    assert np.array_equal(Y, np.vstack(alone))
    assert np.array_equal(pi_features(ta, Ta, p, w, 0.3, ()), pi_features(ta, Ta, p, w, 0.3))


def test_features_follow_their_equations() -> None:
    # a slow ramp: the lagged temperature trails by rate·τ, R is the rate, S the branch
    t = np.arange(0.0, 20000.0)
    T = np.where(t < 10000, 0.001 * t, 10.0 - 0.001 * (t - 10000))
    X = reading_features(t, T, CausalParams(tau_s=300.0, width_c=1.0, warmup_tau_s=600.0))
    i = 9000
    assert X[i, 0] == pytest.approx(T[i] - 0.001 * 300.0, abs=1e-3)
    assert X[i, 1] == pytest.approx(0.001, rel=3e-3)  # discrete step: Δt/2τ
    assert X[i, 2] == 1.0 and X[-1000, 2] == -1.0
    assert X[600, 3] == pytest.approx(np.exp(-1.0))


def test_the_play_follows_the_die_self_heating() -> None:
    # the case held still: with δ the die warms by δ (1 − E) after power-on and drags
    # the play up once δ (1 − E) exceeds its half-width; without δ nothing moves
    t = np.arange(0.0, 6000.0)
    T = np.full(t.size, 20.0)
    p = CausalParams(tau_s=300.0, width_c=1.0, warmup_tau_s=600.0, self_heating_c=0.8)
    X = reading_features(t, T, p)
    H = 0.8 * (1.0 - X[:, 3])
    np.testing.assert_allclose(X[:, 2], np.minimum(H / 0.5, 1.0), atol=1e-12)
    assert X[-1, 2] == 1.0
    assert np.all(reading_features(t, T, CausalParams(tau_s=300.0))[:, 2] == 0.0)
    assert p.to_dict()["self_heating_c"] == 0.8
    assert "self_heating_c" not in CausalParams(tau_s=300.0).to_dict()  # files as before


def test_the_die_carries_its_own_self_heating() -> None:
    # δ_d is the step response of τ dD/dt = T + δ_d − D from D = T at power-on: the
    # temperature column rises by δ_d (1 − exp(−t/τ)) with the case held still, the
    # play follows it, the rate R (of the case's lag) does not; absent from files at 0
    t = np.arange(0.0, 6000.0)
    T = np.full(t.size, -35.0)
    p = CausalParams(tau_s=500.0, width_c=1.0, warmup_tau_s=600.0, die_heating_c=3.0)
    X = reading_features(t, T, p)
    np.testing.assert_allclose(X[:, 0], -35.0 + 3.0 * (1.0 - np.exp(-t / 500.0)), atol=1e-12)
    assert X[-1, 2] == 1.0 and np.all(X[:, 1] == 0.0)
    # the same die by a first-order lag of the case plus δ_d, stepped exactly
    D = np.empty(t.size)
    D[0] = -35.0
    for i in range(1, t.size):
        D[i] = D[i - 1] + (1.0 - np.exp(-1.0 / 500.0)) * (T[i] + 3.0 - D[i - 1])
    np.testing.assert_allclose(X[:, 0], D, atol=1e-9)
    assert p.to_dict()["die_heating_c"] == 3.0
    assert "die_heating_c" not in CausalParams(tau_s=300.0).to_dict()
    assert CausalParams.from_dict(p.to_dict()) == p


def test_the_play_width_follows_temperature() -> None:
    # a triangle 0 → 50 → 0 °C at 1 °C/min: with κ the play's half-width is
    # h = w/2 (1 + κ (F − 25)), so after the turn at 50 °C the branch S falls from +1
    # to −1 over 2.9 °C (the fixed w = 2 °C play: 2 °C); κ = 0 is the fixed play, and
    # absent from files
    t = np.arange(0.0, 6000.0)
    T = np.where(t < 3000, t / 60.0, 100.0 - t / 60.0)
    w, k = 2.0, 0.02
    p = CausalParams(width_c=w, width_temp_per_c=k)
    S = reading_features(t, T, p)[:, 2]
    h = 0.5 * w * (1.0 + k * (T - 25.0))  # 1.5 °C at 50 °C, 0.5 °C at 0 °C
    assert S[3000] == pytest.approx(1.0)  # the top, 50 °C
    # cooling from the top: the play stays at p = F_top − h(F_top) = 48.5 °C until
    # F + h(F) falls to it (47.1 °C: h shrinks as it cools), then S = −1
    top = T[3000] - h[3000]
    j = np.flatnonzero(S[3001:] <= -1.0 + 1e-12)[0] + 3001
    assert T[j] + h[j] == pytest.approx(top, abs=1.1 / 60.0)  # one reading's step
    assert S[3001] < 1.0 - 1e-3  # it leaves +1 at once: the width shrinks with F
    assert np.all(np.diff(S[3000:j]) < 0)
    assert p.to_dict()["width_temp_per_c"] == k
    assert "width_temp_per_c" not in CausalParams(width_c=w).to_dict()
    with pytest.raises(ValueError):
        CausalParams(width_temp_per_c=float("nan"))


# ------------------------------------------------------------------ family selection


def _staircase_run(tau_die: float, hyst: float, seed: int, hours: float = 6.0):
    """A synthetic calibration run: case temperature answering hourly setpoint steps
    (first order, 1200 s), the bias a quadratic in a die temperature lagging the case by
    ``tau_die`` plus a heating/cooling offset ±``hyst``/2, white noise; 3.6 s block means
    and 1 Hz PT100 readings."""
    from scipy.signal import lfilter

    from gyrolab.compensation.causal import CausalCalibration

    rng = np.random.default_rng(seed)
    t = np.arange(0.0, hours * 3600.0)  # 1 Hz
    sp = np.array([25, 60, 50, 30, 10, -10, 20, 45])[np.minimum(t // 2700, 7).astype(int)]
    a = 1.0 - np.exp(-1.0 / 1200.0)
    case = lfilter([a], [1.0, a - 1.0], sp - 25.0, zi=[0.0])[0] + 25.0
    die = case
    if tau_die > 0:
        b = 1.0 - np.exp(-1.0 / tau_die)
        die = lfilter([b], [1.0, b - 1.0], case - 25.0, zi=[0.0])[0] + 25.0
    branch = np.sign(np.gradient(die))
    d = die - 25.0
    bias = 1e-3 + 3.8e-4 * d + 3.4e-6 * d * d + 0.5 * hyst * branch
    rate = bias + rng.normal(0.0, 4.6e-4 * np.sqrt(3.6), t.size)
    nb = t.size // 4  # 4 s blocks are fine for a synthetic check
    tb = t[: nb * 4].reshape(nb, 4).mean(axis=1)
    yb = rate[: nb * 4].reshape(nb, 4).mean(axis=1)
    pt = case + rng.normal(0.0, 0.005, t.size)
    return CausalCalibration(t=tb, rate=yb, pt_t=t, pt_c=pt)


def test_selection_prefers_the_structured_model_when_the_die_lags() -> None:
    from gyrolab.compensation.causal import fit_causal

    cal = _staircase_run(tau_die=600.0, hyst=1e-3, seed=1)
    m = fit_causal(cal, families=("poly", "structured"))
    assert m.family == "structured"
    assert m.cv_rmse["structured"] < 0.7 * m.cv_rmse["poly"]
    assert 300.0 < m.params.tau_s < 900.0
    assert "hyst" in m.model.terms and m.model.h == pytest.approx(5e-4, rel=0.3)


def test_selection_keeps_the_polynomial_when_nothing_lags() -> None:
    from gyrolab.compensation.causal import fit_causal

    cal = _staircase_run(tau_die=0.0, hyst=0.0, seed=2)
    m = fit_causal(cal, families=("poly", "structured"))
    # the structured model cannot beat T alone by 1 %: the simpler family wins
    assert m.family == "poly" and m.params.tau_s == 0.0
    assert m.describe()["selection"]["winner"] == "poly"


# ------------------------------------------------------------------ rotation survives


def test_causal_output_keeps_injected_rotation_angle() -> None:
    """A causal model calibrated on a temperature sweep, applied to a run with known
    rotations added: its output keeps every event's angle within 0.1 % (issue 11 point 5;
    the same ``drift_at`` is what ``StreamingCompensator(..., "causal")`` and ``gyrolab
    apply`` subtract, see test_compensate_cli)."""
    from gyrolab.compensation.causal import fit_causal
    from gyrolab.compensation.rotation import angle_kept, rotation_events

    cal = _staircase_run(tau_die=300.0, hyst=1e-3, seed=6, hours=3.0)
    m = fit_causal(cal, families=("poly", "structured"))
    fs = 10.0
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 3.0 * 3600.0, 1.0 / fs)
    pt_t, pt_c = cal.pt_t, cal.pt_c  # a static run on the same temperature history
    static = 1e-3 + 3.8e-4 * (np.interp(t, pt_t, pt_c) - 25.0)
    static = static + rng.normal(0.0, 0.05 / 60.0 * np.sqrt(fs), t.size)
    d = m.drift_at(t, pt_t, pt_c)
    y0 = static - d
    events = rotation_events(t, t0=3600.0, seed=1)
    assert set(events) == {
        "index 90°",
        "pulse 1 min",
        "pulse 5 min",
        "pulse 15 min",
        "random 20 min",
    }
    for name, omega in events.items():
        assert np.sum(omega) / fs > 50.0, name  # a real turn, not a zero-mean wiggle
        y = static + omega - m.drift_at(t, pt_t, pt_c)
        assert abs(angle_kept(y, y0, 1.0 / fs, omega, 1.0 / fs) - 1.0) < 1e-3, name


# ------------------------------------------------------------------------ the oracle


def test_oracle_is_the_run_without_its_deterministic_drift(tmp_path) -> None:
    """Replaying a gyrolab-simulate recording's setpoints with the model's deterministic
    effects and subtracting gives exactly its noise (up to the ADC's step)."""
    from gyrolab.compensation.oracle import oracle_rate
    from gyrolab.profiles.profile import BUILTIN
    from gyrolab.record.reader import read_recording
    from gyrolab.sim.model import nominal_model
    from gyrolab.sim.physics import Physics
    from gyrolab.sim.simulate import simulate_run

    model = (
        nominal_model()
        .with_effect("thermal_lag", tau_s=300.0)
        .with_effect("hysteresis")
        .with_effect("thermal_rate")
        .with_effect("warmup")
    )
    path = tmp_path / "sim.mcap"
    simulate_run(path, BUILTIN["short"], model, rate_hz=5.0, seed=9, show_progress=False)
    rec = read_recording(path)
    o = oracle_rate(rec)
    noise_only = Physics(
        model.without_effect("bias_poly")
        .without_effect("hysteresis")
        .without_effect("thermal_rate")
        .without_effect("warmup"),
        rate_hz=5.0,
        seed=9,
    ).advance(o.size)
    adc = model.sensors.adc
    lsb = adc.vref_v / 2 ** (adc.bits - 1) / adc.gain_v_per_dps
    assert np.max(np.abs(o - noise_only.rate_dps)) <= lsb
    # a recording that is not a gyrolab simulate output has no oracle
    rec.run = {**rec.run, "source": "acquisition"}
    assert oracle_rate(rec) is None


def test_firmware_loop_equals_offline_model_output() -> None:
    """A fitted structured model run reading by reading (state machine + model, as on the
    device) gives the offline drift estimate sample for sample."""
    from gyrolab.compensation.causal import fit_causal

    cal = _staircase_run(tau_die=300.0, hyst=1e-3, seed=4, hours=3.0)
    m = fit_causal(cal, families=("structured",))
    offline = m.reading_drift(cal.pt_t, cal.pt_c)
    s = initial_state(float(cal.pt_c[0]), float(cal.pt_t[0]))
    prev = float(cal.pt_t[0])
    loop = np.empty(cal.pt_c.size)
    for i, (t, T) in enumerate(zip(cal.pt_t, cal.pt_c, strict=True)):
        f = step(s, float(T), float(t) - prev, m.params)
        prev = float(t)
        loop[i] = m.model.predict(np.array([f]))[0]
    assert np.array_equal(loop, offline)


def test_effective_samples_of_correlated_residuals() -> None:
    from scipy.signal import lfilter

    from gyrolab.compensation.structured import effective_samples

    rng = np.random.default_rng(4)
    w = rng.standard_normal(50_000)
    assert effective_samples(w) == pytest.approx(50_000, rel=0.05)
    ar = lfilter([1.0], [1.0, -0.9], w)  # AR(1): n (1 − φ)/(1 + φ) = n/19
    assert effective_samples(ar) == pytest.approx(50_000 / 19, rel=0.3)


def test_no_issue_23_term_is_kept_for_a_unit_without_it_and_the_band_round_trips() -> None:
    from gyrolab.compensation.causal import causal_from_state, fit_causal
    from gyrolab.compensation.structured import EXTRA_TERMS, TERMS

    cal = _staircase_run(tau_die=600.0, hyst=1e-3, seed=1)
    m = fit_causal(cal, families=("poly", "structured"))
    assert set(m.model.terms) <= set(TERMS) and not set(m.model.terms) & set(EXTRA_TERMS)
    b = m.band
    assert b is not None and b.level == 0.9 and b.half_width > 0
    # a run beyond the calibrated range gets a wider band, never wider than the cap
    t = cal.pt_t
    hot = cal.pt_c + 70.0  # every reading above the calibrated range
    h = b.half_width_at(t, t, hot)
    assert np.all(h > b.half_width)
    assert np.all(b.half_width_at(t, t, hot + 500.0) <= max(b.max_half_width, b.half_width))
    meta = m.describe()
    back = causal_from_state(meta, {}, "causal.")
    assert back.band == b
    np.testing.assert_array_equal(back.reading_drift(t, cal.pt_c), m.reading_drift(t, cal.pt_c))


@pytest.mark.parametrize("warm, kept", [(4e-4, True), (0.0, False)])
def test_the_warmup_is_kept_by_its_t_as_the_cv_cannot_see_it(warm: float, kept: bool) -> None:
    """Its column lives in the first CV segment (held out, the ridge fold fit gives it
    ~0), so the CV cannot judge it — here the CV's 1 % tie would drop a real warm-up;
    the effective-sample t keeps a real warm-up and drops an absent one."""
    from gyrolab.compensation.baselines import blocked_folds
    from gyrolab.compensation.drift_model import TIE
    from gyrolab.compensation.structured import CV_RIDGE, T_KEEP, _select_terms_backward, cv_linear

    rng = np.random.default_rng(11)
    t = np.arange(4000) * 3.6
    F = 20.0 + 30.0 * np.sin(2 * np.pi * t / 20000.0)
    R = np.gradient(F, t)
    X = np.column_stack([F, R, np.sign(R), np.exp(-t / 900.0)])
    y = 2e-5 * F + 0.3 * R + 1e-4 * X[:, 2] + warm * X[:, 3] + rng.normal(0, 5e-5, t.size)
    folds = blocked_folds(t.size, 5, 10)
    terms, _, log = _select_terms_backward(X, y, 2, folds)
    assert ("warmup" in terms) is kept
    assert (log["warmup_t"] >= T_KEEP) is kept
    with_w = cv_linear(X, y, 2, ("rate", "hyst", "warmup"), folds, ridge=CV_RIDGE)
    without = cv_linear(X, y, 2, ("rate", "hyst"), folds, ridge=CV_RIDGE)
    assert without <= with_w * (1.0 + TIE)  # the CV's tie alone would drop it either way
