"""Fit the paper's hybrid compensation model on a calibration run; apply it to any run.

The paper's parallel model (§3.5, Fig. 7), as gyrolab runs it:

1. **Decimate.** The rate is averaged to the paper's 1000 points/h (``block_s`` = 3.6 s:
   ≈ 13 000 points for a 13 h run, the paper's N). The drift model's input at each block
   centre is the last PT100 reading (the same causal rule as the streaming path, see
   :func:`features`). Everything below runs at that rate.
2. **GPSO-VMD** (§3.1–3.2) chooses (K, α) and decomposes the averaged rate into K modes.
3. **MPE** (§3.4, scale 12) classifies the modes: high entropy = *noise*, middle = *mixed*,
   low = *drift* (thresholds of :func:`gyrolab.compensation.mpe.classify_modes`; when no
   mode falls below the drift threshold, the most regular mode is taken as the drift).
4. **Noise** modes are dropped; **mixed** modes are filtered by the forward linear
   predictor (FLP); **drift** modes are summed into the drift target ``d(t)``.
5. **GA-BP** (§3.3) learns ``d ≈ f(T)`` (optionally ``f(T, dT/dt)``) from the PT100
   temperature.
6. Output: ``y = FLP(mixed) + (drift − f(T))`` (the reconstruction of §3.5 step 3).

Applying a fitted model to a **new** run (held out) keeps what was learned — the drift
model ``f``, the decomposition settings (K, α), the class rule and the FLP coefficients
fitted on the calibration run's mixed modes — and re-runs the signal processing on the new
run's own samples: VMD with the stored (K, α), MPE classes by the same rule, the stored FLP
on its mixed modes. The temperature drift removed is always ``f(T_new(t))``: never
refitted on held-out data.

Two outputs come from every application:

* **offline** (the paper's method, above) at 1000 points/h — it low-passes the signal
  (noise modes dropped), so its ARW is *not* the sensor's noise density: the metrics say
  which bandwidth it leaves (:func:`effective_bandwidth`);
* **streaming** (causal, full rate): ``y(t) = raw(t) − f(T(t⁻))`` where ``T(t⁻)`` is the
  last PT100 reading at or before ``t`` (zero-order hold) and dT/dt a backward
  difference — no future sample is used, so it can run on a live stream. It keeps the
  sensor's full bandwidth; ``gyrolab apply`` writes it as ``/gyro/rate``.

Baselines, fitted on the same calibration run and applied the same causal way:
``poly`` (polynomial in T, order by blocked CV) and ``bp`` (plain BP, random initial
weights), both fitted directly on the averaged raw output (the classical approach, no
decomposition). ``compensated_drift_only`` is the paper's GA-BP drift model applied the
same way (no noise removal): the like-for-like comparison with the baselines.
``baselines_with_noise_removal`` puts each baseline drift model behind the paper's noise
removal instead of GA-BP: the like-for-like comparison with the paper's full method.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from gyrolab.compensation.baselines import PolyDriftModel, fit_plain_bp, fit_poly
from gyrolab.compensation.causal import CausalCalibration, CausalDriftModel, fit_causal
from gyrolab.compensation.gabp import BPConfig, GAConfig, MLPDriftModel, fit_gabp
from gyrolab.compensation.guards import RunHasher, calibration_ranges, content_hash, range_check
from gyrolab.errors import InputError
from gyrolab.record.recording import Recording

PAPER_BLOCK_S = 3.6  # 1000 points/h (paper §4.1)


@dataclass(frozen=True)
class PipelineConfig:
    """Settings of the hybrid model; defaults follow the paper where it says."""

    block_s: float = PAPER_BLOCK_S
    use_dtdt: bool = False  # paper: temperature only
    dtdt_window_s: float = 300.0
    hidden: int = 8
    drift_model: str = "gabp"  # the drift model f(T): "gabp" (paper), "bp", "poly"
    ga_population: int = 40
    ga_generations: int = 40
    bp_optimizer: str = "lbfgs"  # "lbfgs" or the paper's plain gradient descent "gd"
    bp_max_iter: int = 400
    bp_learning_rate: float = 0.01  # gd only (paper prints none: traingd's default)
    bp_epochs: int = 1000  # gd only
    vmd_fitness: str = "drift_separation"  # GPSO criterion, fitness.CRITERIA
    k_range: tuple[int, int] = (3, 11)  # paper §4.2
    alpha_range: tuple[float, float] = (50.0, 5000.0)  # paper §4.2
    gpso_population: int = 50  # paper §4.2
    gpso_generations: int = 30
    mpe_scale: int = 12  # paper §4.2
    mpe_order: int = 4
    mpe_delay: int = 1
    mpe_noise_min: float = 0.85  # mpe.DEFAULT_NOISE_MIN
    mpe_drift_max: float = 0.5  # mpe.DEFAULT_DRIFT_MAX
    vmd_K: int | None = None  # fixed (K, alpha): skip the GPSO search
    vmd_alpha: float | None = None
    flp_max_order: int = 32
    flp_criterion: str = "aic"
    min_blocks: int = 256
    min_temp_span_c: float = 2.0
    baselines: tuple[str, ...] = ("poly", "bp")
    # causal drift-model families compared by CV inside the calibration run (causal.py)
    causal_families: tuple[str, ...] = ("poly", "structured", "bp", "gabp")

    def ga(self) -> GAConfig:
        return GAConfig(population=self.ga_population, generations=self.ga_generations)

    def bp(self) -> BPConfig:
        return BPConfig(
            hidden=self.hidden,
            max_iter=self.bp_max_iter,
            optimizer=self.bp_optimizer,
            learning_rate=self.bp_learning_rate,
            epochs=self.bp_epochs,
        )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PipelineConfig:
        known = {k: v for k, v in d.items() if k in cls.__dataclass_fields__}
        for k in ("k_range", "alpha_range", "baselines", "causal_families"):
            if k in known:
                known[k] = tuple(known[k])
        return cls(**known)


DEFAULT_CONFIG = PipelineConfig()  # what `gyrolab compensate` uses (tests swap in a small one)

# ------------------------------------------------------------------ run preparation


@dataclass
class PreparedRun:
    """A run reduced to what the model needs.

    ``t``/``rate``/``temp``/``X``: the 1000 points/h series (s, °/s, °C, features);
    ``raw_t``/``raw_rate``: full-rate samples; ``pt_t``/``pt_c``: PT100 readings."""

    path: str
    t: np.ndarray
    rate: np.ndarray
    temp: np.ndarray
    X: np.ndarray
    raw_t: np.ndarray | None  # None when prepared from the file by streaming
    raw_rate: np.ndarray | None
    raw_period: float
    pt_t: np.ndarray
    pt_c: np.ndarray
    filled_blocks: int = 0
    content_hash: str = ""  # guards.RunHasher digest of the rate and PT100 data
    unit: str | None = None  # the unit of a multi-unit recording (docs/fleet.md)


class BlockAverager:
    """Streaming 3.6 s block means: feed sample blocks in time order with :meth:`add`,
    read the result with :meth:`result`. Memory is that of the averaged series, so a
    47 M-sample run is decimated without holding its samples. Also counts non-finite
    samples and tracks the range and duration the input checks need."""

    def __init__(self, block_s: float) -> None:
        self.block_s = float(block_s)
        self.t_first: float | None = None
        self.t_last = -np.inf
        self.sums = np.zeros(4096)
        self.counts = np.zeros(4096)
        self.n_bins = 0
        self.periods: list[float] = []
        self.n_samples = 0
        self.n_bad = 0
        self.vmin = np.inf
        self.vmax = -np.inf

    def add(self, t: np.ndarray, x: np.ndarray, period: float) -> None:
        """Add samples ``x`` at times ``t`` (s, increasing, after every earlier block)."""
        if t.size == 0:
            return
        if self.t_first is None:
            self.t_first = float(t[0])
        x = np.asarray(x, dtype=float)
        fin = np.isfinite(x)
        if not fin.all():
            self.n_bad += int((~fin).sum())
            t, x = t[fin], x[fin]
        self.periods.append(float(period))
        self.n_samples += int(fin.size)
        if t.size == 0:
            return
        self.t_last = max(self.t_last, float(t[-1]))
        self.vmin = min(self.vmin, float(x.min()))
        self.vmax = max(self.vmax, float(x.max()))
        # the 1e-9 keeps a sample that sits exactly on a boundary in the block it starts
        k = np.floor((t - self.t_first) / self.block_s + 1e-9).astype(np.int64)
        k0, k1 = int(k.min()), int(k.max()) + 1
        if k0 < 0:
            raise ValueError("samples out of time order")
        if k1 > self.sums.size:
            grow = max(k1, 2 * self.sums.size)
            self.sums = np.concatenate([self.sums, np.zeros(grow - self.sums.size)])
            self.counts = np.concatenate([self.counts, np.zeros(grow - self.counts.size)])
        self.sums[k0:k1] += np.bincount(k - k0, weights=x, minlength=k1 - k0)
        self.counts[k0:k1] += np.bincount(k - k0, minlength=k1 - k0)
        self.n_bins = max(self.n_bins, k1)

    @property
    def period(self) -> float:
        return float(np.median(self.periods)) if self.periods else float("nan")

    def result(self) -> tuple[np.ndarray, np.ndarray, int]:
        """Block centres, block means and the number of gap-filled blocks (see
        :func:`block_average`)."""
        if self.t_first is None or not self.period > 0:
            return np.empty(0), np.empty(0), 0
        n = self.n_bins
        if (self.t_last - self.t_first + self.period) < self.block_s * n * (1.0 - 1e-9):
            n -= 1  # trailing partial block
        expected = self.block_s / self.period
        s, c = self.sums[:n], self.counts[:n]
        tb = self.t_first + (np.arange(n) + 0.5) * self.block_s
        good = c >= 0.5 * expected
        xb = np.full(n, np.nan)
        xb[good] = s[good] / c[good]
        filled = int((~good).sum())
        if filled and good.sum() >= 2:
            xb[~good] = np.interp(tb[~good], tb[good], xb[good])
        return tb, xb, filled


def block_average(
    t: np.ndarray, x: np.ndarray, block_s: float, period: float
) -> tuple[np.ndarray, np.ndarray, int]:
    """Average ``x`` over consecutive ``block_s`` windows from ``t[0]``.

    Returns block centres, block means and the number of blocks that had fewer than half
    their samples (recording gaps) and were filled by linear interpolation, so that the
    series stays uniformly sampled for VMD. A trailing partial block is dropped."""
    acc = BlockAverager(block_s)
    acc.add(np.asarray(t, dtype=float), x, period)
    return acc.result()


def causal_temperature(t: np.ndarray, pt_t: np.ndarray, pt_c: np.ndarray) -> np.ndarray:
    """PT100 temperature at ``t`` by zero-order hold of the last reading at or before ``t``
    (the first reading before the first one): causal."""
    i = np.searchsorted(pt_t, t, side="right") - 1
    return pt_c[np.clip(i, 0, pt_c.size - 1)]


def features(t: np.ndarray, pt_t: np.ndarray, pt_c: np.ndarray, cfg: PipelineConfig) -> np.ndarray:
    """Drift-model inputs at times ``t``: T (°C) and, with ``use_dtdt``, the backward
    difference ``(T(t) − T(t − w)) / w`` (°C/s, w = ``dtdt_window_s``). Causal, and the same
    function for fitting, offline and streaming application."""
    T = causal_temperature(t, pt_t, pt_c)
    if not cfg.use_dtdt:
        return T[:, None]
    w = cfg.dtdt_window_s
    Tp = causal_temperature(t - w, pt_t, pt_c)
    return np.column_stack([T, (T - Tp) / w])


def _check_temperature(path: str, pt_t: np.ndarray, pt_c: np.ndarray) -> tuple[np.ndarray, ...]:
    if not np.all(np.isfinite(pt_c)) or not np.all(np.isfinite(pt_t)):
        raise InputError(path, "/temperature/pt100 has NaN or infinite readings")
    order = np.argsort(pt_t, kind="stable")
    return pt_t[order], pt_c[order]


def _finish(
    path: str, acc: BlockAverager, pt_t: np.ndarray, pt_c: np.ndarray, cfg: PipelineConfig
) -> tuple[np.ndarray, ...]:
    """Input checks on the accumulated rate, then the 1000 points/h series."""
    if acc.n_bad:
        raise InputError(path, f"/gyro/rate has {acc.n_bad} NaN or infinite samples")
    if acc.t_first is None:
        raise InputError(path, "recording has no /gyro/rate data")
    if acc.vmax == acc.vmin:
        raise InputError(path, "/gyro/rate is constant: nothing to compensate")
    if not acc.period > 0:
        raise InputError(path, "/gyro/rate has no valid sample period")
    span_s = acc.t_last - acc.t_first
    need_s = cfg.min_blocks * cfg.block_s
    if span_s < need_s:
        raise InputError(
            path,
            f"run is {span_s:.0f} s long; the compensation model needs at least "
            f"{need_s:.0f} s ({cfg.min_blocks} points at {cfg.block_s} s)",
        )
    tb, xb, filled = acc.result()
    if not np.all(np.isfinite(xb)):
        raise InputError(path, "/gyro/rate has too many gaps to average")
    return tb, xb, np.interp(tb, pt_t, pt_c), features(tb, pt_t, pt_c, cfg), filled


def prepare_run(rec: Recording, cfg: PipelineConfig) -> PreparedRun:
    """Validate a recording read into memory and decimate it (keeps the full-rate samples).
    Bad input → :class:`InputError` naming it."""
    rate = rec.require_rate()
    pt_t, pt_c = _check_temperature(rec.path, *rec.require_temperature())
    x = np.asarray(rate.values, dtype=float)
    acc = BlockAverager(cfg.block_s)
    acc.add(rate.t, x, rate.period)
    tb, xb, temp, X, filled = _finish(rec.path, acc, pt_t, pt_c, cfg)
    digest = content_hash(x, pt_t, pt_c)
    return PreparedRun(
        path=rec.path,
        unit=rec.unit,
        t=tb,
        rate=xb,
        temp=temp,
        X=X,
        raw_t=rate.t,
        raw_rate=x,
        raw_period=float(rate.period),
        pt_t=pt_t,
        pt_c=pt_c,
        filled_blocks=filled,
        content_hash=digest,
    )


def iter_rate_batches(
    path: str, min_samples: int = 1 << 20, unit: str | None = None
) -> Iterator[tuple[np.ndarray, np.ndarray, float]]:
    """``(t, rate, period)`` for runs of consecutive ``/gyro/rate`` messages holding at
    least ``min_samples`` samples (the last one fewer): per-sample times built for the
    whole batch at once, so the per-message Python cost is one decode."""
    from gyrolab.record.recording import TOPIC_RATE, iter_blocks

    t0s: list[float] = []
    pers: list[float] = []
    arrs: list[np.ndarray] = []
    n = 0

    def flush() -> tuple[np.ndarray, np.ndarray, float]:
        sizes = np.array([a.size for a in arrs])
        start = np.repeat(np.cumsum(sizes) - sizes, sizes)
        t = np.repeat(t0s, sizes) + (np.arange(sizes.sum()) - start) * np.repeat(pers, sizes)
        return t, np.concatenate(arrs).astype(float), float(np.median(pers))

    for t0, period, _first, arr in iter_blocks(path, TOPIC_RATE, unit=unit):
        t0s.append(t0)
        pers.append(period)
        arrs.append(arr)
        n += arr.size
        if n >= min_samples:
            yield flush()
            t0s, pers, arrs, n = [], [], [], 0
    if arrs:
        yield flush()


def prepare_arrays(
    path: str,
    t: np.ndarray,
    rate: np.ndarray,
    period: float,
    pt_t: np.ndarray,
    pt_c: np.ndarray,
    cfg: PipelineConfig,
) -> PreparedRun:
    """Like :func:`prepare_run` for a run already in arrays (full-rate samples ``rate`` at
    times ``t``, PT100 readings ``pt_c`` at ``pt_t``): simulations and tests."""
    pt_t, pt_c = _check_temperature(path, np.asarray(pt_t, float), np.asarray(pt_c, float))
    x = np.asarray(rate, dtype=float)
    acc = BlockAverager(cfg.block_s)
    acc.add(np.asarray(t, dtype=float), x, period)
    tb, xb, temp, X, filled = _finish(path, acc, pt_t, pt_c, cfg)
    return PreparedRun(
        path, tb, xb, temp, X, np.asarray(t, float), x, float(period), pt_t, pt_c, filled
    )


def prepare_file(path: str, cfg: PipelineConfig, unit: str | None = None) -> PreparedRun:
    """Like :func:`prepare_run`, streaming ``/gyro/rate`` from the file block by block:
    memory is that of the 1000 points/h series, not of the run (``raw_t``/``raw_rate`` are
    ``None``; :func:`streaming_block_means` re-reads the file when it needs the samples)."""
    from gyrolab.record.recording import TOPIC_PT100, read_recording

    rec = read_recording(path, topics=[TOPIC_PT100], unit=unit)
    pt_t, pt_c = _check_temperature(str(path), *rec.require_temperature())
    acc = BlockAverager(cfg.block_s)
    hasher = RunHasher()
    for t, x, period in iter_rate_batches(path, unit=unit):
        acc.add(t, x, period)
        hasher.add_rate(x)
    tb, xb, temp, X, filled = _finish(str(path), acc, pt_t, pt_c, cfg)
    digest = hasher.hexdigest(pt_t, pt_c)
    return PreparedRun(
        path=str(path),
        unit=unit,
        t=tb,
        rate=xb,
        temp=temp,
        X=X,
        raw_t=None,
        raw_rate=None,
        raw_period=acc.period,
        pt_t=pt_t,
        pt_c=pt_c,
        filled_blocks=filled,
        content_hash=digest,
    )


# ------------------------------------------------- adapters to the other modules


@dataclass
class Decomposition:
    """VMD modes at 1000 points/h with their MPE values and classes."""

    K: int
    alpha: float
    modes: np.ndarray  # (K, N), °/s
    omega: np.ndarray  # (K,), cycles/sample
    mpe: np.ndarray  # (K,), mean MPE over scales 1..mpe_scale, in [0, 1]
    classes: dict[str, list[int]]
    history: dict[str, np.ndarray] = field(default_factory=dict)

    def part(self, name: str) -> np.ndarray:
        idx = self.classes.get(name, [])
        if not idx:
            return np.zeros(self.modes.shape[1])
        return self.modes[idx].sum(axis=0)


def _vmd_fixed(x: np.ndarray, K: int, alpha: float) -> tuple[np.ndarray, np.ndarray]:
    from gyrolab.compensation.vmd import vmd

    r = vmd(x, alpha=alpha, K=K)
    return r.modes, r.omega


def _gpso_vmd(
    x: np.ndarray, cfg: PipelineConfig, seed: int
) -> tuple[int, float, dict[str, np.ndarray]]:
    """GPSO search of (K, α) in the paper's box (fitness.py's default criterion); returns
    the choice and the swarm history (every evaluated position and its fitness)."""
    from gyrolab.compensation.fitness import search_vmd_parameters

    s = search_vmd_parameters(
        x,
        criterion=cfg.vmd_fitness,
        K_bounds=cfg.k_range,
        alpha_bounds=cfg.alpha_range,
        population=cfg.gpso_population,
        generations=cfg.gpso_generations,
        seed=seed,
    )
    g = s.gpso
    history = {
        "best_fitness": g.best_history,
        "best_position": g.best_position_history,
        "positions": g.positions,
        "fitness": g.fitness,
    }
    return s.K, s.alpha, history


def _classify(modes: np.ndarray, cfg: PipelineConfig) -> tuple[np.ndarray, dict[str, list[int]]]:
    """Mean MPE over scales 1..``mpe_scale`` per mode and the threshold classes (mpe.py)."""
    from gyrolab.compensation.mpe import classify_modes, mean_mpe

    values = mean_mpe(modes, scales=cfg.mpe_scale, order=cfg.mpe_order, delay=cfg.mpe_delay)
    classes = classify_modes(values, cfg.mpe_noise_min, cfg.mpe_drift_max)
    if not classes["drift"]:
        # The temperature drift is always the most regular thing in the run; when the noise
        # riding on it keeps every mode above drift_max, the most regular mode is the drift.
        k = int(np.argmin(values))
        for name in ("noise", "mixed"):
            if k in classes[name]:
                classes[name].remove(k)
        classes["drift"] = [k]
    return values, classes


def _fit_flp(x: np.ndarray, cfg: PipelineConfig):  # -> ForwardLinearPredictor
    """Forward linear predictor fitted on ``x`` (Burg, order by ``flp_criterion``)."""
    from gyrolab.compensation.flp import ForwardLinearPredictor

    return ForwardLinearPredictor(max_order=cfg.flp_max_order, criterion=cfg.flp_criterion).fit(x)


def _run_flp(flp: Any, x: np.ndarray, block_s: float) -> tuple[np.ndarray, dict[str, Any]]:
    """Filter ``x`` from a fresh state with a fitted predictor; report what it did."""
    flp.reset()
    y = flp.filter(x)
    info = {
        "order": flp.order,
        "variance_in": float(np.var(x)),
        "variance_out": float(np.var(y)),
        "bandwidth_hz": float(flp.bandwidth_hz(1.0 / block_s)),
    }
    return y, info


def decompose(
    x: np.ndarray, cfg: PipelineConfig, seed: int, K: int | None = None, alpha: float | None = None
) -> Decomposition:
    """GPSO-VMD (or VMD at a given (K, α)) + MPE classes of the averaged rate ``x``."""
    history: dict[str, np.ndarray] = {}
    if K is None or alpha is None:
        K, alpha = cfg.vmd_K, cfg.vmd_alpha
    if K is None or alpha is None:
        K, alpha, history = _gpso_vmd(x, cfg, seed)
    modes, omega = _vmd_fixed(x, int(K), float(alpha))
    mpe, classes = _classify(modes, cfg)
    return Decomposition(int(K), float(alpha), modes, omega, mpe, classes, history)


# ------------------------------------------------------------------------ the model


DriftModel = MLPDriftModel | PolyDriftModel


@dataclass
class CompensationModel:
    """What ``gyrolab compensate`` fits and ``gyrolab apply`` uses."""

    config: PipelineConfig
    drift: DriftModel
    baselines: dict[str, DriftModel]
    K: int
    alpha: float
    calibration: dict[str, Any]
    flp_mixed: Any = None  # ForwardLinearPredictor on the mixed modes (None: no mixed mode)
    flp_stream: Any = None  # ForwardLinearPredictor on the causal drift-compensated series
    diagnostics: dict[str, np.ndarray] = field(default_factory=dict)
    decomposition_info: dict[str, Any] = field(default_factory=dict)
    timing_s: dict[str, float] = field(default_factory=dict)
    causal: CausalDriftModel | None = None  # the causal headline model (causal.py)
    seed: int | None = None  # None: a model written before the seed was recorded


def fit_causal_model(run: PreparedRun, cfg: PipelineConfig, seed: int = 0) -> CausalDriftModel:
    """The causal drift model (:func:`gyrolab.compensation.causal.fit_causal`): every family
    of ``cfg.causal_families`` on the causal features, the winner by CV inside ``run``."""
    cal = CausalCalibration(t=run.t, rate=run.rate, pt_t=run.pt_t, pt_c=run.pt_c)
    return fit_causal(cal, families=cfg.causal_families, bp=cfg.bp(), ga=cfg.ga(), seed=seed)


DRIFT_MODELS = ("gabp", "bp", "poly")


def fit_drift_model(X: np.ndarray, drift: np.ndarray, cfg: PipelineConfig, seed: int) -> Any:
    """The drift model ``f`` of ``cfg.drift_model`` fitted to ``drift ≈ f(X)``: the paper's
    GA-BP, plain BP (random initial weights) or the polynomial of :mod:`.baselines`."""
    if cfg.drift_model == "gabp":
        return fit_gabp(X, drift, ga=cfg.ga(), bp=cfg.bp(), seed=seed)
    if cfg.drift_model == "bp":
        return fit_plain_bp(X, drift, bp=cfg.bp(), seed=seed)
    if cfg.drift_model == "poly":
        return fit_poly(X, drift)
    raise ValueError(f"drift_model must be one of {DRIFT_MODELS}, not {cfg.drift_model!r}")


def fit(
    run: PreparedRun, cfg: PipelineConfig = DEFAULT_CONFIG, seed: int = 0
) -> tuple[CompensationModel, Decomposition]:
    """Fit the hybrid model (and the baselines) on a prepared calibration run."""
    import torch

    span = float(np.ptp(run.temp))
    if span < cfg.min_temp_span_c:
        raise InputError(
            run.path,
            f"temperature spans only {span:.2f} °C; fitting a temperature model needs a "
            f"sweep of at least {cfg.min_temp_span_c} °C",
        )
    torch.manual_seed(seed)
    timing: dict[str, float] = {}
    t0 = time.perf_counter()
    dec = decompose(run.rate, cfg, seed)
    timing["gpso_vmd_mpe"] = time.perf_counter() - t0
    drift = dec.part("drift")
    if not dec.classes.get("drift"):
        raise InputError(run.path, "no VMD mode was classified as drift: nothing to model")
    t1 = time.perf_counter()
    gabp = fit_drift_model(run.X, drift, cfg, seed)
    timing["gabp"] = time.perf_counter() - t1
    t2 = time.perf_counter()
    baselines: dict[str, DriftModel] = {}
    if "poly" in cfg.baselines:
        baselines["poly"] = fit_poly(run.X, run.rate)
    if "bp" in cfg.baselines:
        baselines["bp"] = fit_plain_bp(run.X, run.rate, bp=cfg.bp(), seed=seed)
    timing["baselines"] = time.perf_counter() - t2
    t3 = time.perf_counter()
    causal = fit_causal_model(run, cfg, seed)
    timing["causal"] = time.perf_counter() - t3
    mixed = dec.part("mixed")
    flp_mixed = _fit_flp(mixed, cfg) if dec.classes.get("mixed") else None
    flp_stream = _fit_flp(run.rate - gabp.predict(run.X), cfg)
    diagnostics = {
        "calib_t": run.t,
        "calib_rate": run.rate,
        "calib_temp": run.temp,
        "calib_X": run.X,
        "calib_modes": dec.modes,
        "calib_omega": dec.omega,
        "calib_mpe": dec.mpe,
        "drift_target": drift,
        "drift_fit": gabp.predict(run.X),
    }
    for k, v in dec.history.items():
        diagnostics[f"gpso_{k}"] = np.asarray(v)
    model = CompensationModel(
        config=cfg,
        drift=gabp,
        baselines=baselines,
        K=dec.K,
        alpha=dec.alpha,
        calibration={
            "path": run.path,
            "n_points": int(run.t.size),
            "duration_s": float(run.t[-1] - run.t[0] + cfg.block_s),
            **calibration_ranges(run, cfg.dtdt_window_s),
            "raw_rate_hz": 1.0 / run.raw_period,
            "filled_blocks": run.filled_blocks,
            "content_hash": run.content_hash,
        },
        flp_mixed=flp_mixed,
        flp_stream=flp_stream,
        diagnostics=diagnostics,
        decomposition_info={"classes": dec.classes, "mpe": dec.mpe.tolist()},
        timing_s=timing,
        causal=causal,
        seed=int(seed),
    )
    return model, dec


# ---------------------------------------------------------------------- application


@dataclass
class Application:
    """A model applied to one run, at 1000 points/h (``series``) plus diagnostics."""

    t: np.ndarray
    series: dict[str, np.ndarray]  # raw, compensated, compensated_drift_only, baselines.*
    decomposition: Decomposition
    flp_info: dict[str, Any]
    bandwidth: dict[str, float]


def compensate_offline(
    model: CompensationModel,
    run: PreparedRun,
    dec: Decomposition | None = None,
) -> Application:
    """The paper's reconstruction on ``run`` (module docstring), plus the causal outputs of
    the drift-only model and the baselines averaged to the same rate."""
    cfg = model.config
    if dec is None:
        dec = decompose(run.rate, cfg, 0, K=model.K, alpha=model.alpha)
    mixed = dec.part("mixed")
    flp_info: dict[str, Any] = {}
    mixed_f = mixed
    if dec.classes.get("mixed"):
        # the calibration run's predictor; a run whose modes were all mixed-free at
        # calibration but not now gets one fitted on its own mixed modes (recorded)
        flp = model.flp_mixed if model.flp_mixed is not None else _fit_flp(mixed, cfg)
        mixed_f, flp_info = _run_flp(flp, mixed, cfg.block_s)
        flp_info["fitted_on"] = "calibration" if model.flp_mixed is not None else "this run"
    drift = dec.part("drift")
    pred = model.drift.predict(run.X)
    denoised = mixed_f + drift
    drift_only = run.rate - pred
    stream_flp, _ = _run_flp(model.flp_stream, drift_only, cfg.block_s)
    series = {
        "raw": run.rate,
        "compensated": denoised - pred,
        "compensated_drift_only": drift_only,
        "compensated_streaming_flp": stream_flp,
        "denoised": denoised,
        "drift_prediction": pred,
    }
    for name, m in model.baselines.items():
        bpred = m.predict(run.X)
        series[f"baselines.{name}"] = run.rate - bpred
        # the paper's noise removal with this drift model instead of GA-BP: isolates what
        # the drift model itself contributes
        series[f"denoised_baselines.{name}"] = denoised - bpred
    return Application(
        t=run.t,
        series=series,
        decomposition=dec,
        flp_info=flp_info,
        bandwidth=effective_bandwidth(run.rate, denoised, cfg.block_s),
    )


class StreamingCompensator:
    """Causal full-rate compensation ``raw(t) − f(T(t⁻))`` (module docstring), block by
    block: ``comp(t, rate)`` for any run of samples in time order.

    Without dT/dt the drift model is evaluated once per PT100 reading (the zero-order hold
    only changes there) and looked up per sample with one ``searchsorted``; with dT/dt the
    inputs also change through the ``t − w`` lookup, so they are evaluated per sample."""

    def __init__(
        self, model: CompensationModel, pt_t: np.ndarray, pt_c: np.ndarray, which: str = "gabp"
    ) -> None:
        self.cfg = model.config
        self.pt_t, self.pt_c = pt_t, pt_c
        if which == "causal":
            # the causal model's state machine runs over the readings once; its drift is
            # held between readings (causal_features.py)
            if model.causal is None:
                raise ValueError("model has no causal drift model")
            self.model = model.causal
            self._at_reading = model.causal.reading_drift(pt_t, pt_c)
            return
        self.model = model.drift if which == "gabp" else model.baselines[which]
        self._at_reading = None if self.cfg.use_dtdt else self.model.predict(pt_c[:, None])

    def drift(self, t: np.ndarray) -> np.ndarray:
        if self._at_reading is not None:
            i = np.searchsorted(self.pt_t, t, side="right") - 1
            return self._at_reading[np.clip(i, 0, None)]
        return self.model.predict(features(t, self.pt_t, self.pt_c, self.cfg))

    def __call__(self, t: np.ndarray, rate: np.ndarray) -> np.ndarray:
        out = np.empty(rate.size)
        chunk = 1 << 20  # bounded temporaries on long runs
        for s in range(0, rate.size, chunk):
            out[s : s + chunk] = rate[s : s + chunk] - self.drift(t[s : s + chunk])
        return out


def streaming_compensate(
    model: CompensationModel,
    t: np.ndarray,
    rate: np.ndarray,
    pt_t: np.ndarray,
    pt_c: np.ndarray,
    which: str = "gabp",
) -> np.ndarray:
    """:class:`StreamingCompensator` applied to whole arrays."""
    return StreamingCompensator(model, pt_t, pt_c, which)(t, np.asarray(rate, dtype=float))


def streaming_block_means(
    model: CompensationModel, run: PreparedRun, which: str = "gabp"
) -> np.ndarray:
    """The causal full-rate output averaged to the run's 1000 points/h grid: from the
    samples in memory, or by streaming the file again when the run was prepared from it.
    ``which``: ``gabp`` (the paper's drift model on T), a baseline name, or ``causal``."""
    return streaming_block_means_many(model, run, (which,))[which]


def streaming_block_means_many(
    model: CompensationModel, run: PreparedRun, whiches: tuple[str, ...]
) -> dict[str, np.ndarray]:
    """:func:`streaming_block_means` of several causal outputs in one pass over the run
    (one read of the file when the run was prepared from it)."""
    comps = {w: StreamingCompensator(model, run.pt_t, run.pt_c, w) for w in whiches}
    accs = {w: BlockAverager(model.config.block_s) for w in whiches}
    if run.raw_rate is not None and run.raw_t is not None:
        batches: Any = [(run.raw_t, run.raw_rate, run.raw_period)]
    else:
        batches = iter_rate_batches(run.path, unit=run.unit)
    for t, x, period in batches:
        for w in whiches:
            accs[w].add(t, comps[w](t, x), period)
    return {w: accs[w].result()[1] for w in whiches}


def effective_bandwidth(raw: np.ndarray, filtered: np.ndarray, block_s: float) -> dict[str, float]:
    """Bandwidth the offline filtering leaves, from the estimated transfer function
    ``H(f) = P_xy(f) / P_xx(f)`` (Welch, raw x → filtered y, at 1000 points/h):

    * ``f3db_hz`` — the lowest frequency where ``|H|² < ½``;
    * ``enbw_hz`` — equivalent noise bandwidth ``∫₀^{f_N} |H|² df`` (white noise of
      density S leaves the filter with variance S·ENBW);
    * ``nyquist_hz`` — ``1 / (2 block_s)``, what 1000 points/h alone keeps."""
    from scipy import signal

    nper = int(min(1024, max(16, raw.size // 8)))
    f, pxx = signal.welch(raw, fs=1.0 / block_s, nperseg=nper, detrend="linear")
    _, pxy = signal.csd(raw, filtered, fs=1.0 / block_s, nperseg=nper, detrend="linear")
    h2 = np.abs(pxy / np.where(pxx > 0, pxx, np.inf)) ** 2
    h2 = np.minimum(h2, 1.0)
    below = np.flatnonzero((h2 < 0.5) & (f > 0))
    f3 = float(f[below[0]]) if below.size else float(f[-1])
    enbw = float(np.trapezoid(h2, f))
    return {"f3db_hz": f3, "enbw_hz": enbw, "nyquist_hz": 0.5 / block_s}


# ---------------------------------------------------------------------- persistence


def _drift_from_state(meta: dict[str, Any], arrays: dict[str, np.ndarray], prefix: str):
    if meta["kind"] == "mlp":
        return MLPDriftModel.from_state(meta, arrays, prefix)
    if meta["kind"] == "poly":
        return PolyDriftModel.from_state(meta, arrays, prefix)
    raise ValueError(f"unknown drift model kind {meta['kind']!r}")


def save_model(model: CompensationModel, directory: str) -> None:
    """Write ``model`` into an existing directory (see :mod:`.model_dir` for the layout)."""
    from gyrolab.compensation.model_dir import save_model_dir

    arrays: dict[str, np.ndarray] = dict(model.diagnostics)
    cmeta = None
    if model.causal is not None:
        cmeta, carr = model.causal.to_state("causal.")
        arrays.update(carr)
    dmeta, darr = model.drift.to_state("drift.")
    arrays.update(darr)
    bmeta: dict[str, Any] = {}
    for name, m in model.baselines.items():
        meta, arr = m.to_state(f"baseline.{name}.")
        bmeta[name] = meta
        arrays.update(arr)
    meta = {
        "seed": model.seed,
        "config": model.config.to_dict(),
        "vmd": {"K": model.K, "alpha": model.alpha},
        "decomposition": model.decomposition_info,
        "drift_model": dmeta,
        "baselines": bmeta,
        "calibration": model.calibration,
        "flp": {
            "mixed": None if model.flp_mixed is None else model.flp_mixed.to_dict(),
            "stream": None if model.flp_stream is None else model.flp_stream.to_dict(),
        },
        "causal_model": cmeta,
        "streaming": {
            "temperature": "zero-order hold of the last PT100 reading",
            "dtdt": "backward difference over config.dtdt_window_s"
            if model.config.use_dtdt
            else None,
        },
    }
    torch_states = {}
    if isinstance(model.drift, MLPDriftModel):
        torch_states["drift_gabp"] = model.drift.torch_state_dict()
    bp = model.baselines.get("bp")
    if isinstance(bp, MLPDriftModel):
        torch_states["baseline_bp"] = bp.torch_state_dict()
    save_model_dir(directory, meta, arrays, torch_states)


def load_model(directory: str) -> CompensationModel:
    """Read a model directory written by :func:`save_model` (format checked)."""
    from gyrolab.compensation.flp import ForwardLinearPredictor
    from gyrolab.compensation.guards import check_finite
    from gyrolab.compensation.model_dir import load_model_dir

    meta, arrays = load_model_dir(directory)
    try:
        check_finite(directory, meta, arrays)
        flp = meta.get("flp") or {}
        flp_mixed = flp.get("mixed")
        flp_stream = flp.get("stream")
        cfg = PipelineConfig.from_dict(meta["config"])
        drift = _drift_from_state(meta["drift_model"], arrays, "drift.")
        baselines = {
            name: _drift_from_state(bm, arrays, f"baseline.{name}.")
            for name, bm in meta.get("baselines", {}).items()
        }
        diagnostics = {
            k: v for k, v in arrays.items() if not k.startswith(("drift.", "baseline.", "causal."))
        }
        cmeta = meta.get("causal_model")
        causal = None if cmeta is None else CausalDriftModel.from_state(cmeta, arrays, "causal.")
        return CompensationModel(
            config=cfg,
            drift=drift,
            baselines=baselines,
            K=int(meta["vmd"]["K"]),
            alpha=float(meta["vmd"]["alpha"]),
            calibration=dict(meta.get("calibration", {})),
            flp_mixed=None if flp_mixed is None else ForwardLinearPredictor.from_dict(flp_mixed),
            flp_stream=None if flp_stream is None else ForwardLinearPredictor.from_dict(flp_stream),
            diagnostics=diagnostics,
            decomposition_info=dict(meta.get("decomposition", {})),
            timing_s=dict(meta.get("timing_s", {})),
            causal=causal,
            seed=None if meta.get("seed") is None else int(meta["seed"]),
        )
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(directory, f"incomplete or damaged model ({e!r})") from None


# -------------------------------------------------------------------------- metrics


def series_metrics(x: np.ndarray, block_s: float) -> dict[str, float]:
    """The five metrics (docs/cli.md; :func:`gyrolab.compensation.metrics.signal_metrics`) of a
    series sampled every ``block_s`` seconds (°/s). Every series is compared at the paper's
    1000 points/h, so ``rms_deg_per_s`` is that of the 3.6 s averages, and bias stability
    and drift peak-to-peak are those of the series itself. The Allan curve behind ARW and
    bias instability stops at T/10."""
    from gyrolab.compensation.metrics import signal_metrics
    from gyrolab.numerics.allan import allan_deviation

    # Octave taus up to T/10 only: beyond that an Allan point rests on a handful of
    # averages, and a long-tau stretch that happens to fall at slope -1/2 (drift residual
    # turning over) would otherwise be read as the ARW line and extrapolated to 1 s.
    m_max = max(2, x.size // 10)
    taus = block_s * 2.0 ** np.arange(int(np.log2(m_max)) + 1)
    allan = allan_deviation(x, 1.0 / block_s, taus=taus, confidence=None)
    return signal_metrics(
        x, 1.0 / block_s, stability_window_s=block_s, drift_window_s=block_s, allan=allan
    )


def series_noise_terms(x: np.ndarray, block_s: float) -> dict[str, Any]:
    """The IEEE 952 terms (Q, N, B, K, R) the Allan curve of a ``block_s`` series
    identifies — τ ≤ T/10 and slopes supported by the 1σ confidence intervals, B only at a
    floor (:func:`gyrolab.numerics.allan.noise_terms`) — with the τ range of each and a
    reason for each term that is not identifiable (``None``)."""
    from gyrolab.numerics.allan import allan_deviation, noise_terms

    return noise_terms(allan_deviation(x, 1.0 / block_s, taus="octave")).to_dict()


def evaluate(
    model: CompensationModel, app: Application, run: PreparedRun, held_out: bool
) -> dict[str, Any]:
    """metrics.json content for one application (docs/cli.md keys plus diagnostics)."""
    bs = model.config.block_s
    m: dict[str, Any] = {"run": run.path, "held_out": bool(held_out)}
    for key in ("raw", "compensated", "compensated_drift_only", "compensated_streaming_flp"):
        m[key] = series_metrics(app.series[key], bs)
    whiches = ("gabp", "causal") if model.causal is not None else ("gabp",)
    streams = streaming_block_means_many(model, run, whiches)
    m["compensated_streaming"] = series_metrics(streams["gabp"], bs)
    if model.causal is not None:
        causal_series = streams["causal"]
        m["causal"] = series_metrics(causal_series, bs)
        m["causal_model"] = model.causal.describe()
        m["headline"] = headline_info(model, run)
        m["drift_pp_100s_deg_per_s"] = drift_pp_table(
            {
                "raw": app.series["raw"],
                "causal": causal_series,
                "compensated": app.series["compensated"],
                "compensated_drift_only": app.series["compensated_drift_only"],
                **{f"baselines.{n}": app.series[f"baselines.{n}"] for n in model.baselines},
            },
            bs,
        )
    m["baselines"] = {
        name: series_metrics(app.series[f"baselines.{name}"], bs) for name in model.baselines
    }
    m["baselines_with_noise_removal"] = {
        name: series_metrics(app.series[f"denoised_baselines.{name}"], bs)
        for name in model.baselines
    }
    dec = app.decomposition
    m["vmd"] = {"K": dec.K, "alpha": dec.alpha}
    m["imf_classes"] = dec.classes
    m["mpe_mean"] = [float(v) for v in dec.mpe]
    m["vmd_center_frequency_hz"] = [float(w) / bs for w in dec.omega]
    m["denoising"] = {
        "arw_with_noise_removal_deg_per_sqrt_h": m["compensated"]["arw_deg_per_sqrt_h"],
        "arw_without_noise_removal_deg_per_sqrt_h": m["compensated_drift_only"][
            "arw_deg_per_sqrt_h"
        ],
        "bandwidth": app.bandwidth,
        "raw_bandwidth_hz": 0.5 / run.raw_period,
        "flp": app.flp_info,
    }
    m["noise_terms"] = {
        key: series_noise_terms(x, bs)
        for key, x in (
            ("raw", app.series["raw"]),
            ("compensated", app.series["compensated"]),
            ("compensated_drift_only", app.series["compensated_drift_only"]),
            ("compensated_streaming", streams["gabp"]),
            *((("causal", streams["causal"]),) if "causal" in streams else ()),
        )
    }
    rng = range_check(model.calibration, run)
    if rng:
        m["temperature"] = rng
    m["sample_period_s"] = bs
    m["n_points"] = int(run.t.size)
    return m


DRIFT_PP_WINDOW_S = 100.0  # issue 11: p-p of 3.6 s averages is set by white noise


def drift_pp_table(
    series: dict[str, np.ndarray], block_s: float, window_s: float = DRIFT_PP_WINDOW_S
) -> dict[str, float]:
    """Peak-to-peak (°/s) of every series after averaging it over ``window_s`` windows
    (whole 3.6 s blocks: 28 → 100.8 s) — the same low-pass for every method."""
    from gyrolab.compensation.metrics import block_means

    return {
        k: float(np.ptp(block_means(np.asarray(v, float), 1.0 / block_s, window_s)))
        for k, v in series.items()
    }


def headline_info(model: CompensationModel, run: PreparedRun) -> dict[str, Any]:
    """What the headline is: the causal full-bandwidth output, and the paper's offline
    method beside it with its bandwidth (metrics.json ``headline``)."""
    c = model.causal
    return {
        "output": "causal",
        "description": "raw(t) - d(t), d from PT100 readings at or before t (causal, "
        "full bandwidth)",
        "family": None if c is None else c.family,
        "bandwidth_hz": 0.5 / run.raw_period,
        "offline_method": "compensated (the paper's GPSO-VMD/MPE/FLP/GA-BP reconstruction, "
        "offline, low-passed: see denoising.bandwidth)",
        "metrics_window_s": model.config.block_s,
        "drift_pp_window_s": DRIFT_PP_WINDOW_S,
    }
