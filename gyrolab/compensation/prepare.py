"""A run reduced to what the compensation model needs (:class:`PreparedRun`).

Step 1 of the model (:mod:`gyrolab.compensation.fit`): the rate is averaged to the
paper's 1000 points/h (``block_s`` = 3.6 s, :mod:`gyrolab.numerics.averaging`: ≈ 13 000
points for a 13 h run, the paper's N), after the input checks (finite, not constant, long
enough; bad input → one-line :class:`~gyrolab.errors.InputError`). The drift model's input
at each block centre is the last PT100 reading at or before it (:func:`features`): the
same causal rule as the streaming output of :mod:`gyrolab.compensation.apply`.

Three sources: a :class:`~gyrolab.record.reader.Recording` in memory
(:func:`prepare_run`), a file streamed block by block in bounded memory
(:func:`prepare_file`) and plain arrays (:func:`prepare_arrays`: simulations and tests).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from gyrolab.compensation.causal_features import hold
from gyrolab.compensation.config import PipelineConfig
from gyrolab.compensation.guards import RunHasher, content_hash
from gyrolab.compensation.temperature_model import temperature_inputs
from gyrolab.errors import InputError
from gyrolab.numerics.averaging import BlockAverager
from gyrolab.record.format import TOPIC_PT100, TOPIC_RATE
from gyrolab.record.reader import Block, Recording, iter_blocks, read_recording


@dataclass
class PreparedRun:
    """A run reduced to what the model needs.

    ``t``/``rate``/``temp``/``X``: the 1000 points/h series (s, °/s, °C, features);
    ``raw_t``/``raw_rate``: full-rate samples; ``pt_t``/``pt_c``: PT100 readings.
    ``path`` is the file read (error messages name it); :attr:`name` is how the outputs
    record the run."""

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
    # what pt_c is: the PT100, or the unit's internal sensor (Recording.temperature_source)
    temperature_source: str = "pt100"
    serial: str = ""  # the unit's serial as the recording names it ("": not recorded)
    label: str = ""  # the caller's stable name for the run ("": the path as given)
    # prepare_file's full-rate batches, kept for the later passes (run_rate_batches) when the
    # run has at most RATE_KEEP_MAX_SAMPLES samples; None: those passes stream the file
    rate_batches: list[RateBatch] | None = None

    @property
    def name(self) -> str:
        """The run as model.json, metrics.json and results.json record it: ``label``, else
        ``path`` as the caller gave it (``gyrolab demo`` passes paths relative to its DIR,
        never its temporary build directory)."""
        return self.label or self.path


def causal_temperature(t: np.ndarray, pt_t: np.ndarray, pt_c: np.ndarray) -> np.ndarray:
    """PT100 temperature (°C) at ``t`` (s): the last reading at or before ``t`` (the first
    reading before the first one), the zero-order hold of
    :func:`gyrolab.compensation.causal_features.hold`. Causal."""
    return hold(t, pt_t, pt_c)


def features(t: np.ndarray, pt_t: np.ndarray, pt_c: np.ndarray, cfg: PipelineConfig) -> np.ndarray:
    """Drift-model inputs at times ``t``: T (°C) and, with ``use_dtdt``, the backward
    difference ``(T(t) − T(t − w)) / w`` (°C/s, w = ``dtdt_window_s``). Causal, and the same
    function for fitting, offline and streaming application."""
    return temperature_inputs(t, pt_t, pt_c, cfg.dtdt_window_s if cfg.use_dtdt else None)


def _check_temperature(path: str, pt_t: np.ndarray, pt_c: np.ndarray) -> tuple[np.ndarray, ...]:
    if not np.all(np.isfinite(pt_c)) or not np.all(np.isfinite(pt_t)):
        raise InputError(path, "/temperature/pt100 has NaN or infinite readings")
    order = np.argsort(pt_t, kind="stable")
    return pt_t[order], pt_c[order]


def _finish(
    path: str,
    acc: BlockAverager,
    pt_t: np.ndarray,
    pt_c: np.ndarray,
    cfg: PipelineConfig,
    raw: tuple[np.ndarray, np.ndarray] | None,
    unit: str | None = None,
    cut: list[tuple[float, float]] | tuple[()] = (),
) -> PreparedRun:
    """Input checks on the accumulated rate, then the run at 1000 points/h; ``raw``: the
    full-rate ``(t, rate)`` when they are in memory; ``cut``: a resumed run's
    interruptions, over which nothing is filled in (the series jumps over them).
    ``content_hash`` is left to the caller."""
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
    tb, xb, filled = acc.result(cut)
    if not np.all(np.isfinite(xb)):
        raise InputError(path, "/gyro/rate has too many gaps to average")
    return PreparedRun(
        path=path,
        unit=unit,
        t=tb,
        rate=xb,
        temp=np.interp(tb, pt_t, pt_c),
        X=features(tb, pt_t, pt_c, cfg),
        raw_t=None if raw is None else raw[0],
        raw_rate=None if raw is None else raw[1],
        raw_period=acc.period,
        pt_t=pt_t,
        pt_c=pt_c,
        filled_blocks=filled,
    )


def prepare_run(rec: Recording, cfg: PipelineConfig) -> PreparedRun:
    """Validate a recording read into memory and decimate it (keeps the full-rate samples).
    Bad input → :class:`InputError` naming it."""
    rate = rec.require_rate()
    pt_t, pt_c = _check_temperature(rec.path, *rec.require_temperature())
    x = np.asarray(rate.values, dtype=float)
    acc = BlockAverager(cfg.block_s)
    acc.add(rate.t, x, rate.period)
    run = _finish(rec.path, acc, pt_t, pt_c, cfg, (rate.t, x), rec.unit, rec.interruptions)
    run.content_hash = content_hash(x, pt_t, pt_c)
    run.temperature_source = rec.temperature_source
    run.serial = str(rec.run.get("unit_serial") or "")
    return run


RateBatch = tuple[np.ndarray, np.ndarray, float]


class RateBatcher:
    """Consecutive ``/gyro/rate`` blocks gathered into ``(t, rate, period)`` batches of at
    least ``min_samples`` samples (the last one fewer): per-sample times built for the
    whole batch at once, so the per-message Python cost is one decode."""

    def __init__(self, min_samples: int = 1 << 20) -> None:
        self.min_samples = min_samples
        self._t0s: list[float] = []
        self._pers: list[float] = []
        self._arrs: list[np.ndarray] = []
        self._n = 0

    def add(self, block: Block) -> RateBatch | None:
        """Take one decoded block; the batch it completes, else ``None``."""
        t0, period, _first, arr = block
        self._t0s.append(t0)
        self._pers.append(period)
        self._arrs.append(arr)
        self._n += arr.size
        return self.flush() if self._n >= self.min_samples else None

    def flush(self) -> RateBatch | None:
        """The blocks taken since the last batch, as one batch (``None``: none)."""
        if not self._arrs:
            return None
        t0s, pers, arrs = self._t0s, self._pers, self._arrs
        self._t0s, self._pers, self._arrs, self._n = [], [], [], 0
        sizes = np.array([a.size for a in arrs])
        start = np.repeat(np.cumsum(sizes) - sizes, sizes)
        t = np.repeat(t0s, sizes) + (np.arange(sizes.sum()) - start) * np.repeat(pers, sizes)
        return t, np.concatenate(arrs).astype(float), float(np.median(pers))


#: The most full-rate samples :func:`prepare_file` keeps in memory for the passes that follow
#: (:func:`run_rate_batches`): 6 M samples, 96 MB of float64 times and rates — a 13 h unit at
#: 100 Hz (4.68 M). Longer or faster runs are streamed from the file again by each pass.
RATE_KEEP_MAX_SAMPLES = 6_000_000


def iter_rate_batches(
    path: str, min_samples: int = 1 << 20, unit: str | None = None
) -> Iterator[RateBatch]:
    """``(t, rate, period)`` batches of the file's ``/gyro/rate`` (:class:`RateBatcher`)."""
    batcher = RateBatcher(min_samples)
    for block in iter_blocks(path, TOPIC_RATE, unit=unit):
        batch = batcher.add(block)
        if batch is not None:
            yield batch
    last = batcher.flush()
    if last is not None:
        yield last


def run_rate_batches(run: PreparedRun) -> Iterable[RateBatch]:
    """The run's full-rate ``(t, rate, period)`` batches, for a pass after the preparation:
    the ones :func:`prepare_file` kept, else :func:`iter_rate_batches` from the file (the same
    batches: one batcher, one reader). A run prepared in memory has ``raw_t``/``raw_rate``
    instead."""
    if run.rate_batches is not None:
        return run.rate_batches
    return iter_rate_batches(run.path, unit=run.unit)


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
    t = np.asarray(t, dtype=float)
    acc.add(t, x, period)
    return _finish(path, acc, pt_t, pt_c, cfg, (t, x))


def prepare_file(path: str, cfg: PipelineConfig, unit: str | None = None) -> PreparedRun:
    """Like :func:`prepare_run`, streaming ``/gyro/rate`` from the file block by block:
    memory is that of the 1000 points/h series, not of the run (``raw_t``/``raw_rate`` are
    ``None``; the full-rate batches are kept for the later passes up to
    :data:`RATE_KEEP_MAX_SAMPLES`, beyond which :func:`run_rate_batches` re-reads the file).
    One pass through the file: the PT100 readings are gathered
    while the rate streams (:func:`~gyrolab.record.reader.read_recording` ``on_rate``)."""
    acc = BlockAverager(cfg.block_s)
    hasher = RunHasher()
    batcher = RateBatcher()
    kept: list[RateBatch] | None = []  # for run_rate_batches, up to RATE_KEEP_MAX_SAMPLES

    def take(batch: RateBatch | None) -> None:
        nonlocal kept
        if batch is not None:
            t, x, period = batch
            acc.add(t, x, period)
            hasher.add_rate(x)
            if kept is not None:
                kept.append(batch)
                if hasher.n_rate > RATE_KEEP_MAX_SAMPLES:
                    kept = None  # too long to keep: the later passes stream the file

    rec = read_recording(
        path, topics=[TOPIC_PT100, TOPIC_RATE], unit=unit, on_rate=lambda b: take(batcher.add(b))
    )
    take(batcher.flush())
    pt_t, pt_c = _check_temperature(str(path), *rec.require_temperature())
    run = _finish(str(path), acc, pt_t, pt_c, cfg, None, unit, rec.interruptions)
    run.content_hash = hasher.hexdigest(pt_t, pt_c)
    run.temperature_source = rec.temperature_source
    run.serial = str(rec.run.get("unit_serial") or "")
    run.rate_batches = kept
    return run
