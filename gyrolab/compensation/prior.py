"""A fleet prior over the structured causal drift model, and the shrinkage (MAP) fit of a
new unit towards it (issue 30): calibrate a unit on a short run by learning from the
units calibrated before it.

**Parameter vector.** A unit's structured model (:mod:`gyrolab.compensation.causal`)

    d = Σ c_i L_i(u(F)) + k R + h S + A E + kp max(R, 0) + k2 R|R| + hT S v

is made comparable across units by expressing it on one *reference basis*
(:class:`Basis`): Legendre polynomials of order ``P`` on the fleet's range ``[lo, hi]`` of
the die temperature F (the union of the units' calibration ranges), followed by the six
terms. A unit's own polynomial (on its own range, continued linearly outside it) is
projected onto that basis by least squares on a grid of F over the reference range; its
``hT`` term (on its own ``v``) becomes ``hT a`` on the reference ``v`` and ``hT b`` on S
(``v_unit = a v_ref + b``). The linear parameter vector is θ (``P + 7`` numbers, °/s per
regressor unit); the nonlinear one φ = (ln(τ + 60 s), ln w, ln τ_w) (feature
parameters of :class:`~gyrolab.compensation.causal_features.CausalParams`).

**Prior** (:func:`learn_prior`): per cluster of units, the mean μ of θ, and a covariance
Σ = (1 + 1/n) (½ S + ½ diag(S)) + floor: S the within-cluster covariance pooled over the
clusters (they differ in their means), shrunk halfway to its diagonal (a few dozen units
cannot estimate ``P + 7`` dimensions' correlations), widened for the cluster mean's own
uncertainty (n units), and a floor: no component is claimed known better than
:data:`FLOOR_DPS` at its regressor's largest value (:data:`REGRESSOR_SCALE`). φ gets a
mean and standard deviation per cluster (floor 0.1); the power-on hysteresis branch s₀
(``start_branch``, 0 or +1: issue 23's ``structured_rate``), the play's self-heating
shift δ (``self_heating_c``, °C) and its width's temperature coefficient κ
(``width_temp_per_c``, 1/°C; both the same family's) and the die's own self-heating δ_d
(``die_heating_c``, °C) are not in φ but carried with it — each cluster fits and applies
its members' median s₀, δ, κ and δ_d.
**Clusters**: k-means (k = 2, 3) on what the units' drift does (°/s: the polynomial at 11
temperatures, each term at its largest regressor value), kept only when every cluster has
≥ :data:`MIN_CLUSTER` units and the mean silhouette is ≥ :data:`SILHOUETTE_MIN` (the
units form clear groups, as 250 MPU-9250s did in CEUR Vol-2278); else one cluster.

**MAP fit** (:func:`fit_map`): at feature parameters φ, the features of the unit's run give
the design A on the reference basis and θ minimises

    J(θ) = |y − A θ|² / s² + (θ − μ)ᵀ Σ⁻¹ (θ − μ)

(closed form), where ``s² = σ² n / n_eff`` — the residual variance of the 3.6 s
means inflated by the effective sample size of the residual
(:func:`~gyrolab.compensation.structured.effective_samples`), the same inflation the
structured model's term test uses: flicker-dominated residuals are far from independent.
φ is chosen on a grid around the cluster's prior (τ, w, τ_w at the prior mean and ±½ … ±2
sd, one component at a time, τ twice) by the blocked CV RMSE of that MAP fit (the causal
selection's folds); the φ the unit's own causal selection chooses without a prior
(:data:`OWN_FAMILIES`) competes on the same CV — the grid search is local, and a unit
whose lag lies away from its cluster's was otherwise fitted at the wrong one. Not by a
joint J over θ and φ: with the prior on θ in the criterion, φ bends the features until θ
looks typical (validation unit 10's lag came out 2080 s for a true 1176 s, its held-out
bias stability 2.5× its 13 h fit's). A unit with much data
(the 13 h run) is dominated by its own likelihood and reproduces its own fit; a short run
borrows the prior where it says little (the cold end the chamber cannot reach in 3 h,
the warm-up, the hysteresis).

**Does the unit belong?** (:class:`Membership`): the unit's own least-squares estimate
θ̂ (same φ) against the prior, on the components some unit of the fleet uses: its
covariance ``C`` by the delete-a-block jackknife over the run (:func:`own_covariance`:
the white-noise ``s² (AᵀA)⁻¹`` was a median 2.9× too small on the suites' quick runs), and
the Mahalanobis distance ``d²`` of θ̂ − μ under ``Σ + C`` over the directions where the
run says more than the prior (:func:`informative_distance`), χ² with that many degrees of
freedom. Over all directions the statistic was not calibrated — in-family units had a
median d²/dof of 1.6 (χ² ≈ 0.93) and 3 of 24 fell below p = 1e-3 — because where a
3 h run leaves the prior to speak (the temperatures it never reached) θ̂ is its own
extrapolation: noise and bias, no power (docs/results.md, "Chamber time", measured). A
unit whose p-value is below :data:`P_OUT` (in every cluster) does not belong: another
part number, a defective unit — it must be calibrated on the full profile.
The cluster of a unit is the one of largest p-value.
**A term the fleet mostly lacks** (:func:`wanted_terms`): a term fewer than half the
fleet's units use has the absent units' near-zero spike for a Gaussian prior, and the
distance above, over the directions the run informs, may not see a unit that has it. A
spike-and-slab test per such term — the run's marginal likelihood with the term's prior
replaced by a wide slab (on the fleet's side of zero where its units agree on the sign)
against the cluster's prior, times the fleet's prior odds of the term — refuses the unit
the same way when the odds favour the term.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.polynomial import legendre
from scipy import stats

from gyrolab.compensation.band import fit_band
from gyrolab.compensation.baselines import blocked_folds
from gyrolab.compensation.causal import CV_FOLDS, CV_SEGMENTS, fit_causal
from gyrolab.compensation.causal_features import CausalParams
from gyrolab.compensation.causal_models import StructuredCausalModel, hysteresis_width
from gyrolab.compensation.drift_model import CausalCalibration
from gyrolab.compensation.structured import StructuredModel, block_features, effective_samples
from gyrolab.numerics.jackknife import jackknife_covariance

#: the six terms after the Legendre columns, in θ order
TERMS = ("rate", "hyst", "warmup", "rate_pos", "rate_sq", "hyst_T")
#: each term's largest regressor value on a chamber run (R ≤ 3 °C/min = 0.05 °C/s,
#: R|R| ≤ 0.0025 °C²/s², S, E, v ≤ 1): the scale of the prior's floor
REGRESSOR_SCALE = {
    "rate": 0.05,
    "hyst": 1.0,
    "warmup": 1.0,
    "rate_pos": 0.05,
    "rate_sq": 0.0025,
    "hyst_T": 1.0,
}
#: the prior never claims a component known better than this at its largest value, °/s
FLOOR_DPS = 1e-4
PHI_SD_FLOOR = 0.1
TAU0_S = 60.0  # φ₁ = ln(τ + τ0): τ = 0 is allowed
MIN_CLUSTER = 3
SILHOUETTE_MIN = 0.5
P_OUT = 1e-3
#: contiguous stretches of the run the detector's jackknife deletes one at a time
JACKKNIFE_BLOCKS = 24
#: the detector tests the directions where the run's precision is at least this many
#: times the prior's
INFORMATIVE = 1.0
MAX_ORDER = 6
#: the families whose causal selection gives the unit's own φ, the MAP fit's second start
OWN_FAMILIES = ("poly", "structured")
#: a rare term's slab: N(0, (SLAB_WIDEN × the RMS of the fleet's nonzero values)²), or its
#: half on the fleet's side (docs/results.md, "Chamber time": the widths measured)
SLAB_WIDEN = 5.0
#: a term fewer than this fraction of the fleet uses is *rare*: its Gaussian prior is the
#: absent units' near-zero spike, and a run that wants the term is tested for it
RARE = 0.5
#: φ grid of the MAP fit: the prior mean plus these multiples of its sd
PHI_STEPS = (-2.0, -1.5, -1.0, -0.5, 0.0, 0.5, 1.0, 1.5, 2.0)


@dataclass(frozen=True)
class Basis:
    """The fleet's reference basis: Legendre order ``order`` on ``[lo, hi]`` (°C of F),
    then :data:`TERMS`."""

    lo: float
    hi: float
    order: int

    @property
    def size(self) -> int:
        return self.order + 1 + len(TERMS)

    def names(self) -> list[str]:
        return [f"c{i}" for i in range(self.order + 1)] + list(TERMS)

    def u(self, F: np.ndarray) -> np.ndarray:
        return (2.0 * np.asarray(F, dtype=float) - (self.lo + self.hi)) / (self.hi - self.lo)

    def design(self, X: np.ndarray) -> np.ndarray:
        """The regressors of feature rows ``X = (F, R, S, E)``; the Legendre part is
        continued linearly beyond ``[lo, hi]`` as the structured model's is."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        u = self.u(X[:, 0])
        uc = np.clip(u, -1.0, 1.0)
        L = legendre.legvander(uc, self.order)
        if np.any(u != uc):
            eye = np.eye(self.order + 1)
            dL = np.stack(
                [legendre.legval(uc, legendre.legder(eye[i])) for i in range(self.order + 1)],
                axis=1,
            )
            L = L + dL * (u - uc)[:, None]
        R, S, E = X[:, 1], X[:, 2], X[:, 3]
        terms = [R, S, E, np.maximum(R, 0.0), R * np.abs(R), S * uc]
        return np.hstack([L, np.stack(terms, axis=1)])

    def scale(self) -> np.ndarray:
        """Each regressor's largest value (the floor's scale)."""
        return np.array([1.0] * (self.order + 1) + [REGRESSOR_SCALE[t] for t in TERMS])

    def model(self, theta: np.ndarray) -> StructuredModel:
        """θ as a structured model on the reference range."""
        P = self.order + 1
        k, h, A, kp, k2, hT = (float(v) for v in theta[P:])
        terms = tuple(t for t, v in zip(TERMS, theta[P:], strict=True) if v != 0.0)
        return StructuredModel(
            coef=np.asarray(theta[:P], dtype=float),
            lo=self.lo,
            hi=self.hi,
            k=k,
            h=h,
            A=A,
            terms=terms,
            kp=kp,
            k2=k2,
            hT=hT,
        )

    def to_dict(self) -> dict[str, Any]:
        return {"lo": self.lo, "hi": self.hi, "order": self.order}


def phi_of(p: CausalParams) -> np.ndarray:
    """φ = (ln(τ + τ0), ln w, ln τ_w)."""
    return np.array([math.log(p.tau_s + TAU0_S), math.log(p.width_c), math.log(p.warmup_tau_s)])


def params_of(
    phi: np.ndarray,
    start_branch: float = 0.0,
    self_heating_c: float = 0.0,
    width_temp_per_c: float = 0.0,
    die_heating_c: float = 0.0,
) -> CausalParams:
    """The feature parameters of φ, the play starting on hysteresis branch
    ``start_branch`` s₀ (issue 23's power-on branch: not part of φ — it takes the values
    0 and +1 only — but carried with it, so a unit or cluster whose models start on the
    heating branch is fitted and applied on it)."""
    return CausalParams(
        tau_s=max(float(math.exp(phi[0]) - TAU0_S), 0.0),
        width_c=float(math.exp(phi[1])),
        warmup_tau_s=float(math.exp(phi[2])),
        start_branch=float(start_branch),
        self_heating_c=float(self_heating_c),
        width_temp_per_c=float(width_temp_per_c),
        die_heating_c=float(die_heating_c),
    )


def unit_vector(m: StructuredModel, basis: Basis) -> np.ndarray:
    """A unit's structured model as θ on the reference basis (module docstring)."""
    F = np.linspace(basis.lo, basis.hi, 201)
    V = legendre.legvander(basis.u(F), basis.order)
    c = np.linalg.lstsq(V, m.poly(F), rcond=None)[0]
    # v_unit = a v_ref + b (their clipping ignored: the two ranges nearly agree)
    a = (basis.hi - basis.lo) / (m.hi - m.lo)
    b = ((basis.lo + basis.hi) - (m.lo + m.hi)) / (m.hi - m.lo)
    tail = [m.k, m.h + m.hT * b, m.A, m.kp, m.k2, m.hT * a]
    return np.concatenate([c, np.asarray(tail, dtype=float)])


@dataclass
class UnitEntry:
    """One earlier unit: its name, feature parameters and structured model."""

    name: str
    params: CausalParams
    model: StructuredModel


@dataclass
class Cluster:
    """A group of units: the prior of θ (``mean``, ``cov``) and of φ."""

    mean: np.ndarray
    cov: np.ndarray
    phi_mean: np.ndarray
    phi_sd: np.ndarray
    members: list[str]
    #: the members' power-on hysteresis branch s₀ (their median: 0 or +1)
    start_branch: float = 0.0
    #: the members' self-heating shift δ of the play (their median, °C)
    self_heating_c: float = 0.0
    #: the members' play-width temperature coefficient κ (their median, 1/°C)
    width_temp_per_c: float = 0.0
    #: the members' own die self-heating δ_d (their median, °C)
    die_heating_c: float = 0.0

    def params(self, phi: np.ndarray | None = None) -> CausalParams:
        """The feature parameters at ``phi`` (default: the cluster's mean) on the
        cluster's start branch, self-heating shift and width coefficient."""
        phi = self.phi_mean if phi is None else phi
        return params_of(
            phi, self.start_branch, self.self_heating_c, self.width_temp_per_c, self.die_heating_c
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "mean": self.mean.tolist(),
            "cov": self.cov.tolist(),
            "phi_mean": self.phi_mean.tolist(),
            "phi_sd": self.phi_sd.tolist(),
            "members": list(self.members),
            "start_branch": self.start_branch,
            # only when not 0: priors of fleets without it are written as before
            **({"self_heating_c": self.self_heating_c} if self.self_heating_c else {}),
            **({"width_temp_per_c": self.width_temp_per_c} if self.width_temp_per_c else {}),
            **({"die_heating_c": self.die_heating_c} if self.die_heating_c else {}),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Cluster:
        return cls(
            np.asarray(d["mean"], float),
            np.asarray(d["cov"], float),
            np.asarray(d["phi_mean"], float),
            np.asarray(d["phi_sd"], float),
            list(d["members"]),
            float(d.get("start_branch", 0.0)),  # priors written before s₀ was carried
            float(d.get("self_heating_c", 0.0)),
            float(d.get("width_temp_per_c", 0.0)),
            float(d.get("die_heating_c", 0.0)),
        )


@dataclass
class FleetPrior:
    """The prior learned from earlier units (module docstring)."""

    basis: Basis
    clusters: list[Cluster]
    skipped: dict[str, str] = field(default_factory=dict)  # unit → why it was not used
    #: the components some unit of the fleet uses (the detector's parameters)
    active: np.ndarray | None = None
    #: per rare term (some units use it, fewer than :data:`RARE` of them): (index in θ,
    #: its prior probability of presence, the slab's sd, the sign every unit that has
    #: it shares: +1 / −1, 0 when their signs differ) — :func:`wanted_terms`
    slabs: list[tuple[int, float, float, int]] = field(default_factory=list)

    def active_mask(self) -> np.ndarray:
        if self.active is None:
            return np.ones(self.basis.size, dtype=bool)
        return np.asarray(self.active, dtype=bool)

    @property
    def units(self) -> list[str]:
        return [m for c in self.clusters for m in c.members]

    def to_dict(self) -> dict[str, Any]:
        return {
            "basis": self.basis.to_dict(),
            "parameters": self.basis.names(),
            "clusters": [c.to_dict() for c in self.clusters],
            "skipped": dict(self.skipped),
            "active": self.active_mask().tolist(),
            "slabs": [list(x) for x in self.slabs],
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> FleetPrior:
        b = d["basis"]
        return cls(
            Basis(float(b["lo"]), float(b["hi"]), int(b["order"])),
            [Cluster.from_dict(c) for c in d["clusters"]],
            dict(d.get("skipped", {})),
            np.asarray(d["active"], dtype=bool) if "active" in d else None,
            # priors written before the rare-term test have no slabs: not tested; before
            # the slab's sign, three numbers: a symmetric slab, as they were tested
            [
                (int(x[0]), float(x[1]), float(x[2]), int(x[3]) if len(x) > 3 else 0)
                for x in d.get("slabs", [])
            ],
        )


def _cluster(
    thetas: np.ndarray,
    phis: np.ndarray,
    names: list[str],
    S: np.ndarray,
    basis: Basis,
    carried: np.ndarray,
) -> Cluster:
    """A cluster's prior: its mean, and the pooled within-cluster covariance ``S`` shrunk
    halfway to its diagonal, floored, and widened by ``1 + 1/n`` (the mean itself is
    estimated from the cluster's ``n`` units: the predictive spread of a new unit), and
    the medians of the members' ``carried`` (s₀, δ, κ, δ_d) rows."""
    n = thetas.shape[0]
    cov = 0.5 * S + 0.5 * np.diag(np.diag(S))
    cov = (1.0 + 1.0 / n) * cov + np.diag((FLOOR_DPS / basis.scale()) ** 2)
    sd = phis.std(axis=0, ddof=1) if n > 1 else np.zeros(3)
    s0, shift, kappa, die = np.median(carried, axis=0)
    return Cluster(
        thetas.mean(axis=0),
        cov,
        phis.mean(axis=0),
        np.maximum(sd, PHI_SD_FLOOR),
        names,
        start_branch=float(s0),
        self_heating_c=float(shift),
        width_temp_per_c=float(kappa),
        die_heating_c=float(die),
    )


def _silhouette(Z: np.ndarray, lab: np.ndarray) -> float:
    D = np.sqrt(((Z[:, None, :] - Z[None, :, :]) ** 2).sum(axis=-1))
    s = []
    for i in range(Z.shape[0]):
        same = (lab == lab[i]) & (np.arange(Z.shape[0]) != i)
        if not same.any():
            s.append(0.0)
            continue
        a = D[i, same].mean()
        b = min(D[i, lab == k].mean() for k in set(lab.tolist()) if k != lab[i])
        s.append((b - a) / max(a, b))
    return float(np.mean(s))


def _kmeans(Z: np.ndarray, k: int, seed: int = 0, restarts: int = 10) -> np.ndarray:
    """Lloyd's k-means, best of ``restarts`` seeded starts (least within-cluster sum)."""
    rng = np.random.default_rng(seed)
    best: tuple[float, np.ndarray] | None = None
    for _ in range(restarts):
        C = Z[rng.choice(Z.shape[0], k, replace=False)]
        for _ in range(100):
            lab = np.argmin(((Z[:, None, :] - C[None]) ** 2).sum(-1), axis=1)
            new = np.array([Z[lab == j].mean(0) if (lab == j).any() else C[j] for j in range(k)])
            if np.allclose(new, C):
                break
            C = new
        w = float(((Z - C[lab]) ** 2).sum())
        if best is None or w < best[0]:
            best = (w, lab)
    assert best is not None
    return best[1]


def _drift_space(thetas: np.ndarray, basis: Basis) -> np.ndarray:
    """Units as what their drift does, in °/s: the polynomial at 11 temperatures across
    the range and each term at its regressor's largest value (the space the clusters of
    thermal profiles are found in)."""
    P = basis.order + 1
    V = legendre.legvander(np.linspace(-1.0, 1.0, 11), basis.order)
    return np.hstack([thetas[:, :P] @ V.T, thetas[:, P:] * basis.scale()[P:]])


def learn_prior(units: list[UnitEntry], skipped: dict[str, str] | None = None) -> FleetPrior:
    """The fleet prior of ``units`` (module docstring): at least 2 units."""
    if len(units) < 2:
        raise ValueError(
            f"a fleet prior needs at least 2 units with a structured model, not {len(units)}"
        )
    lo = min(u.model.lo for u in units)
    hi = max(u.model.hi for u in units)
    basis = Basis(lo, hi, min(max(u.model.order for u in units), MAX_ORDER))
    thetas = np.array([unit_vector(u.model, basis) for u in units])
    phis = np.array([phi_of(u.params) for u in units])
    # s₀, δ, κ and δ_d, carried beside φ (module docstring)
    carried = np.array(
        [
            (p.start_branch, p.self_heating_c, p.width_temp_per_c, p.die_heating_c)
            for p in (u.params for u in units)
        ]
    )
    names = [u.name for u in units]
    labels = np.zeros(len(units), dtype=int)
    Z = _drift_space(thetas, basis)
    best = SILHOUETTE_MIN
    for k in (2, 3):
        if len(units) < k * MIN_CLUSTER:
            break
        lab = _kmeans(Z, k)
        if np.bincount(lab, minlength=k).min() < MIN_CLUSTER:
            continue
        s = _silhouette(Z, lab)
        if s >= best:
            best, labels = s, lab
    k = int(labels.max()) + 1
    # one within-cluster covariance for all clusters (they differ in their means)
    dev = thetas - np.array([thetas[labels == j].mean(axis=0) for j in range(k)])[labels]
    S = dev.T @ dev / max(len(units) - k, 1)
    clusters = [
        _cluster(
            thetas[labels == j],
            phis[labels == j],
            [n for n, lab in zip(names, labels, strict=True) if lab == j],
            S,
            basis,
            carried[labels == j],
        )
        for j in range(k)
    ]
    active = np.any(thetas != 0.0, axis=0)
    P = basis.order + 1
    slabs = []
    for j in range(P, basis.size):
        on = thetas[:, j] != 0.0
        if 0 < on.sum() < RARE * len(units):
            rms = float(np.sqrt(np.mean(thetas[on, j] ** 2)))
            sign = np.sign(thetas[on, j])
            slabs.append(
                (
                    j,
                    (on.sum() + 1.0) / (len(units) + 2.0),
                    SLAB_WIDEN * rms,
                    int(sign[0]) if np.all(sign == sign[0]) else 0,
                )
            )
    return FleetPrior(basis, clusters, dict(skipped or {}), active, slabs)


# ----------------------------------------------------------------------------- MAP fit


@dataclass
class Membership:
    """Whether a unit belongs to the prior (module docstring)."""

    cluster: int
    d2: float  # Mahalanobis distance² of the unit's own estimate from the cluster's mean
    dof: int
    p_value: float
    belongs: bool
    d2_all: list[float]
    #: rare terms the run wants (:func:`wanted_terms`): name → log posterior odds
    wanted: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "cluster": self.cluster,
            "mahalanobis_d2": self.d2,
            "dof": self.dof,
            "p_value": self.p_value,
            "belongs": self.belongs,
            "d2_per_cluster": self.d2_all,
            "threshold_p": P_OUT,
            "wanted_terms": dict(self.wanted),
        }

    def message(self) -> str:
        if self.wanted:
            terms = ", ".join(f"{k} (log odds {v:.2g})" for k, v in self.wanted.items())
            return (
                f"the unit's run wants terms most of the fleet lacks: {terms}; the fleet "
                "prior would shrink them away: calibrate it on the full profile "
                "(--profile paper, 13 h)"
            )
        return (
            f"the unit does not belong to the fleet prior (Mahalanobis d² = {self.d2:.1f} on "
            f"{self.dof} parameters, p = {self.p_value:.1e} < {P_OUT:g}; another part number "
            "or a defective unit?): calibrate it on the full profile (--profile paper, 13 h)"
        )


def _posterior(
    A: np.ndarray, y: np.ndarray, s2: float, mean: np.ndarray, cov: np.ndarray
) -> tuple[np.ndarray, float, np.ndarray]:
    """The MAP θ on design ``A`` under the prior N(mean, cov) at noise variance ``s2``, its
    criterion ``J = |y − Aθ|²/s² + (θ − mean)ᵀ cov⁻¹ (θ − mean)`` and the posterior
    precision ``H = AᵀA/s² + cov⁻¹``."""
    P = np.linalg.inv(cov)
    H = A.T @ A / s2 + P
    theta = np.linalg.solve(H, A.T @ y / s2 + P @ mean)
    r = y - A @ theta
    d = theta - mean
    return theta, float(r @ r / s2 + d @ P @ d), H


def _map(A: np.ndarray, y: np.ndarray, s2: float, c: Cluster) -> tuple[np.ndarray, float]:
    """θ of least J for fixed φ and its J without the φ term."""
    theta, J, _ = _posterior(A, y, s2, c.mean, c.cov)
    return theta, J


def log_evidence(
    A: np.ndarray, y: np.ndarray, s2: float, mean: np.ndarray, cov: np.ndarray
) -> float:
    """The log marginal likelihood of the run under the prior N(mean, cov), up to a
    constant common to every prior: ``y ~ N(A μ, s² I + A Σ Aᵀ)``, by Woodbury

        ln p(y) = −½ (J_min + ln det Σ + ln det H) + const,   H = AᵀA / s² + Σ⁻¹

    (J_min the MAP criterion's least value; Bishop 2006, §3.5.1)."""
    return _evidence_posterior(A, y, s2, mean, cov)[0]


def _evidence_posterior(
    A: np.ndarray, y: np.ndarray, s2: float, mean: np.ndarray, cov: np.ndarray
) -> tuple[float, np.ndarray, np.ndarray]:
    """:func:`log_evidence`, the posterior mean of θ and its precision ``H``."""
    theta, J, H = _posterior(A, y, s2, mean, cov)
    return -0.5 * (J + np.linalg.slogdet(cov)[1] + np.linalg.slogdet(H)[1]), theta, H


def wanted_terms(
    A: np.ndarray,
    y: np.ndarray,
    s2: float,
    c: Cluster,
    slabs: list[tuple[int, float, float, int]],
) -> dict[int, float]:
    """The rare terms the run's data wants: a spike-and-slab test per term fewer than
    :data:`RARE` of the fleet use. Their Gaussian prior is the fleet's compromise — with
    10 of 11 units at 0 a near-zero variance that crushes a unit whose run shows the term
    (break unit 4's warm-up: 8.3 prior sd out, the MAP shrank it to an eighth, and the
    Mahalanobis detector, over the directions the run informs, did not see it). For each
    such term j, the log posterior odds of *present* — the term's prior replaced by its
    slab ``N(0, sd²)`` (``sd``: :data:`SLAB_WIDEN` × the RMS of the fleet's nonzero
    values, uncorrelated with the rest) — against the cluster's prior:

        ln O_j = ln p(y | slab_j) − ln p(y | prior) + ln(π_j / (1 − π_j))

    (:func:`log_evidence`: the marginal likelihood pays for the slab's width;
    π_j = (n_on + 1)/(n + 2) the fleet's rate of the term). When every fleet unit that
    has the term has it with one sign, the slab is the half-normal on that side
    (``2 N(0, sd²)`` on ``sign·θ_j > 0``; evidence ``2 p(y | slab) P(sign·θ_j > 0 | y,
    slab)``, the posterior under the full slab Gaussian): a run that wants the term with
    the opposite sign wants something else the term's shape absorbs (break unit 11's
    quick run: −3.9e-3 °/s against the fleet's +6e-4 and +1.9e-3; its 13 h model has no
    warm-up), not the fleet's term. Returns ``{j: ln O_j}`` of
    the terms with ``ln O_j > 0``: the run says the unit has a term its prior says it
    lacks, so the prior cannot be trusted for it (releasing the term instead was tried:
    docs/results.md, "Chamber time")."""
    base = log_evidence(A, y, s2, c.mean, c.cov)
    out = {}
    for j, frac, sd, sign in slabs:
        mean, cov = c.mean.copy(), c.cov.copy()
        mean[j] = 0.0
        cov[j, :] = 0.0
        cov[:, j] = 0.0
        cov[j, j] = sd**2
        ev, theta, H = _evidence_posterior(A, y, s2, mean, cov)
        lo = ev - base + math.log(frac / (1.0 - frac))
        if sign:
            # the half-normal slab on the fleet's side: 2 N(0, sd²) on sign·θ_j > 0 has
            # the evidence 2 p(y | slab) P(sign·θ_j > 0 | y, slab) — the posterior
            # under the full slab is Gaussian
            z = sign * theta[j] / math.sqrt(np.linalg.inv(H)[j, j])
            lo += math.log(2.0) + float(stats.norm.logcdf(z))
        if lo > 0.0:
            out[j] = lo
    return out


def _noise_scale(A: np.ndarray, y: np.ndarray, c: Cluster, neff: bool = True) -> float:
    """s² = σ² n / n_eff of the residual of a first MAP fit at s² = its OLS residual
    (``neff=False``: σ², the residual taken as independent)."""

    def inflate(r: np.ndarray) -> float:
        return r.size / max(effective_samples(r), 1.0) if neff else 1.0

    theta = np.linalg.lstsq(A, y, rcond=None)[0]
    r = y - A @ theta
    s2 = float(r @ r) / max(r.size - A.shape[1], 1) * inflate(r)
    theta, _ = _map(A, y, s2, c)
    r = y - A @ theta
    return float(r @ r) / r.size * inflate(r)


def own_covariance(A: np.ndarray, y: np.ndarray, blocks: int = JACKKNIFE_BLOCKS) -> np.ndarray:
    """The covariance of the unit's own least-squares estimate on design ``A``, by the
    delete-a-block jackknife over ``blocks`` contiguous stretches of the run
    (:func:`gyrolab.numerics.jackknife.jackknife_covariance`; Künsch 1989; Efron & Stein
    1981):

        C = (m − 1)/m Σ_k (θ̂₋ₖ − θ̄)(θ̂₋ₖ − θ̄)ᵀ

    — unlike ``s² (AᵀA)⁻¹`` it holds the flicker's correlation and the model's misfit,
    and a direction only one excursion of the run shows gets the spread that excursion
    leaves (on the suites' quick runs a median 2.9× the white-noise trace)."""
    n = y.size
    m = min(blocks, n)
    blk = np.minimum((np.arange(n) * m) // n, m - 1)
    th = np.array([np.linalg.lstsq(A[blk != k], y[blk != k], rcond=None)[0] for k in range(m)])
    return jackknife_covariance(th)


def informative_distance(d: np.ndarray, S: np.ndarray, C: np.ndarray) -> tuple[float, int]:
    """``d² = Σ_j z_j² / (1 + γ_j)`` over the directions where the run is informative:
    ``S^{-1/2} C S^{-1/2} = U diag(γ) Uᵀ``, ``z = Uᵀ S^{-1/2} d``, kept where the run's
    variance is below the prior's (γ_j < 1 / :data:`INFORMATIVE`); the number kept is
    the degrees of freedom. Under the prior ``z_j ~ N(0, 1 + γ_j)``; the directions
    left out are those the run leaves to the prior, where ``d`` is mostly the run's own
    extrapolation (testing them added noise, not power)."""
    L = np.linalg.cholesky(S)
    Li = np.linalg.inv(L)
    g, U = np.linalg.eigh(Li @ C @ Li.T)
    keep = g < 1.0 / INFORMATIVE
    z = U[:, keep].T @ (Li @ d)
    return float(np.sum(z**2 / (1.0 + g[keep]))), int(keep.sum())


def membership(A: np.ndarray, y: np.ndarray, prior: FleetPrior) -> Membership:
    """The unit's own estimate on design ``A`` against every cluster (module docstring),
    on the components some unit of the fleet uses (a term no unit has is left out: on a
    short run its estimate is only the collinearity of the rate terms), its covariance
    by the jackknife (:func:`own_covariance`), the distance over the directions the run
    informs (:func:`informative_distance`)."""
    act = prior.active_mask()
    Aa = A[:, act]
    own = np.linalg.lstsq(Aa, y, rcond=None)[0]
    C = own_covariance(Aa, y)
    got = [
        informative_distance(own - c.mean[act], c.cov[np.ix_(act, act)], C)
        for c in prior.clusters
    ]
    p_all = [float(stats.chi2.sf(d2, dof)) if dof else 1.0 for d2, dof in got]
    j = int(np.argmax(p_all))
    return Membership(j, got[j][0], got[j][1], p_all[j], p_all[j] >= P_OUT, [g[0] for g in got])


@dataclass
class PriorFit:
    """A unit fitted with the prior: the causal model, whether it belongs, the fit log."""

    model: StructuredCausalModel
    membership: Membership
    log: dict[str, Any]


def fit_map(cal: CausalCalibration, prior: FleetPrior, *, neff: bool = True) -> PriorFit:
    """The MAP (shrinkage) fit of a unit's run towards the prior (module docstring);
    the causal model is a ``structured`` one on the reference basis, its CV RMSE and band
    measured by the same blocked CV as the selection's."""
    y = np.asarray(cal.rate, dtype=float)
    b = prior.basis
    # φ by the blocked CV of the MAP fit (the selection's folds): what predicts the run's
    # held-out stretches, not what makes θ look typical (choosing φ by the whole J bent a
    # validation unit's lag to 2080 s for a true 1176 s; by the least-squares residual on
    # the fleet's flexible basis, the same)
    folds = blocked_folds(y.size, CV_FOLDS, CV_SEGMENTS)

    def cv_rmse(A: np.ndarray, s2: float, c: Cluster, pred: np.ndarray | None = None) -> float:
        sq = 0.0
        for held in folds:
            th, _ = _map(A[~held], y[~held], s2, c)
            p = A[held] @ th
            if pred is not None:
                pred[held] = p
            sq += float(np.sum((p - y[held]) ** 2))
        return math.sqrt(sq / y.size)

    def search(p0: CausalParams, grid: bool) -> tuple[float, CausalParams, float, Cluster]:
        """From ``p0``: the noise scale and the cluster there, then (``grid``) φ on the
        grid around the cluster's mean, on its start branch; the CV RMSE, the feature
        parameters, s², the cluster."""
        A0 = b.design(block_features(cal, p0))
        s2 = _noise_scale(A0, y, prior.clusters[0], neff)
        c = prior.clusters[membership(A0, y, prior).cluster]
        if not grid:
            return cv_rmse(A0, s2, c), p0, s2, c
        best: tuple[float, np.ndarray] | None = None
        for i in (0, 1, 2, 0):  # φ components one at a time, around the prior mean
            phi_c = c.phi_mean.copy() if best is None else best[1].copy()
            for step in PHI_STEPS:
                phi = phi_c.copy()
                phi[i] = c.phi_mean[i] + step * c.phi_sd[i]
                e = cv_rmse(b.design(block_features(cal, c.params(phi))), s2, c)
                if best is None or e < best[0]:
                    best = (e, phi)
        assert best is not None
        return best[0], c.params(best[1]), s2, c

    # the grid search is local (one component at a time, around the prior mean) and misses
    # a unit whose lag or warm-up lies elsewhere: the φ (and start branch) the unit's own
    # causal selection (no prior, OWN_FAMILIES) chooses on the run competes on the same CV,
    # with the noise scale and cluster there (a misfit φ inflates s² and hands the fit to
    # the prior)
    starts = {
        "prior": search(prior.clusters[0].params(), True),
        "own": search(fit_causal(cal, families=OWN_FAMILIES).params, False),
    }
    start = min(starts, key=lambda k: starts[k][0])  # a tie: the prior's
    _, params, s2, c = starts[start]
    A = b.design(block_features(cal, params))
    theta, _ = _map(A, y, s2, c)
    # the unit's membership at its own φ (the detector's number)
    mem = membership(A, y, prior)
    wanted = wanted_terms(A, y, s2, c, prior.slabs)
    if wanted:
        mem.wanted = {b.names()[j]: v for j, v in wanted.items()}
        mem.belongs = False
    pred = np.empty_like(y)
    cv = cv_rmse(A, s2, c, pred)
    r = y - A @ theta
    log = {
        "method": "MAP towards the fleet prior (gyrolab/compensation/prior.py)",
        "prior_units": len(prior.units),
        "cluster": mem.cluster,
        "cluster_units": len(c.members),
        "membership": mem.to_dict(),
        "features": params.to_dict(),
        "features_from": start,
        "cv_rmse_by_start": {k: v[0] for k, v in starts.items()},
        "noise_s2": s2,
        "rms_residual_deg_per_s": float(np.sqrt(np.mean(r * r))),
        "hysteresis_width": hysteresis_width(b.model(theta)),
    }
    model = StructuredCausalModel(
        family="structured",
        params=params,
        model=b.model(theta),
        cv_rmse={"structured": cv},
        selection={"winner": "structured", "prior": log},
        band=fit_band(cal.t, y, pred, folds, cal.pt_t, cal.pt_c, power_ons=tuple(cal.power_ons)),
    )
    return PriorFit(model, mem, log)


def structured_of(causal: Any) -> tuple[CausalParams, StructuredModel] | None:
    """The feature parameters and structured model of a causal model, or ``None`` when
    it is a network (the prior is over the structured family's parameters)."""
    m = getattr(causal, "model", None)
    if isinstance(m, StructuredModel):
        return causal.params, m
    return None


__all__ = [
    "Basis",
    "Cluster",
    "FleetPrior",
    "Membership",
    "PriorFit",
    "UnitEntry",
    "fit_map",
    "learn_prior",
    "membership",
    "structured_of",
    "unit_vector",
]
