"""What ``gyrolab compensate`` computed on each run it evaluated, kept for the report.

``gyrolab report RUN --model MODEL_DIR`` reads these instead of applying the model again
(VMD, MPE, FLP, the causal outputs, the Allan curves), so the report's figures and numbers
are the ones ``compensate`` computed. Two files in the model directory, written and read
by :class:`~gyrolab.compensation.model_dir.ModelDir` (format version 1):

``results.json``
    ``format``, ``format_version``, ``software_version`` and ``runs``: one entry per
    evaluated run, keyed by its role (``calibration``; ``validation`` with
    ``--validate``): ``path``, ``content_hash`` (the run's rate and PT100 data,
    :func:`gyrolab.compensation.guards.content_hash`), ``held_out``, ``block_s``,
    ``classes`` and ``mpe`` of its VMD modes, ``oracle_checked`` (whether the oracle was
    looked for: ``true`` with no ``oracle`` series means the run has none), and ``allan``:
    per series (``raw``, ``compensated``) the noise terms the curve identifies.
``results.npz``
    per run, ``<role>.<name>``: ``t`` and ``temp`` (the 1000 points/h grid, s and °C),
    ``modes`` (K × N, °/s), ``series.<name>`` (°/s at 1000 points/h: ``raw``,
    ``compensated``, ``drift_prediction``, ``causal`` — block means of the causal
    full-rate output of the causal model —, ``baselines.<name>``, ``oracle`` for a
    simulated run) and ``allan.<series>.{tau,adev,lo,hi}`` (octave τ in s, deviation and 1σ
    Greenhall bounds in °/s).

The metrics of each run are those of ``metrics.json`` (the top level for the run
``compensate`` reports on, ``calibration`` for the calibration run of a ``--validate``
fit). A model directory written before these files existed has none:
:meth:`ModelDir.results` returns ``{}`` and the report computes what it needs, saying so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gyrolab.errors import InputError

#: Series of the application kept for the report (the baselines are added by name).
KEPT_SERIES = ("raw", "compensated", "drift_prediction")
#: Series whose Allan curve is kept (``causal``: the causal output, where the model has one).
ALLAN_SERIES = ("raw", "causal", "compensated")


@dataclass
class AllanSummary:
    """One Allan curve (octave τ, 1σ Greenhall bounds) and the ARW / bias instability it
    identifies (IEEE 952 via :func:`gyrolab.numerics.noise_terms.noise_terms`: τ ≤ T/10,
    slopes supported by the confidence intervals, B only at a true floor).

    ``tau`` in s; ``adev``/``lo``/``hi`` in °/s; ``arw`` in °/√h and ``bi`` in °/h
    (``None`` when not identified); ``arw_tau``/``bi_tau`` the τ range (s) each was read
    on; ``tau_b`` the τ (s) of the curve's minimum; ``bi_upper_bound`` (°/h) σ_min/0.664
    when there is no floor."""

    tau: np.ndarray
    adev: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    arw: float | None
    bi: float | None
    arw_tau: tuple[float, float] | None = None
    bi_tau: tuple[float, float] | None = None
    tau_b: float = float("nan")
    bi_upper_bound: float | None = None

    def scalars(self) -> dict[str, Any]:
        return {
            "arw_deg_per_sqrt_h": self.arw,
            "bias_instability_deg_per_h": self.bi,
            "arw_tau_s": None if self.arw_tau is None else list(self.arw_tau),
            "bi_tau_s": None if self.bi_tau is None else list(self.bi_tau),
            "tau_b_s": _num(self.tau_b),
            "bi_upper_bound_deg_per_h": self.bi_upper_bound,
        }

    @classmethod
    def from_parts(cls, s: dict[str, Any], a: dict[str, np.ndarray]) -> AllanSummary:
        def rng(v: Any) -> tuple[float, float] | None:
            return None if v is None else (float(v[0]), float(v[1]))

        tau_b = s.get("tau_b_s")
        return cls(
            tau=a["tau"],
            adev=a["adev"],
            lo=a["lo"],
            hi=a["hi"],
            arw=s.get("arw_deg_per_sqrt_h"),
            bi=s.get("bias_instability_deg_per_h"),
            arw_tau=rng(s.get("arw_tau_s")),
            bi_tau=rng(s.get("bi_tau_s")),
            tau_b=float("nan") if tau_b is None else float(tau_b),
            bi_upper_bound=s.get("bi_upper_bound_deg_per_h"),
        )


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(float(x)) else None


def allan_summary(x: np.ndarray, rate_hz: float) -> AllanSummary | None:
    """:class:`AllanSummary` of the series ``x`` (°/s) sampled at ``rate_hz``; ``None``
    when the series is too short or constant for a curve."""
    from gyrolab.numerics.allan import allan_deviation
    from gyrolab.numerics.noise_terms import noise_terms

    try:
        res = allan_deviation(np.asarray(x, dtype=float), rate_hz, taus="octave")
        nt = noise_terms(res, terms=("N", "B"))
    except InputError:
        return None
    terms = nt.deg_h()
    bi = terms["bias_instability_deg_per_h"]
    ub = nt.upper_bounds.get("B")
    n_rng, b_rng = nt.tau_ranges.get("N"), nt.tau_ranges.get("B")
    return AllanSummary(
        tau=np.asarray(res.taus, dtype=float),
        adev=np.asarray(res.dev, dtype=float),
        lo=np.asarray(res.dev_lo, dtype=float),
        hi=np.asarray(res.dev_hi, dtype=float),
        arw=terms["arw_deg_per_sqrt_h"],
        bi=bi,
        arw_tau=None if n_rng is None else (float(n_rng[0]), float(n_rng[1])),
        bi_tau=None if b_rng is None else (float(b_rng[0]), float(b_rng[1])),
        tau_b=float(nt.tau_b),
        bi_upper_bound=None if ub is None else 3600.0 * float(ub),
    )


@dataclass
class RunResults:
    """The model applied to one run, as ``compensate`` computed it (module docstring)."""

    role: str  # "calibration" | "validation" | "report" (computed by the report)
    path: str
    content_hash: str
    held_out: bool
    block_s: float
    t: np.ndarray  # s, 1000 points/h grid
    temp: np.ndarray  # °C (PT100 interpolated to t)
    modes: np.ndarray  # (K, N) VMD modes of this run, °/s
    mpe: list[float]
    classes: dict[str, list[int]]
    series: dict[str, np.ndarray] = field(default_factory=dict)
    allan: dict[str, AllanSummary] = field(default_factory=dict)
    oracle_checked: bool = False

    @property
    def K(self) -> int:
        return int(self.modes.shape[0])

    def part(self, name: str) -> np.ndarray:
        """Sum of the modes of one class (zeros when the class is empty)."""
        idx = self.classes.get(name, [])
        if not idx:
            return np.zeros(self.modes.shape[1])
        return self.modes[idx].sum(axis=0)


def run_results(role: str, model: Any, app: Any, run: Any, held_out: bool) -> RunResults:
    """What the report needs of one application (``app``, an
    :class:`~gyrolab.compensation.apply.Application` of ``model`` to ``run``, after
    :func:`~gyrolab.compensation.evaluate.evaluate`, which leaves the block means of the
    causal outputs in ``app.series``)."""
    bs = float(model.config.block_s)
    series = {k: np.asarray(app.series[k], float) for k in KEPT_SERIES}
    for k, v in app.series.items():
        if k.startswith("baselines."):
            series[k] = np.asarray(v, float)
    if "stream.causal" in app.series:
        series["causal"] = np.asarray(app.series["stream.causal"], float)
    allan = {}
    for k in (k for k in ALLAN_SERIES if k in series):
        a = allan_summary(series[k], 1.0 / bs)
        if a is not None:
            allan[k] = a
    dec = app.decomposition
    return RunResults(
        role=role,
        path=str(run.name),
        content_hash=str(run.content_hash),
        held_out=bool(held_out),
        block_s=bs,
        t=np.asarray(run.t, float),
        temp=np.asarray(run.temp, float),
        modes=np.asarray(dec.modes, float),
        mpe=[float(v) for v in dec.mpe],
        classes={k: [int(i) for i in v] for k, v in dec.classes.items()},
        series=series,
        allan=allan,
    )


def results_to_parts(runs: list[RunResults]) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """``(runs metadata, arrays)``: results.json's ``runs`` and results.npz's arrays
    (:class:`~gyrolab.compensation.model_dir.ModelDir` writes them)."""
    meta: dict[str, Any] = {}
    arrays: dict[str, np.ndarray] = {}
    for r in runs:
        p = f"{r.role}."
        arrays[p + "t"], arrays[p + "temp"], arrays[p + "modes"] = r.t, r.temp, r.modes
        for k, v in r.series.items():
            arrays[f"{p}series.{k}"] = np.asarray(v, float)
        for k, a in r.allan.items():
            for part in ("tau", "adev", "lo", "hi"):
                arrays[f"{p}allan.{k}.{part}"] = getattr(a, part)
        meta[r.role] = {
            "path": r.path,
            "content_hash": r.content_hash,
            "held_out": r.held_out,
            "block_s": r.block_s,
            "classes": r.classes,
            "mpe": r.mpe,
            "oracle_checked": r.oracle_checked,
            "allan": {k: a.scalars() for k, a in r.allan.items()},
        }
    return meta, arrays


def results_from_parts(
    runs: dict[str, Any], arrays: dict[str, np.ndarray]
) -> dict[str, RunResults]:
    """The results by role from results.json's ``runs`` and results.npz's arrays
    (``KeyError``/``TypeError``/``ValueError`` when they are incomplete)."""
    out: dict[str, RunResults] = {}
    for role, m in runs.items():
        p = f"{role}."
        series = {k[len(p) + 7 :]: v for k, v in arrays.items() if k.startswith(p + "series.")}
        allan = {
            k: AllanSummary.from_parts(
                s, {q: arrays[f"{p}allan.{k}.{q}"] for q in ("tau", "adev", "lo", "hi")}
            )
            for k, s in m.get("allan", {}).items()
        }
        out[role] = RunResults(
            role=role,
            path=str(m["path"]),
            content_hash=str(m["content_hash"]),
            held_out=bool(m["held_out"]),
            block_s=float(m["block_s"]),
            t=arrays[p + "t"],
            temp=arrays[p + "temp"],
            modes=arrays[p + "modes"],
            mpe=[float(v) for v in m["mpe"]],
            classes={k: [int(i) for i in v] for k, v in m["classes"].items()},
            series=series,
            allan=allan,
            oracle_checked=bool(m.get("oracle_checked", False)),
        )
    return out


def keep_oracle(r: RunResults, oracle: np.ndarray | None) -> None:
    """Record that the oracle of ``r``'s run was looked for, and keep it when there is one
    (:func:`gyrolab.compensation.oracle.add_oracle`)."""
    r.oracle_checked = True
    if oracle is not None:
        r.series["oracle"] = np.asarray(oracle, float)
