"""The one block averager: means of a rate over consecutive non-overlapping windows.

The paper records and models the gyro at 1000 points per hour (§4.1), i.e. the means of
consecutive :data:`PAPER_BLOCK_S` = 3.6 s blocks; every metric of docs/cli.md is taken on
that series. Two forms of the same operation:

* **by time** — :class:`BlockAverager` (streaming: feed sample batches in time order,
  memory is that of the averaged series) and :func:`block_average` (whole arrays). Block
  ``k`` holds the samples with ``k·b ≤ t − t₀ < (k+1)·b`` (``t₀`` the first sample, ``b``
  the block length, s); its centre is ``t₀ + (k + ½)·b``. A block with fewer than half its
  expected ``b / period`` samples (a recording gap) is filled by linear interpolation of
  its neighbours and counted, so the series stays uniformly sampled (VMD needs that); a
  trailing partial block is dropped. Across an interruption of a resumed run (``cut``:
  the recording's interruptions, docs/recording-format.md "Segments") nothing is filled:
  the blocks without enough samples that overlap one are left out, and the series jumps
  over the interruption.
* **by sample count** — :func:`block_means` for a series already uniformly sampled (e.g. the
  3.6 s series itself averaged again to 100 s): windows of ``round(window_s · fs)`` ≥ 1
  samples, a trailing partial window dropped.
"""

from __future__ import annotations

import numpy as np

from gyrolab.errors import InputError

__all__ = ["PAPER_BLOCK_S", "BlockAverager", "block_average", "block_means"]

PAPER_BLOCK_S = 3.6  # s: the paper's 1000 points per hour (§4.1)


class BlockAverager:
    """Streaming block means by time: feed sample batches in time order with :meth:`add`,
    read the result with :meth:`result`. Memory is that of the averaged series, so a
    47 M-sample run is decimated without holding its samples. Also counts non-finite
    samples (left out of the means) and tracks the range and duration that input checks
    need (:mod:`gyrolab.compensation.prepare`)."""

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
        """Add samples ``x`` at times ``t`` (s, increasing, after every earlier batch);
        ``period`` is the batch's nominal sample period (s)."""
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
        """Median nominal sample period of the batches (s); NaN before the first."""
        return float(np.median(self.periods)) if self.periods else float("nan")

    def result(
        self, cut: list[tuple[float, float]] | tuple[()] = ()
    ) -> tuple[np.ndarray, np.ndarray, int]:
        """Block centres (s), block means and the number of gap-filled blocks (module
        docstring); the blocks short of samples that overlap an interval of ``cut`` (s)
        are left out instead of filled."""
        if self.t_first is None or not self.period > 0:
            return np.empty(0), np.empty(0), 0
        n = self.n_bins
        if (self.t_last - self.t_first + self.period) < self.block_s * n * (1.0 - 1e-9):
            n -= 1  # trailing partial block
        expected = self.block_s / self.period
        s, c = self.sums[:n], self.counts[:n]
        tb = self.t_first + (np.arange(n) + 0.5) * self.block_s
        good = c >= 0.5 * expected
        keep = np.ones(n, dtype=bool)
        for a, b in cut:  # an interruption: its short blocks go, never filled in
            lo = tb - 0.5 * self.block_s
            keep &= good | (lo + self.block_s <= a) | (lo >= b)
        tb, s, c, good = tb[keep], s[keep], c[keep], good[keep]
        xb = np.full(tb.size, np.nan)
        xb[good] = s[good] / c[good]
        filled = int((~good).sum())
        if filled and good.sum() >= 2:
            xb[~good] = np.interp(tb[~good], tb[good], xb[good])
        return tb, xb, filled


def block_average(
    t: np.ndarray, x: np.ndarray, block_s: float, period: float
) -> tuple[np.ndarray, np.ndarray, int]:
    """:class:`BlockAverager` over whole arrays: ``x`` (any unit) at times ``t`` (s) with
    sample period ``period`` (s) averaged over consecutive ``block_s`` windows from
    ``t[0]``. Returns block centres, block means and the number of gap-filled blocks."""
    acc = BlockAverager(block_s)
    acc.add(np.asarray(t, dtype=float), x, period)
    return acc.result()


def block_means(x: np.ndarray, rate_hz: float, window_s: float) -> np.ndarray:
    """Means of consecutive non-overlapping windows of ``round(window_s · rate_hz)`` ≥ 1
    samples of a uniformly sampled ``x`` (``rate_hz``, Hz); a trailing partial window is
    dropped. Fewer than two windows, or a window that is not positive, is an
    :class:`~gyrolab.errors.InputError`."""
    if not window_s > 0:
        raise InputError(None, f"averaging window must be positive, got {window_s} s")
    w = max(1, int(round(window_s * rate_hz)))
    n = x.size // w
    if n < 2:
        raise InputError(
            None, f"series of {x.size} samples too short for two {window_s} s averaging windows"
        )
    return x[: n * w].reshape(n, w).mean(axis=1)
