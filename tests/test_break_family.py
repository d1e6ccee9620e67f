"""The break-the-model validation family (benchmarks/breakfam, issue 23): its physics does
what its docstring says, its scorer is right on known input, and one small in-process
round (one unit, calibrate, one held-out run) runs gyrolab's causal model through it.
The full family is ``benchmarks/break_suite.py`` (docs/results.md)."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from breakfam import physics as P  # noqa: E402
from breakfam.family import simulate_run, units  # noqa: E402
from breakfam.realnoise import real_noise, records  # noqa: E402
from breakfam.score import means, score, window_means  # noqa: E402
from breakfam.trajectories import CALIBRATIONS, NAMES, trajectory  # noqa: E402


def test_family_shares_no_code_with_gyrolab() -> None:
    root = Path(__file__).resolve().parents[1] / "benchmarks" / "breakfam"
    for f in root.glob("*.py"):
        assert "gyrolab" not in f.read_text().replace("gyrolab's", ""), f.name


def test_two_node_network_self_heats_the_die() -> None:
    u = replace(units(1)[0], q0=2.0 / 300.0, tau_dp=300.0, beta=0.0)
    air = np.full(6 * 3600, 25.0)
    pkg, die = P.thermal(u, air, 25.0)
    # steady state: the die q0·τ_dp above the package (less what the package takes back)
    assert 1.5 < die[-1] - pkg[-1] < 2.05
    assert die[0] - pkg[0] < 0.05  # at rest at power-on: the warm-up is the transient
    # a package step reaches the die later
    air2 = np.r_[np.full(3600, 25.0), np.full(3600, 45.0)]
    pkg2, die2 = P.thermal(replace(u, q0=0.0), air2, 25.0)
    assert pkg2[3700] - 25.0 > die2[3700] - 25.0


def test_hysteresis_width_follows_temperature() -> None:
    u = replace(units(1)[0], h=(1e-3, 0.0, 0.0), w0=(2.0, 1.0, 1.0), kappa=0.8)
    u = replace(u, c=(0.0,) * 5, k_pos=0.0, k_neg=0.0, k2=0.0, g=0.0, age_a=0.0)
    t = np.arange(4000.0)

    def saturated(centre: float) -> float:
        """Share of a ±3 °C cycle at ``centre`` on a saturated branch (|S| = 1)."""
        D = centre + 3.0 * np.sin(2 * np.pi * t / 1000.0)
        return float(np.mean(np.abs(P.drift(u, D, D, 0.0)[2000:] / 1e-3) > 0.999))

    # the branch flips within the play width: wider at the warm end (κ > 0), so less of
    # the cycle is saturated there than at the cold end
    assert saturated(45.0) < saturated(5.0)


def test_real_noise_is_scaled_to_the_arw() -> None:
    a, arw0 = records()
    assert a.shape[0] == 15 and 1.5 < arw0 < 4.0  # the ADIS16405's ARW, °/√h
    x = real_noise(200_000, 0.05, np.random.default_rng(1))
    s1 = means(x, 10)
    assert 60.0 * np.std(s1) == pytest.approx(0.05, rel=0.1)


def test_scorer_on_known_input() -> None:
    y = np.r_[np.zeros(36 * 28), np.full(36 * 28, 1e-3)]
    s = score(y)
    assert s["pp_100s_deg_per_s"] == pytest.approx(1e-3)
    assert s["mean_bias_deg_per_h"] == pytest.approx(1.8)
    assert s["bias_stability_deg_per_h"] == pytest.approx(3600 * np.std(means(y, 36), ddof=1))
    assert window_means(y).size == 2


def test_trajectories_are_defined() -> None:
    for name in NAMES:
        sp, rest = trajectory(name, 1)
        assert sp.size > 5 * 3600 and -40.0 <= sp.min() and sp.max() <= 60.0
    for name, base in CALIBRATIONS.items():  # the run it extends, with a cycle inserted
        sp, rest = trajectory(name, 1)
        sb, rb = trajectory(base, 1)
        assert rest == rb and sp.size > sb.size
        assert -40.0 <= sp.min() and sp.max() <= 60.0
        # the base run is kept whole: a prefix of it, the inserted cycle, the rest of it
        left = np.flatnonzero(sp[: sb.size] != sb)
        head = int(left[0]) if left.size else sb.size
        tail = sb.size - head
        assert tail == 0 or np.array_equal(sp[sp.size - tail :], sb[head:]), name
        # what it adds: ramps of 3 °C/min at most, from where it leaves the base run
        added = sp[max(head - 1, 0) : sp.size - tail]
        assert np.abs(np.diff(added)).max() <= 3.01 / 60.0, name


def test_one_round_through_gyrolab_causal_model() -> None:
    from gyrolab.compensation.causal import CausalCalibration, fit_causal
    from gyrolab.numerics.averaging import block_average

    u = units(1)[0]
    cal = simulate_run(u, "staircase", seed=1)
    held = simulate_run(u, "heating", seed=2)
    tb, xb, _ = block_average(cal.t, cal.raw, 3.6, 0.1)
    m = fit_causal(
        CausalCalibration(t=tb, rate=xb, pt_t=cal.pt_t, pt_c=cal.pt_c),
        families=("poly", "structured"),
    )
    y = held.raw - m.drift_at(held.t, held.pt_t, held.pt_c)
    raw, out, oracle = score(held.raw), score(y), score(held.raw - held.drift)
    assert out["bias_stability_deg_per_h"] < 0.2 * raw["bias_stability_deg_per_h"]
    assert out["bias_stability_deg_per_h"] >= oracle["bias_stability_deg_per_h"] * 0.98
    lo, hi = m.band_at(held.t, held.pt_t, held.pt_c)
    assert np.all(hi > 0) and np.all(lo == -hi)


def test_a_calibration_of_two_power_ons() -> None:
    # break_suite --cold-power-on: the ramp-cycle run and a cold power-on (coldcal) on one
    # time axis; the structured features of each run's blocks are those of that run alone
    import break_suite

    from gyrolab.compensation.causal_features import CausalParams
    from gyrolab.compensation.drift_model import POWER_CYCLE_GAP_S
    from gyrolab.compensation.structured import block_features

    sp, rest = trajectory("coldcal")
    assert rest == -20.0 and sp[0] == -20.0 and 3.5 * 3600 < sp.size < 3.7 * 3600
    u = units(1)[0]
    a, b = simulate_run(u, "staircase", seed=1), simulate_run(u, "coldcal", seed=2)
    cal = break_suite.calibration([a, b])
    one = [break_suite.calibration([r]) for r in (a, b)]
    end = max(one[0].t[-1], one[0].pt_t[-1])  # the first run's last block or reading
    assert end <= a.t[-1] and cal.power_ons == (float(end) + POWER_CYCLE_GAP_S,)
    assert cal.t.size == sum(c.t.size for c in one) and one[0].power_ons == ()
    p = CausalParams(tau_s=400.0, width_c=1.0, warmup_tau_s=600.0)
    X = block_features(cal, p)
    # to 1e-10: the second run's times, shifted by 1e6 s, round in their last bits
    np.testing.assert_allclose(X, np.vstack([block_features(c, p) for c in one]), atol=1e-10)
    ever = break_suite.calibration([simulate_run(u, "coldcal", seed=2), a])
    assert not np.allclose(block_features(ever, p)[:10, 0], X[:10, 0])  # order matters


def test_die_sensor_is_the_units_own_coarse_register() -> None:
    """The die thermometer (``--temperature internal`` in prior_suite): readings on its
    register's grid, one offset per unit across its runs (another unit another), and its
    own generator — the run's PT100 readings are those of the same seed without it."""
    u0, u1 = units(2)
    a, b = (simulate_run(u0, "slowramp", seed=s) for s in (3, 4))
    c = simulate_run(u1, "slowramp", seed=3)
    lsb = P.DIE_LSB_C
    assert np.allclose(a.die_sensor_c / lsb, np.round(a.die_sensor_c / lsb))
    off = [float(np.mean(r.die_sensor_c - r.die_c)) for r in (a, b, c)]
    assert abs(off[0] - off[1]) < 0.01  # the same unit: the same offset (noise averages)
    assert abs(off[0] - off[2]) > 0.01  # draws of N(0, 0.5 °C) for units 0 and 1 differ
    rng = np.random.default_rng([3, 5])  # the run's own generator, as simulate_run seeds it
    sp, rest = trajectory("slowramp", 3)
    pkg, _ = P.thermal(u0, P.air_temperature(sp, rest), rest)
    assert np.array_equal(a.pt_c, P.pt100(u0, pkg, rng))


def test_true_form_regressors_span_the_familys_drift() -> None:
    """benchmarks/true_form.py's floor fits the family's own drift form: on each unit's
    run, the drift is exactly a linear combination of its regressors (and the coefficients
    are the unit's), so what that floor misses is noise and excitation, not form."""
    from true_form import regressors

    for u in (2, 3):  # every effect; and a unit without hysteresis
        unit = units(4)[u]
        sp, rest = trajectory("heating", 100 * u + 2)
        pkg, die = P.thermal(unit, P.air_temperature(sp, rest), rest)
        d = P.drift(unit, pkg, die, 86400.0)  # heating is held out on day 1
        X = regressors(unit, "heating", 100 * u + 2)
        beta = np.linalg.lstsq(X, d, rcond=None)[0]
        assert np.max(np.abs(X @ beta - d)) < 1e-9 * np.max(np.abs(d))
        assert beta[1] == pytest.approx(unit.c[1], rel=1e-6)  # the linear u coefficient
