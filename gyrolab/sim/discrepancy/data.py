"""What the discrepancy workflow sees of a run: the bench channels, decimated early.

Only what a real bench records is read: ``/gyro/rate``, ``/temperature/pt100`` (or a
unit's ``/unit/<serial>/temperature/internal``, its die sensor, when it has no PT100),
``/oven/state`` and, of the metadata, the ``bench`` record (the multimeter's model and
range, for its PT100 test current); no other metadata record (where a simulator stores
its provenance) is decoded. A die sensor's readings are marked as such
(``temperature_source``): the thermal fit models the die behind the case.

The 100 Hz rate stream is reduced in one pass to

* low-frequency bin means ``y_j`` over ``bin_s`` seconds (deterministic effects live
  below ~0.01 Hz, so 10 s bins lose nothing and a 13 h run becomes 4 680 points);
* high-rate statistics: the robust white-noise level, isolated spikes (outliers), the
  output's value lattice (quantization), first differences for the sample-distribution
  gap, and the Allan deviation at τ shorter than one bin.

Spikes are detected by the centred second difference
``e_i = x_i − (x_{i−1} + x_{i+1})/2`` against ``k · 1.4826 · MAD(e)`` (k = 8: a Gaussian
exceeds it once in ~10¹⁵ samples) and replaced by the mean of their neighbours before
binning, so that a bad sample does not leak into the low-frequency fit.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gyrolab.errors import InputError
from gyrolab.numerics.allan import allan_deviation
from gyrolab.pt100 import fres_test_current_a
from gyrolab.record.blocks import decode_block
from gyrolab.record.format import (
    TOPIC_EVENT,
    TOPIC_OVEN,
    TOPIC_PT100,
    TOPIC_RATE,
    TOPIC_TEMPERATURE_INTERNAL,
)
from gyrolab.record.reader import iter_messages, read_bench_record

SPIKE_K = 8.0
"""Spike threshold in robust standard deviations of the centred second difference."""
TAIL_K = 3.0
"""Lower edge of the tail of |e| kept for the outlier mixture fit (robust σ units)."""


@dataclass
class HighRate:
    """Statistics of the full-rate gyro stream (units °/s unless stated)."""

    dt: float
    n: int
    white_sigma: float
    """Robust per-sample standard deviation of the white part: 1.4826·MAD(Δx)/√2."""
    spike_t: np.ndarray
    spike_amp: np.ndarray
    """Times (s) and heights (°/s) of the certain spikes (> SPIKE_K σ_e), removed."""
    e_sigma: float
    """Robust σ of the centred second difference ``e`` (°/s)."""
    e_tail: np.ndarray
    """Every |e| above ``TAIL_K · e_sigma``: the tail the outlier test fits."""
    lattice_step: float
    """Estimated spacing of the output's values (0 when the values look continuous)."""
    lattice_fraction: float
    """Fraction of first differences that are integer multiples of ``lattice_step``."""
    diffs: np.ndarray
    """A contiguous sample of first differences Δx (despiked), for distribution checks."""
    tau: np.ndarray
    adev: np.ndarray


@dataclass
class Step:
    """One constant-setpoint segment of the oven channel."""

    index: int
    t0: float
    t1: float
    setpoint_c: float


@dataclass
class BenchData:
    """Arrays of one run, as the workflow uses them."""

    t: np.ndarray
    """Bin centres, s since power-on."""
    y: np.ndarray
    """Gyro output, bin means, °/s."""
    bin_s: float
    temp_c: np.ndarray
    """PT100 temperature at the bin centres, °C."""
    pt100_t: np.ndarray
    pt100_c: np.ndarray
    oven_t: np.ndarray
    oven_sp: np.ndarray
    oven_pv: np.ndarray
    hr: HighRate
    steps: list[Step] = field(default_factory=list)
    source: str = "<arrays>"
    pt100_current_a: float | None = None
    """The multimeter's PT100 test current (A) from the bench record, when known."""
    temperature_source: str = "pt100"
    """``pt100`` (a PT100 on the case: ``pt100_*`` are its readings) or ``die`` (a unit's
    internal sensor: ``pt100_*`` hold the die readings; docs/discrepancy.md)."""

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0] + self.bin_s)


def choose_bin_s(duration_s: float) -> float:
    """10 s bins, shorter for short runs so that there are at least ~2 000 bins."""
    return float(np.clip(np.floor(duration_s / 2000.0), 1.0, 10.0))


def _spikes(x: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Indices of certain spikes, the robust σ of the centred second difference and the
    tail of |e| (every value above ``TAIL_K σ``)."""
    e = x[1:-1] - 0.5 * (x[:-2] + x[2:])
    sub = e[:: max(1, e.size // 400_000)]
    s = 1.4826 * float(np.median(np.abs(sub - np.median(sub))))
    if s <= 0:
        return np.empty(0, dtype=np.int64), s, np.empty(0)
    ae = np.abs(e)
    big = np.flatnonzero(ae > TAIL_K * s)
    # A spike at i also makes e_{i±1} ≈ −A/2: keep only the local maxima of |e|.
    lo = np.clip(big - 1, 0, e.size - 1)
    hi = np.clip(big + 1, 0, e.size - 1)
    peak = big[(ae[big] >= ae[lo]) & (ae[big] >= ae[hi])]
    certain = peak[ae[peak] > SPIKE_K * s]
    return certain + 1, s, ae[big]


def _lattice_of(v: np.ndarray, d: np.ndarray, scale: float) -> tuple[float, float]:
    """Spacing of the sorted distinct magnitudes ``v`` and the fraction of ``d`` on it."""
    u = np.unique(v)
    if u.size < 3:
        return 0.0, 0.0
    du = np.diff(u)
    # Values stored as float32: spacings closer than its resolution are not a lattice.
    tol = 4.0 * np.finfo(np.float32).eps * max(1e-12, scale)
    du = du[du > tol]
    if du.size == 0:
        return 0.0, 0.0
    q = float(np.median(du[du <= 1.5 * np.min(du)]))
    r = d / q
    return q, float(np.mean(np.abs(r - np.rint(r)) < 0.05))


def lattice_coherence(d: np.ndarray, q: float, window: int = 256) -> float:
    """How firmly the differences ``d`` sit on multiples of ``q`` up to a slowly varying
    offset: the mean over windows of ``|mean exp(2πi d/q)|`` (1 on a lattice whose
    offset — a bias drift added after the quantizer — is constant within a window,
    ≈ 1/√window for a continuum)."""
    n = (d.size // window) * window
    if n == 0 or q <= 0:
        return 0.0
    z = np.exp(2j * np.pi * d[:n] / q).reshape(-1, window)
    return float(np.mean(np.abs(z.mean(axis=1))))


def _lattice(x: np.ndarray) -> tuple[float, float]:
    """Output lattice ``q`` and how firmly the first differences Δx sit on it (the fraction
    on multiples of it for a value lattice, :func:`lattice_coherence` for a lattice in
    the differences).

    Two estimates, the better supported kept: the spacing of the distinct output values
    (a quantizer whose codes are the output), and the spacing of the clusters of |Δx| (a
    digital gyro that adds a slowly varying bias *after* quantizing: its values are off
    any lattice, their differences are not). The first cluster boundary of the sorted
    |Δx| is the first jump larger than half the value it lands on, with at least 0.02 %
    of the differences below it (a continuum has no such jump: its gaps are of order
    range/n) and larger than float32's resolution of the values; the step is the median
    of the cluster above it (of the first 20 such jumps, the one with most differences on
    its lattice, its step refined within ±3 % to the most coherent).
    """
    sub = x[: min(x.size, 200_000)]
    d = np.diff(sub)
    scale = float(np.max(np.abs(sub))) if sub.size else 1.0
    best = _lattice_of(sub, d, scale)
    a = np.sort(np.abs(d))
    if a.size > 1000:
        g = np.diff(a)
        j0 = max(1, int(2e-4 * a.size))
        # float32 storage puts the differences on a grid of ~eps·|x|: not a lattice
        floor = 64.0 * float(np.finfo(np.float32).eps) * max(scale, 1e-12)
        jump = np.flatnonzero((g[j0:] > 0.5 * a[j0 + 1 :]) & (g[j0:] > floor))
        # the first few jumps are candidates (a sparse tail of the zero cluster — a
        # slow bias drift — can jump too); the one most coherent wins, refined
        for jj in jump[:20]:
            first = float(a[j0 + jj + 1])
            q2 = float(np.median(a[(a >= first) & (a <= 1.5 * first)]))
            c2 = lattice_coherence(d, q2)
            if c2 > 0.5 and c2 > best[1] + 0.2:
                grid = q2 * np.linspace(0.97, 1.03, 121)
                sub_d = d[:50_000]
                coh = [lattice_coherence(sub_d, float(g)) for g in grid]
                q2 = float(grid[int(np.argmax(coh))])
                best = (q2, lattice_coherence(d, q2))
    return best


def high_rate_stats(
    x: np.ndarray, dt: float, bin_n: int, n_diffs: int = 500_000
) -> tuple[HighRate, np.ndarray, np.ndarray]:
    """High-rate statistics of ``x``; returns them, the despiked series and spike indices."""
    idx, e_sigma, e_tail = _spikes(x)
    xd = x
    amps = np.empty(0)
    if idx.size:
        xd = x.copy()
        lo = np.clip(idx - 1, 0, x.size - 1)
        hi = np.clip(idx + 1, 0, x.size - 1)
        fill = 0.5 * (x[lo] + x[hi])
        amps = x[idx] - fill
        xd[idx] = fill
    d = np.diff(x[: min(x.size, n_diffs + 1)])
    white = 1.4826 * float(np.median(np.abs(d - np.median(d)))) / np.sqrt(2.0)
    q, frac = _lattice(x)  # raw: despiking fills in off-lattice means
    m = 2 ** np.arange(int(np.floor(np.log2(max(1, bin_n)))) + 1)
    # the overlapping ADEV alone (no confidence work) at the octave taus up to one bin
    adev = allan_deviation(xd, 1.0 / dt, taus=m * dt, confidence=None, allow_constant=True)
    tau, ad = adev.taus, adev.dev
    hr = HighRate(
        dt=dt,
        n=int(x.size),
        white_sigma=white,
        spike_t=idx * dt,
        spike_amp=amps,
        e_sigma=e_sigma,
        e_tail=e_tail,
        lattice_step=q,
        lattice_fraction=frac,
        diffs=d,
        tau=tau,
        adev=ad,
    )
    return hr, xd, idx


def steps_from_setpoint(t: np.ndarray, sp: np.ndarray, t_end: float) -> list[Step]:
    """Constant-setpoint segments of the oven setpoint channel."""
    if t.size == 0:
        return []
    change = np.flatnonzero(np.abs(np.diff(sp)) > 1e-6) + 1
    starts = np.concatenate([[0], change])
    out = []
    for k, s in enumerate(starts):
        t1 = float(t[starts[k + 1]]) if k + 1 < starts.size else float(t_end)
        out.append(Step(k, float(t[s]), t1, float(sp[s])))
    return out


def from_arrays(
    rate_t0: float,
    rate_dt: float,
    rate: np.ndarray,
    pt100_t: np.ndarray,
    pt100_c: np.ndarray,
    oven_t: np.ndarray,
    oven_sp: np.ndarray,
    oven_pv: np.ndarray,
    *,
    rate_index: np.ndarray | None = None,
    bin_s: float | None = None,
    source: str = "<arrays>",
) -> BenchData:
    """Build :class:`BenchData` from bench arrays (rate samples at ``rate_t0 + k·rate_dt``,
    or at ``rate_t0 + rate_index·rate_dt`` when the stream has gaps)."""
    x = np.asarray(rate, dtype=float)
    if x.size < 100:
        raise InputError(source, "too few gyro rate samples for a discrepancy analysis")
    if np.asarray(pt100_t).size < 10 or np.asarray(oven_t).size < 10:
        raise InputError(source, "too few temperature/oven samples for a discrepancy analysis")
    index = np.arange(x.size) if rate_index is None else np.asarray(rate_index, dtype=np.int64)
    duration = (index[-1] - index[0] + 1) * rate_dt
    bs = choose_bin_s(duration) if bin_s is None else float(bin_s)
    bin_n = max(1, int(round(bs / rate_dt)))
    bs = bin_n * rate_dt
    hr, xd, _ = high_rate_stats(x, rate_dt, bin_n)
    b = (index - index[0]) // bin_n
    cnt = np.bincount(b)
    ysum = np.bincount(b, weights=xd)
    ok = cnt >= max(1, bin_n // 2)
    bins = np.flatnonzero(ok)
    y = ysum[ok] / cnt[ok]
    t = rate_t0 + (index[0] + (bins + 0.5) * bin_n) * rate_dt
    pt_t = np.asarray(pt100_t, dtype=float)
    pt_c = np.asarray(pt100_c, dtype=float)
    temp = np.interp(t, pt_t, pt_c)
    ot = np.asarray(oven_t, dtype=float)
    sp = np.asarray(oven_sp, dtype=float)
    pv = np.asarray(oven_pv, dtype=float)
    return BenchData(
        t=t,
        y=y,
        bin_s=bs,
        temp_c=temp,
        pt100_t=pt_t,
        pt100_c=pt_c,
        oven_t=ot,
        oven_sp=sp,
        oven_pv=pv,
        hr=hr,
        steps=steps_from_setpoint(ot, sp, float(t[-1] + bs / 2)),
        source=source,
    )


Bench = tuple[float, float, np.ndarray, np.ndarray, np.ndarray, np.ndarray, float | None, str]


def _read_bench(path: str | os.PathLike[str], unit: str | None) -> Bench:
    """The bench channels of a recording: rate start and period, rate samples (n, or
    n × axes), their indices, temperature rows (t, °C), oven rows (t, SP, PV), the PT100
    test current (A, or None) and the temperature's source (``pt100`` or ``die``)."""
    blocks = []
    pt: list[tuple[float, float]] = []
    oven: list[tuple[float, float, float]] = []
    topics = [TOPIC_RATE, TOPIC_PT100, TOPIC_OVEN]
    if unit is not None:  # a unit on its internal sensor records that instead of a PT100
        topics.append(TOPIC_TEMPERATURE_INTERNAL)
    internal: list[tuple[float, float]] = []
    for topic, _ts, data in iter_messages(path, topics, unit=unit):
        if topic == TOPIC_TEMPERATURE_INTERNAL:
            m = json.loads(data)
            internal.append((m["t"], m["temperature_c"]))
        elif topic == TOPIC_RATE:
            blocks.append(decode_block(data, "rate"))
        elif topic == TOPIC_PT100:
            m = json.loads(data)
            pt.append((m["t"], m["temperature_c"]))
        elif topic == TOPIC_OVEN:
            m = json.loads(data)
            oven.append((m["t"], m["setpoint_c"], m["process_value_c"]))
    if not blocks:
        raise InputError(path, f"recording has no {TOPIC_RATE} data")
    source = "pt100"
    if not pt and internal:
        # a die sensor: the thermal fit models its lag behind the case and its offset
        pt, source = internal, "die"
    if not pt:
        raise InputError(path, f"recording has no {TOPIC_PT100} data")
    if not oven:
        raise InputError(path, f"recording has no {TOPIC_OVEN} data")
    blocks.sort(key=lambda b: b[2])
    period = float(np.median([b[1] for b in blocks]))
    n = sum(b[3].shape[0] for b in blocks)
    x = np.empty((n,) + blocks[0][3].shape[1:])
    idx = np.empty(n, dtype=np.int64)
    pos = 0
    for _t0, _p, first, arr in blocks:
        k = arr.shape[0]
        x[pos : pos + k] = arr
        idx[pos : pos + k] = first + np.arange(k)
        pos += k
    t0 = blocks[0][0] - blocks[0][2] * period
    current = pt100_current_a(read_bench_record(path)) if source == "pt100" else None
    pts = np.asarray(sorted(pt), dtype=float)
    return t0, period, x, idx, pts, np.asarray(sorted(oven)), current, source


def pt100_current_a(bench: dict[str, Any] | None) -> float | None:
    """The PT100 test current (A) of the meter a ``bench`` record names (its
    ``multimeter``, or a multi-unit bench's ``scanner``): an ``excitation_current_a`` it
    records, else the meter's documented current on its range (:mod:`gyrolab.pt100`)."""
    for key in ("multimeter", "scanner"):
        m = (bench or {}).get(key)
        if isinstance(m, dict):
            i = m.get("excitation_current_a")
            if isinstance(i, (int, float)) and i > 0:
                return float(i)
            r = m.get("range_ohm")
            return fres_test_current_a(
                str(m.get("model", "")), float(r) if isinstance(r, (int, float)) else None
            )
    return None


def _bench_data(
    bench: Bench,
    column: np.ndarray,
    bin_s: float | None,
    source: str,
) -> BenchData:
    """:class:`BenchData` of one rate column of what :func:`_read_bench` returned."""
    t0, period, _x, idx, p, o, current, source = bench
    d = from_arrays(
        t0,
        period,
        column,
        p[:, 0],
        p[:, 1],
        o[:, 0],
        o[:, 1],
        o[:, 2],
        rate_index=idx,
        bin_s=bin_s,
        source=source,
    )
    d.pt100_current_a = current
    d.temperature_source = source
    return d


def load_recording(
    path: str | os.PathLike[str], bin_s: float | None = None, unit: str | None = None
) -> BenchData:
    """Read the bench channels of a recording (never its metadata) into :class:`BenchData`."""
    bench = _read_bench(path, unit)
    x = bench[2]
    if x.ndim > 1:
        raise InputError(
            path,
            f"a {x.shape[1]}-axis recording: the discrepancy analysis models "
            "one gyro axis (simulate the axes one by one)",
        )
    return _bench_data(bench, x, bin_s, str(path))


def load_recording_axes(
    path: str | os.PathLike[str], bin_s: float | None = None, unit: str | None = None
) -> list[BenchData]:
    """One :class:`BenchData` per gyro axis of a recording (one for a single-axis one),
    all with the same temperature channels, for
    :func:`gyrolab.sim.discrepancy.axes_workflow.run_discrepancy_axes`."""
    bench = _read_bench(path, unit)
    cols = bench[2] if bench[2].ndim > 1 else bench[2][:, None]
    return [
        _bench_data(bench, cols[:, k], bin_s, f"{path} (axis {k})") for k in range(cols.shape[1])
    ]


_ = TOPIC_EVENT  # profile events are not needed: steps come from the setpoint channel
