"""The drift-model interface: what every drift-model family implements.

A *drift model* turns the temperature readings of a run into the gyro's drift ``d(t)``
(°/s) at any sample time ``t``, using readings at or before ``t`` only (causal), so that
``raw(t) − d(t)`` can run on a live stream, offline over a file, and in firmware. A
*family* is a way to fit one (poly, structured, BP, GA-BP, ...): it is registered in
:mod:`gyrolab.compensation.families` and everything else — the causal selection,
``compensate``, ``apply``, the model directory, ``export --format json|c`` — reaches it
through this interface only (docs/compensation.md, "Adding a drift-model family").

What a family provides (:class:`DriftModel`, :class:`Family`, :class:`SpecKind`):

* **fit** — ``Family.fit(ctx)`` on a calibration run (:class:`FitContext`: 3.6 s block
  means of the raw rate, the PT100 readings, the blocked CV folds, the seed, the network
  settings) → :class:`Candidate`: the model refitted on the whole run and its blocked-CV
  RMSE (the selection of :mod:`gyrolab.compensation.causal` compares these);
* **predict causally, sample by sample** — ``start()`` → state, ``reading(state, t, T)``
  for every temperature reading in time order, ``sample(state, t)`` for every gyro sample
  (at or after the last reading pushed): what firmware runs;
* **predict vectorised** — ``drift_at(t, pt_t, pt_c)`` over whole arrays, bit for bit the
  numbers of the sample-by-sample form (:func:`drift_sample_by_sample` runs the latter;
  the tests compare them); ``reading_drift(pt_t, pt_c)`` for models whose drift changes
  at readings only (held in between), ``None`` otherwise;
* **state** — the numbers ``start``/``reading`` carry (a family's own type);
* **save / load** — ``save(prefix)`` → JSON metadata and arrays (model.json, arrays.npz;
  the arrays' names start with ``prefix``), ``Family.load(meta, arrays, prefix)`` back;
  ``describe()`` the JSON summary that metrics.json shows; ``torch_state()`` a network's
  weights as a torch state dict (``None`` otherwise);
* **firmware spec** — ``spec()`` → the ``MODEL`` entry of ``gyrolab export --format
  json`` (a dict with a ``kind``), or :class:`NotExportable` saying why not;
* **C code** — ``SpecKind.c_model(spec, prefix)`` → :class:`CModel`, the C99 float32
  pieces that :mod:`gyrolab.export.c_code` assembles, and ``SpecKind.evaluate(spec, t,
  pt_t, pt_c)``, the JSON's reference evaluation (float64, independent of the fitting
  code; the export tests compare it with the model and with the compiled C).

Samples before the first reading get the first reading's drift in the vectorised form
(:func:`~gyrolab.compensation.causal_features.hold`); a stream starts with a reading.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gyrolab.compensation.causal_features import hold

#: A candidate must beat every simpler one by this fraction of its CV RMSE to be chosen
#: (the causal selection; the structured model's terms follow the same rule).
TIE = 0.01


class NotExportable(ValueError):
    """A drift model that has no firmware form (``spec()``); the message says why."""


@dataclass
class DriftModel(ABC):
    """A fitted drift model (module docstring). Subclasses are dataclasses that set
    ``family`` — the registered name, a class attribute or (for a class that serves
    several families) a field — and implement the abstract methods.

    ``cv_rmse``, ``selection``, ``band`` and ``alternatives`` are the causal selection's
    record of how this model was chosen (:func:`gyrolab.compensation.causal.fit_causal`):
    every candidate family's CV RMSE (°/s), the selection log, the winner's 90 %
    prediction band (:class:`~gyrolab.compensation.band.PredictionBand`, from its held-out
    CV predictions; ``None`` without them or for a model written before), and the other
    fitted candidates (not saved)."""

    cv_rmse: dict[str, float] = field(default_factory=dict, kw_only=True, repr=False)
    selection: dict[str, Any] = field(default_factory=dict, kw_only=True, repr=False)
    band: Any = field(default=None, kw_only=True, repr=False)
    alternatives: dict[str, DriftModel] = field(
        default_factory=dict, kw_only=True, repr=False, compare=False
    )

    # -- causal, one reading and one sample at a time (what firmware runs)
    @abstractmethod
    def start(self) -> Any:
        """The state before the first reading."""

    @abstractmethod
    def reading(self, state: Any, t_s: float, temp_c: float) -> None:
        """Take one temperature reading (°C) at time ``t_s`` (s since power-on), in time
        order, updating ``state`` in place."""

    @abstractmethod
    def sample(self, state: Any, t_s: float) -> float:
        """The drift (°/s) at a sample time ``t_s`` at or after the last reading taken."""

    # -- vectorised, bit for bit the same numbers
    def reading_drift(self, pt_t: np.ndarray, pt_c: np.ndarray) -> np.ndarray | None:
        """The drift at every reading when it changes only there (held until the next
        reading); ``None`` for a model whose drift changes between readings."""
        return None

    def drift_at(self, t: np.ndarray, pt_t: np.ndarray, pt_c: np.ndarray) -> np.ndarray:
        """The drift (°/s) at sample times ``t`` from readings ``pt_t`` (s, increasing),
        ``pt_c`` (°C). The default holds :meth:`reading_drift`; a model whose drift
        changes between readings overrides it."""
        d = self.reading_drift(pt_t, pt_c)
        if d is None:
            raise NotImplementedError(f"{type(self).__name__} must implement drift_at")
        return hold(np.asarray(t, dtype=float), pt_t, d)

    # -- persistence
    def parameters(self) -> dict[str, Any]:
        """The parameters that fit in JSON (the default :meth:`describe` shows them)."""
        return {}

    def describe(self) -> dict[str, Any]:
        """The JSON summary of the fitted model and how it was chosen (metrics.json
        ``causal_model``; model.json holds it with :meth:`save`'s metadata)."""
        return {
            "family": self.family,
            **self.parameters(),
            "cv_rmse_deg_per_s": self.cv_rmse,
            "selection": self.selection,
            **self.band_entry(),
        }

    def band_entry(self) -> dict[str, Any]:
        """``{"band": ...}`` of :meth:`describe` (empty without a band)."""
        return {} if self.band is None else {"band": self.band.to_dict()}

    def band_at(
        self, t: np.ndarray, pt_t: np.ndarray, pt_c: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The 90 % band ``(lo, hi)`` (°/s) of the compensated output's 100 s means at
        times ``t`` (:mod:`gyrolab.compensation.band`); raises for a model without one."""
        if self.band is None:
            raise ValueError("this causal model has no prediction band")
        h = self.band.half_width_at(t, pt_t, pt_c)
        return -h, h

    def save(self, prefix: str) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """What model.json needs beyond :meth:`describe` to load the model again, and the
        arrays (names starting with ``prefix``) for arrays.npz."""
        return {}, {}

    def torch_state(self) -> dict[str, Any] | None:
        """A network's weights as a torch state dict (``*.pt`` in the model directory)."""
        return None

    # -- firmware
    def spec(self) -> dict[str, Any]:
        """The ``MODEL`` entry of the JSON export (a dict with ``kind``)."""
        raise NotExportable(f"the {self.family} drift model has no firmware form")


def drift_sample_by_sample(
    model: DriftModel, t: np.ndarray, pt_t: np.ndarray, pt_c: np.ndarray
) -> np.ndarray:
    """The drift at sample times ``t`` computed the way firmware does: readings taken
    one at a time in time order, each sample evaluated after every reading at or before
    it (the first reading before any sample: a stream starts with a reading). Equal,
    bit for bit, to ``model.drift_at(t, pt_t, pt_c)``."""
    t = np.asarray(t, dtype=float)
    out = np.empty(t.size)
    state = model.start()
    n = 0
    for i, ts in enumerate(t):
        while n < len(pt_t) and (n == 0 or pt_t[n] <= ts):
            model.reading(state, float(pt_t[n]), float(pt_c[n]))
            n += 1
        out[i] = model.sample(state, float(ts))
    return out


# --------------------------------------------------------------------------- fitting


@dataclass
class CausalCalibration:
    """What a family is fitted on: a calibration run's 3.6 s block means of the raw
    rate at the block centres, and its PT100 readings; ``power_ons``: the times (s) of
    later power-ons where the calibration is several runs, or a run with a power cycle,
    on one time axis (the features start again at rest at each:
    :func:`~gyrolab.compensation.causal_features.reading_features`)."""

    t: np.ndarray  # block centres, s
    rate: np.ndarray  # 3.6 s block means of the raw rate, °/s
    pt_t: np.ndarray  # PT100 reading times, s
    pt_c: np.ndarray  # PT100 readings, °C
    power_ons: tuple[float, ...] = ()  # later power-ons, s (the first is t = 0)


#: The gap (s) :func:`join_calibrations` leaves between one power-on's run and the next:
#: the features start again at rest at a power-on, so its length changes nothing as long
#: as no reading of one run falls inside the next.
POWER_CYCLE_GAP_S = 1.0e6


def join_calibrations(parts: Sequence[CausalCalibration]) -> CausalCalibration:
    """Several calibrations of one unit, each from its own power-on at its ``t = 0``
    (e.g. ``compensate RUN --also COLD``: the main run and a cold start), as one: each
    later part shifted to start :data:`POWER_CYCLE_GAP_S` after the one before it ends
    (its last block centre or reading), every part's start a power-on of ``power_ons``.
    A part's own later ``power_ons`` are kept, shifted with it."""
    if not parts:
        raise ValueError("no calibration to join")
    ts, ys, pts, pcs, ons, off = [], [], [], [], [], 0.0
    for i, c in enumerate(parts):
        ts.append(np.asarray(c.t, dtype=float) + off)
        ys.append(np.asarray(c.rate, dtype=float))
        pts.append(np.asarray(c.pt_t, dtype=float) + off)
        pcs.append(np.asarray(c.pt_c, dtype=float))
        ons.extend(([off] if i else []) + [p + off for p in c.power_ons])
        off += max(float(c.t[-1]), float(c.pt_t[-1])) + POWER_CYCLE_GAP_S
    cat = np.concatenate
    return CausalCalibration(
        t=cat(ts), rate=cat(ys), pt_t=cat(pts), pt_c=cat(pcs), power_ons=tuple(ons)
    )


@dataclass
class Candidate:
    """A family fitted on the whole calibration run: the model, its blocked-CV RMSE
    (°/s, held-out 3.6 s block means), what model.json's ``selection`` records of it
    (``None``: nothing), and its held-out prediction of every block (the CV's; the
    winner's prediction band is measured on them — ``None``: no band)."""

    model: DriftModel
    cv_rmse: float
    log: dict[str, Any] | None = None
    cv_pred: np.ndarray | None = None


@dataclass
class FitContext:
    """Everything a family's fit may use: the calibration run, the blocked CV folds in
    time (boolean held-out masks over the blocks), the seed and the pipeline settings
    (:class:`~gyrolab.compensation.config.PipelineConfig`: ``bp()``, ``ga()``, ...), and a
    cache shared by the families of one selection (:meth:`shared`)."""

    cal: CausalCalibration
    folds: list[np.ndarray]
    seed: int = 0
    config: Any = None
    cache: dict[str, Any] = field(default_factory=dict)

    def shared(self, key: str, make: Callable[[], Any]) -> Any:
        """``make()`` once per selection (e.g. the structured model's feature parameters,
        which the network families reuse)."""
        if key not in self.cache:
            self.cache[key] = make()
        return self.cache[key]

    def cross_validate(self, fit: Callable[[np.ndarray], DriftModel]) -> tuple[float, np.ndarray]:
        """Blocked CV of a family: ``fit(train)`` (a boolean mask over the blocks) fitted
        on each fold's training blocks, its :meth:`DriftModel.drift_at` at the held-out
        block centres against their block means → ``(RMSE °/s, the held-out prediction
        of every block)``. Not for a calibration with later ``power_ons``:
        :meth:`DriftModel.drift_at` knows one power-on (a family there predicts from
        its own block features, :func:`~gyrolab.compensation.structured.block_features`)."""
        cal = self.cal
        if cal.power_ons:
            raise ValueError(
                "cross_validate predicts through drift_at, which knows one power-on; this "
                "calibration has later power-ons"
            )
        pred = np.empty(cal.t.size)
        for held in self.folds:
            pred[held] = fit(~held).drift_at(cal.t[held], cal.pt_t, cal.pt_c)
        r = pred - cal.rate
        return float(np.sqrt(float(r @ r) / r.size)), pred


@dataclass(frozen=True)
class Family:
    """A registered drift-model family (:mod:`gyrolab.compensation.families`).

    ``fit(ctx)`` → :class:`Candidate`; ``load(meta, arrays, prefix)`` → the model from
    what :meth:`DriftModel.describe` and :meth:`DriftModel.save` wrote; ``rank``: the
    order of simplicity (a candidate must beat every simpler one by the selection's tie
    margin)."""

    name: str
    fit: Callable[[FitContext], Candidate]
    load: Callable[[dict[str, Any], dict[str, np.ndarray], str], DriftModel]
    rank: float
    description: str = ""


# ------------------------------------------------------------------------ firmware


@dataclass(frozen=True)
class CModel:
    """One axis's drift model in C99 (float32), the pieces :mod:`gyrolab.export.c_code`
    assembles into ``gyrolab_comp_temperature`` / ``gyrolab_comp_drift``.

    ``code``: file-scope constants and static functions (every name starts with the
    prefix :meth:`SpecKind.c_model` was given; ``clampf(x, lo, hi)`` and ``<math.h>`` are
    available). ``state``: this axis's state members (``"float F"``, ...). ``reading``:
    the body of ``void reading(STATE *st, float T, float dt, double t, int first)``, run
    at every temperature reading (``T`` °C, ``dt`` s since the previous one, 0 at the
    first; ``t`` s since power-on). ``sample``: the body of ``float sample(const STATE
    *st, const float *x, double t_s)`` returning the drift (°/s) at a sample, where ``x``
    holds the held temperature ``T(t)`` and, when ``window_s`` is set, its backward
    difference ``(T(t) − T(t − w)) / w`` (°C/s). ``uses_temperature``: whether ``sample``
    reads ``x``. ``note``: what the model does outside its calibrated range (a line of
    the header)."""

    code: str
    sample: str
    state: tuple[str, ...] = ()
    reading: str = ""
    uses_temperature: bool = False
    window_s: float | None = None
    note: str = ""


@dataclass(frozen=True)
class SpecKind:
    """A ``kind`` of exported ``MODEL``: its reference evaluation ``evaluate(spec, t,
    pt_t, pt_c)`` → drift (°/s, float64) at ``t``, and its C code
    ``c_model(spec, prefix)`` → :class:`CModel`."""

    kind: str
    evaluate: Callable[[dict[str, Any], np.ndarray, np.ndarray, np.ndarray], np.ndarray]
    c_model: Callable[[dict[str, Any], str], CModel]


def c_float(v: float) -> str:
    """A float32 C literal that reads back as ``float32(v)`` (a non-finite constant is a
    :class:`ValueError`)."""
    import math

    if not math.isfinite(v):
        raise ValueError(f"non-finite model constant {v}")
    s = f"{v:.9g}"
    if not any(ch in s for ch in ".en"):
        s += ".0"
    return s + "f"


def c_array(name: str, values: list[float]) -> str:
    """``static const float name[n] = {...};``"""
    body = ", ".join(c_float(v) for v in values)
    return f"static const float {name}[{len(values)}] = {{{body}}};"


__all__ = [
    "CModel",
    "Candidate",
    "CausalCalibration",
    "DriftModel",
    "Family",
    "FitContext",
    "NotExportable",
    "POWER_CYCLE_GAP_S",
    "SpecKind",
    "TIE",
    "c_array",
    "c_float",
    "join_calibrations",
    "drift_sample_by_sample",
]
