"""The fleet prior and the MAP fit (gyrolab/compensation/prior.py, issue 30): a fleet of
synthetic units with known structured drift on the simulator's chamber, learned from their
13 h fits; a new unit calibrated on the 3.25 h ``quick`` profile borrows strength, a unit
of another part number is detected, and a full-data unit reproduces its own fit."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gyrolab.compensation.causal_features import CausalParams, hold, reading_features
from gyrolab.compensation.causal_models import hysteresis_width
from gyrolab.compensation.drift_model import CausalCalibration
from gyrolab.compensation.prior import (
    FleetPrior,
    UnitEntry,
    fit_map,
    learn_prior,
    unit_vector,
)
from gyrolab.compensation.profile_design import case_trace
from gyrolab.compensation.structured import fit_structured
from gyrolab.profiles.profile import BUILTIN
from gyrolab.sim.thermal import ThermalParams

BLOCK = 3.6


def _trace(name: str) -> tuple[np.ndarray, np.ndarray]:
    sched = [(s.setpoint_c, s.duration_s) for s in BUILTIN[name].steps]
    t, _, case = case_trace(sched, ThermalParams())
    return t, case


TRACES = {name: _trace(name) for name in ("paper", "quick")}


def _unit(rng: np.random.Generator, sign: float = 1.0) -> tuple[CausalParams, np.ndarray]:
    """True feature parameters and (c0, c1, c2, k, h, A) of a unit of the part number."""
    p = CausalParams(tau_s=float(rng.uniform(200, 400)), width_c=1.0, warmup_tau_s=600.0)
    c = np.array(
        [
            rng.normal(0.01, 0.004),
            sign * 3.8e-4 * rng.uniform(0.8, 1.2),
            3.4e-6 * rng.uniform(0.7, 1.3),
            rng.normal(0.1, 0.02),
            rng.normal(1e-3, 2e-4),
            rng.normal(3e-3, 5e-4),
        ]
    )
    return p, c


def _run(trace: str, p: CausalParams, c: np.ndarray, seed: int):
    """Block means of the unit's drift plus white and random-walk noise, and the truth."""
    t, case = TRACES[trace]
    rng = np.random.default_rng(seed)
    pt_c = case + 0.005 * rng.standard_normal(case.size)
    tb = np.arange(BLOCK / 2, t[-1], BLOCK)
    X = hold(tb, t, reading_features(t, case, p))
    dT = X[:, 0] - 25.0
    d = c[0] + c[1] * dT + c[2] * dT**2 + c[3] * X[:, 1] + c[4] * X[:, 2] + c[5] * X[:, 3]
    # ARW 0.05 °/√h (5e-4 °/s in 3.6 s) and a random walk of ~0.3 °/h over 13 h
    noise = 5e-4 * rng.standard_normal(tb.size) + np.cumsum(1e-6 * rng.standard_normal(tb.size))
    return CausalCalibration(t=tb, rate=d + noise, pt_t=t, pt_c=pt_c), d


def _own_fit(cal: CausalCalibration, p: CausalParams):
    X = hold(cal.t, cal.pt_t, reading_features(cal.pt_t, cal.pt_c, p))
    return fit_structured(X, cal.rate, 3, ("rate", "hyst", "warmup"))


@pytest.fixture(scope="module")
def fleet() -> FleetPrior:
    rng = np.random.default_rng(30)
    units = []
    for i in range(8):
        p, c = _unit(rng)
        cal, _ = _run("paper", p, c, seed=i)
        units.append(UnitEntry(f"u{i}", p, _own_fit(cal, p)))
    return learn_prior(units)


def _err(model, p_fit, trace: str, p: CausalParams, c: np.ndarray) -> float:
    """RMS error (°/s) of a fitted model's drift against the truth on ``trace``."""
    cal, d = _run(trace, p, c, seed=99)
    X = hold(cal.t, cal.pt_t, reading_features(cal.pt_t, cal.pt_c, p_fit))
    return float(np.sqrt(np.mean((model.predict(X) - d) ** 2)))


def test_quick_profile_is_short_and_goes_up_and_down() -> None:
    q = BUILTIN["quick"]
    assert q.duration_s <= 3.25 * 3600
    t, case = TRACES["quick"]
    i = int(np.argmax(case))
    assert case[i] - case[0] > 15 and case[i] - case[i:].min() > 60  # up, then down
    assert case[-1] - case[i:].min() > 2  # and up again at the end (a second reversal)


def test_quick_is_what_the_design_chooses() -> None:
    from gyrolab.compensation.profile_design import design_profile

    p, rec = design_profile(3.25)
    assert [(s.setpoint_c, s.duration_s) for s in p.steps] == [
        (s.setpoint_c, s.duration_s) for s in BUILTIN["quick"].steps
    ]
    lo, hi = rec["case_range_c"]
    assert -19 < lo < -17 and 45 < hi < 47


def test_design_weighted_to_the_soaks_holds_the_hot_end_longer() -> None:
    from gyrolab.compensation.profile_design import design_profile

    p, rec = design_profile(3.25, weight="soaks")
    # the drift wanted at the settled 60 °C soak too: a longer hot leg, a hotter case
    assert rec["weight"] == "soaks" and p.steps[1].setpoint_c == 60.0
    assert p.steps[1].duration_s > BUILTIN["quick"].steps[1].duration_s
    assert rec["case_range_c"][1] > 47
    with pytest.raises(ValueError, match="weight"):
        design_profile(3.25, weight="hot")


def test_prior_one_cluster_and_in_prior_unit_borrows_strength(fleet: FleetPrior) -> None:
    assert len(fleet.clusters) == 1 and len(fleet.units) == 8
    p, c = _unit(np.random.default_rng(1234))
    cal, _ = _run("quick", p, c, seed=5)
    got = fit_map(cal, fleet)
    assert got.membership.belongs, got.membership.to_dict()
    # held out on the 13 h staircase (the quick run never sees the case below -18 °C):
    # the shrinkage estimate beats the unit's own short-run fit by far
    e_map = _err(got.model.model, got.model.params, "paper", p, c)
    e_own = _err(_own_fit(cal, p), p, "paper", p, c)
    assert e_map < 0.5 * e_own, (e_map, e_own)
    assert e_map < 1e-4  # a fifth of the white noise of one 3.6 s block
    w = hysteresis_width(got.model.model)
    assert w["at_mid_deg_per_h"] == pytest.approx(7200 * c[4], rel=0.5)


def test_another_part_number_is_detected(fleet: FleetPrior) -> None:
    p, c = _unit(np.random.default_rng(77), sign=-1.0)  # temperature slope reversed
    cal, _ = _run("quick", p, c, seed=6)
    mem = fit_map(cal, fleet).membership
    assert not mem.belongs and mem.p_value < 1e-6
    assert "full profile" in mem.message()


def test_full_data_unit_reproduces_its_own_fit(fleet: FleetPrior) -> None:
    p, c = _unit(np.random.default_rng(4321))
    cal, d = _run("paper", p, c, seed=8)
    got = fit_map(cal, fleet)
    own = _own_fit(cal, p)
    X = hold(cal.t, cal.pt_t, reading_features(cal.pt_t, cal.pt_c, got.model.params))
    Xo = hold(cal.t, cal.pt_t, reading_features(cal.pt_t, cal.pt_c, p))
    diff = got.model.model.predict(X) - own.predict(Xo)
    assert float(np.sqrt(np.mean(diff**2))) < 5e-5  # 10 % of the 3.6 s white noise


def test_unit_vector_and_prior_round_trip(fleet: FleetPrior) -> None:
    b = fleet.basis
    theta = fleet.clusters[0].mean
    again = unit_vector(b.model(theta), b)
    np.testing.assert_allclose(again, theta, rtol=1e-9, atol=1e-12)
    back = FleetPrior.from_dict(fleet.to_dict())
    np.testing.assert_array_equal(back.clusters[0].cov, fleet.clusters[0].cov)


def test_clusters_found_when_the_units_form_groups() -> None:
    """Two part-number variants (the temperature slope reversed): two clusters, and a new
    unit of the second variant belongs to its cluster."""
    rng = np.random.default_rng(3)
    units = []
    for i in range(8):
        p, c = _unit(rng, sign=1.0 if i % 2 else -1.0)
        cal, _ = _run("paper", p, c, seed=40 + i)
        units.append(UnitEntry(f"u{i}", p, _own_fit(cal, p)))
    prior = learn_prior(units)
    assert sorted(sorted(cl.members) for cl in prior.clusters) == [
        ["u0", "u2", "u4", "u6"],
        ["u1", "u3", "u5", "u7"],
    ]
    p, c = _unit(np.random.default_rng(8), sign=-1.0)
    cal, _ = _run("quick", p, c, seed=9)
    mem = fit_map(cal, prior).membership
    assert mem.belongs and "u0" in prior.clusters[mem.cluster].members


@pytest.mark.parametrize(
    "name,fleet,value,seeds",
    [
        ("start_branch", (1.0, 1.0, 1.0, 1.0), 1.0, (23, 24, 60)),
        ("self_heating_c", (0.5, 0.5, 1.0, 0.25), 0.5, (25, 26, 70)),
        ("width_temp_per_c", (0.01, 0.01, 0.005, 0.01), 0.01, (27, 28, 80)),
    ],
)
def test_power_on_branch_self_heating_and_width_slope_are_carried_to_the_fit(
    name: str, fleet: tuple[float, ...], value: float, seeds: tuple[int, int, int]
) -> None:
    """Units whose models start on the heating branch (issue 23's power-on branch, s₀ = +1)
    or whose play follows the die's self-heating or changes width with temperature
    (``structured_rate``'s δ and κ): the cluster carries the members' median, the MAP fit
    of a new unit of the part number runs its play with it, and a prior saved before it
    was carried reads as 0 (δ, κ: and is written without it)."""
    rng = np.random.default_rng(seeds[0])
    units = []
    for i, v in enumerate(fleet):
        p, c = _unit(rng)
        p = replace(p, **{name: v})
        cal, _ = _run("paper", p, c, seed=seeds[2] + i)
        units.append(UnitEntry(f"u{i}", p, _own_fit(cal, p)))
    prior = learn_prior(units)
    assert [getattr(cl, name) for cl in prior.clusters] == [value]
    p, c = _unit(np.random.default_rng(seeds[1]))
    cal, _ = _run("quick", replace(p, **{name: value}), c, seed=7)
    got = fit_map(cal, prior)
    assert getattr(got.model.params, name) == value, got.log["features_from"]
    assert got.log["features"][name] == value
    d = prior.to_dict()
    assert getattr(FleetPrior.from_dict(d).clusters[0], name) == value
    del d["clusters"][0][name]
    back = FleetPrior.from_dict(d)
    assert getattr(back.clusters[0], name) == 0.0
    assert (name in back.to_dict()["clusters"][0]) == (name == "start_branch")


def test_own_covariance_holds_correlated_noise() -> None:
    """The detector's jackknife covariance of a least-squares estimate under correlated
    noise (AR(1), correlation time 10 samples, shorter than a jackknife block) matches the
    estimate's spread over repeated runs; the white-noise formula ``s² (AᵀA)⁻¹`` claims
    it 20× too small."""
    from scipy.signal import lfilter

    from gyrolab.compensation.prior import own_covariance

    rng = np.random.default_rng(11)
    n = 1200
    x = np.linspace(-1.0, 1.0, n)
    A = np.stack([np.ones(n), x, np.sin(3 * x)], axis=1)
    est, jk, white = [], [], []
    for _ in range(150):
        e = lfilter([1.0], [1.0, -0.9], rng.standard_normal(n)) * 0.01
        y = A @ np.array([1.0, 0.5, -0.2]) + e
        th, res, *_ = np.linalg.lstsq(A, y, rcond=None)
        est.append(th)
        jk.append(np.diag(own_covariance(A, y)))
        white.append(np.diag(res[0] / (n - 3) * np.linalg.inv(A.T @ A)))
    spread = np.var(np.array(est), axis=0, ddof=1)
    ratio_jk = np.mean(jk, axis=0) / spread
    ratio_white = np.mean(white, axis=0) / spread
    assert np.all((ratio_jk > 0.7) & (ratio_jk < 1.3)), ratio_jk
    assert np.all(ratio_white < 0.1), ratio_white


def test_log_evidence_is_the_marginal_likelihood() -> None:
    """Woodbury's form against the dense Gaussian ``y ~ N(A μ, s² I + A Σ Aᵀ)``: equal up
    to the constant common to every prior, so differences between priors agree."""
    from scipy.stats import multivariate_normal

    from gyrolab.compensation.prior import log_evidence

    rng = np.random.default_rng(5)
    A = rng.standard_normal((40, 3))
    y = A @ np.array([0.3, -1.0, 0.5]) + 0.2 * rng.standard_normal(40)
    s2 = 0.04
    got, dense = [], []
    for mu, sd in (([0.0, 0.0, 0.0], [1.0, 1.0, 1.0]), ([0.3, -1.0, 0.0], [0.1, 0.1, 3.0])):
        cov = np.diag(np.square(sd))
        got.append(log_evidence(A, y, s2, np.array(mu), cov))
        dense.append(multivariate_normal(A @ mu, s2 * np.eye(40) + A @ cov @ A.T).logpdf(y))
    assert got[1] - got[0] == pytest.approx(dense[1] - dense[0], rel=1e-9)


def test_a_term_the_fleet_mostly_lacks_is_not_shrunk_away() -> None:
    """A fleet where one unit in six has a warm-up: the Gaussian prior of the warm-up is
    the others' near-zero spike. A new unit whose quick run shows a strong warm-up is sent
    to the full profile (the rare-term test); one without it belongs."""
    rng = np.random.default_rng(31)
    units = []
    for i in range(6):
        p, c = _unit(rng)
        c[5] = c[5] if i == 0 else 0.0
        cal, _ = _run("paper", p, c, seed=80 + i)
        terms = ("rate", "hyst", "warmup") if i == 0 else ("rate", "hyst")
        X = hold(cal.t, cal.pt_t, reading_features(cal.pt_t, cal.pt_c, p))
        units.append(UnitEntry(f"u{i}", p, fit_structured(X, cal.rate, 3, terms)))
    prior = learn_prior(units)
    assert [prior.basis.names()[j] for j, *_ in prior.slabs] == ["warmup"]
    p, c = _unit(np.random.default_rng(32))
    c[5] = 4e-3
    mem = fit_map(_run("quick", p, c, seed=11)[0], prior).membership
    assert not mem.belongs and "warmup" in mem.wanted, mem.to_dict()
    assert "full profile" in mem.message()
    c[5] = 0.0
    mem = fit_map(_run("quick", p, c, seed=12)[0], prior).membership
    assert mem.belongs and not mem.wanted, mem.to_dict()
    assert FleetPrior.from_dict(prior.to_dict()).slabs == prior.slabs
    # the fleet's one warm-up is positive: the slab is its half on that side, and a run
    # whose warm-up has the other sign does not want the fleet's term
    assert prior.slabs[0][3] == 1
    c[5] = -4e-3
    mem = fit_map(_run("quick", p, c, seed=11)[0], prior).membership
    assert "warmup" not in mem.wanted, mem.to_dict()
    # a prior saved before the sign (three numbers a slab) gets the symmetric slab
    old = prior.to_dict()
    old["slabs"] = [x[:3] for x in old["slabs"]]
    assert [x[3] for x in FleetPrior.from_dict(old).slabs] == [0]
