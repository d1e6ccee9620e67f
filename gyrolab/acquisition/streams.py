"""One rate stream's recording: the ADC blocks a :class:`~gyrolab.instruments.roles.RateStream`
delivers, turned into gap-free ``/gyro/adc`` and ``/gyro/rate`` blocks on the run clock.

:class:`RateRecorder` is the bookkeeping of one stream (one unit): which device sample is
run sample 0, the next index expected, the block being filled, gaps (logged with their
cause), repeated samples (dropped, never written twice), damaged frames, and the tail of a
stream that stopped before the run ended. The run engine
(:class:`gyrolab.acquisition.runner.Acquisition`) keeps one per unit: the single-unit
bench's one stream is written to the single-unit topics (``unit=None``), a multi-unit
bench's to ``/unit/<serial>/…`` (docs/recording-format.md). A unit read by its internal
sensor also has its temperature readings recorded here, and handed to the engine's
temperature intake by :meth:`RateRecorder.take_readings` (the engine asks; the recorder
never calls back).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from gyrolab.instruments.roles import AdcBlock, AdcRead, RateStream, RateStreamConfig

# A stopped ADC stream (RateRecorder.record_tail_gap): a tail longer than this many times
# the stream's median arrival lag, and than TAIL_MIN_S run seconds, is a gap.
TAIL_LATENCY_FACTOR = 4.0
TAIL_MIN_S = 2.0


# ``log(level, source, message, kind, data, t)``: the engine's /log writer.
LogFn = Callable[..., None]


class RateRecorder:
    """Records one rate stream (see module doc). ``config`` is the stream's config (its
    ``block_s``, ``sample_rate_hz`` and counts → °/s conversion ``to_dps``); ``unit`` the
    serial of a multi-unit recording's unit (None: the single-unit layout)."""

    def __init__(
        self,
        device: RateStream,
        config: RateStreamConfig,
        writer: Any,
        log: LogFn,
        *,
        unit: str | None = None,
        on_samples: Callable[[float], None] | None = None,
        internal: bool = False,
    ) -> None:
        self.dev = device
        self.config = config
        self.w = writer
        self.log = log
        self.unit = unit
        self.on_samples = on_samples
        # A unit on its internal sensor (a multi-unit recording's unit): the readings its
        # blocks carry go to /unit/<serial>/temperature/internal, averaged per recorded
        # block, and each average to ``readings`` until the engine takes it.
        self.internal = internal and unit is not None
        # (run time, °C, run index of its sample) not yet written
        self._temps: list[tuple[float, float, float]] = []
        self._readings: list[tuple[float, float]] = []  # written, not yet taken
        self.dropped = False  # a multi-unit run gave up on this stream
        # A resumed run's continuation (acquire --resume; the engine sets both): the run
        # index after the last sample the segments before it hold with its run time, and
        # the run time the continuation starts. Its first sample's run index is that index
        # plus the periods between the two times: the samples between are the
        # interruption's gap.
        self.resume_index: tuple[int, float] | None = None
        self.t_start = 0.0
        self._base = 0  # run index of device sample idx0
        # Device index of the first sample, next expected index, block buffer.
        self.idx0: int | None = None
        self._adc_offset = 0.0  # ADC clock minus run time
        self._blk_t0 = 0.0
        self._next_idx: int | None = None
        self._blk: list[np.ndarray] = []
        self._blk_first = 0
        self._blk_n = 0
        self._block_len = max(1, int(round(config.block_s * config.sample_rate_hz)))
        self.period = 1.0 / config.sample_rate_hz
        self.samples = 0
        self.received_to = -math.inf  # run time up to which samples have arrived
        self.gaps = 0
        self.missing = 0
        self.dups = 0
        self.faults = 0  # port faults (disconnects, failed opens)
        self._counters_seen: dict[str, int] = {}
        # Arrival lag (arrival run time - end of the samples that arrived) of recent
        # blocks: the stream's normal latency, against which a stopped stream is judged.
        self._adc_lags: deque[float] = deque(maxlen=200)

    @property
    def name(self) -> str:
        """The stream's source name in /log (``adc``; a multi-unit run's ``unit/<serial>``)."""
        return self.dev.name

    def behind(self, t_end: float) -> bool:
        """Whether samples up to run time ``t_end`` are still to arrive."""
        return (
            not self.dropped
            and self.idx0 is not None
            and self.received_to < t_end - 0.5 * self.period
        )

    def on_read(self, got: AdcRead, t: float, ok: Callable[[], None]) -> None:
        """What one read delivered at run time ``t`` (arrival): port events logged, then
        ``ok()`` if samples came, then the blocks, then damaged-frame counts."""
        for ev in got.events:
            kind = getattr(ev, "kind", "event")
            if kind == "gap":
                continue  # logged below from the sample indices, with the cause
            level, tag = {
                "disconnect": ("warning", "fault"),
                "open_failed": ("warning", "fault"),
                "reconnect": ("info", "recovery"),
            }.get(kind, ("info", kind))
            if tag == "fault":
                self.faults += 1
            self.log(
                level,
                self.name,
                f"ADC port {kind}: {ev.message}",
                tag,
                dict(getattr(ev, "data", {}) or {}),
                t,
            )
        if got.blocks:
            ok()
            causes = sorted({str(getattr(g, "cause", "lost")) for g in got.gaps})
            for blk in got.blocks:
                self._on_block(blk, t, causes)
        self._log_counter_changes(t)

    def _on_block(self, blk: AdcBlock, t_arrival: float, causes: list[str]) -> None:
        counts = np.asarray(blk.counts, dtype=np.int32)  # (n,) or (n, axes)
        idx = int(blk.first_index)
        n = int(len(counts))
        if n == 0:
            return
        if self.idx0 is None:
            # Run time of sample 0: its block's arrival less the block's length; from then
            # on sample times follow the ADC's own clock (frame timestamps), not arrival.
            t_first = max(self.t_start, t_arrival - n * self.period)
            self._adc_offset = float(blk.t0) - t_first
            if self.resume_index is not None:
                nxt, t_next = self.resume_index
                self._base = nxt + max(0, int(round((t_first - t_next) / self.period)))
            self.idx0 = idx
            self._next_idx = idx
            self._blk_first = self._base
            self.log(
                "info",
                self.name,
                f"ADC stream: run sample {self._base} is device sample {idx}",
                "startup",
                {"device_index": idx}
                | ({"run_index": self._base} if self.resume_index is not None else {}),
                t_arrival,
            )
            if self.resume_index is not None and self._base > self.resume_index[0]:
                self._interrupted(t_first, t_arrival)
        assert self._next_idx is not None
        if self.internal and blk.temperature_c is not None:
            self._take_temperatures(blk)
        if idx < self._next_idx:
            # Some or all of these samples were written already: never write one twice.
            dup = min(n, self._next_idx - idx)
            self.dups += 1
            self.log(
                "warning",
                self.name,
                f"dropped {dup} repeated ADC sample(s) at index {self._run(idx)}",
                "duplicate",
                {"index": self._run(idx), "samples": dup},
                t_arrival,
            )
            if dup == n:
                return
            counts = counts[dup:]
            idx += dup
            n -= dup
            t0_dev = float(blk.t0) + dup * self.period
        else:
            t0_dev = float(blk.t0)
        if idx > self._next_idx:
            missing = idx - self._next_idx
            self.emit_block()
            self.gaps += 1
            self.missing += missing
            first = self._run(self._next_idx)
            self.log(
                "warning",
                self.name,
                f"ADC gap: {missing} sample(s) missing from index {first}",
                "gap",
                {
                    "first_missing_index": first,
                    "n_missing": missing,
                    "t_first_missing": round(t0_dev - self._adc_offset - missing * self.period, 6),
                    "cause": ",".join(causes) or "lost",
                },
                t_arrival,
            )
            self._blk_first = self._run(idx)
        if not self._blk_n:
            self._blk_t0 = t0_dev - self._adc_offset
        self._blk.append(counts)
        self._blk_n += n
        self._next_idx = idx + n
        self.received_to = t0_dev - self._adc_offset + n * self.period
        self._adc_lags.append(t_arrival - self.received_to)
        if self.on_samples is not None:
            # Received, not yet necessarily on disk: what a crash-loss measurement needs.
            self.on_samples(self.received_to)
        if self._blk_n >= self._block_len:
            self.emit_block()

    def _run(self, device_index: int) -> int:
        """The run index of device sample ``device_index``."""
        assert self.idx0 is not None
        return device_index - self.idx0 + self._base

    def _interrupted(self, t_first: float, t: float) -> None:
        """A continuation's first sample: the run's samples since the last one the
        segments before it hold are a gap, logged as such (never filled in)."""
        assert self.resume_index is not None
        nxt, t_next = self.resume_index
        missing = self._base - nxt
        self.gaps += 1
        self.missing += missing
        self.log(
            "warning",
            self.name,
            f"ADC gap: {missing} sample(s) missing from index {nxt}: the run was "
            "interrupted and resumed",
            "gap",
            {
                "first_missing_index": nxt,
                "n_missing": missing,
                "t_first_missing": round(t_next, 6),
                "t_resumed": round(t_first, 6),
                "cause": "run interrupted",
            },
            t,
        )

    def _take_temperatures(self, blk: AdcBlock) -> None:
        """Keep the internal-temperature readings of samples not recorded yet (a repeated
        frame's reading is dropped with its samples), on the run clock."""
        assert self._next_idx is not None
        k = np.arange(len(blk.temperature_c))
        first = int(blk.first_index) + k * int(blk.samples_per_reading)
        new = first >= self._next_idx
        t = float(blk.t0) + (first - int(blk.first_index)) * self.period - self._adc_offset
        vals = np.asarray(blk.temperature_c, dtype=float)
        run = first - self.idx0 + self._base if self.idx0 is not None else first
        self._temps += [
            (float(a), float(b), float(r))
            for a, b, r in zip(t[new], vals[new], run[new], strict=True)
        ]

    def _emit_temperature(self) -> None:
        """Write the readings kept since the last block, one message (their mean) per
        ``block_s`` of samples they were taken at — however many samples one read brought
        — and keep each for :meth:`take_readings`."""
        if not self._temps or not self.internal:
            return
        a = np.asarray(self._temps)
        self._temps = []
        span = a[:, 2] // self._block_len
        for b in np.unique(span):
            group = a[span == b]
            t, c = group[:, :2].mean(axis=0)
            self.w.write_internal_temperature(float(t), float(c), len(group), unit=self.unit)
            self._readings.append((float(t), float(c)))

    def take_readings(self) -> list[tuple[float, float]]:
        """The internal-sensor readings recorded since the last call, ``(run time, °C)``
        each (one per recorded block), for the engine's temperature intake."""
        out, self._readings = self._readings, []
        return out

    def emit_block(self) -> None:
        """Write the block being filled (``/gyro/adc`` and ``/gyro/rate``), and the unit's
        internal temperature readings of it."""
        self._emit_temperature()
        if not self._blk_n:
            return
        counts = np.concatenate(self._blk) if len(self._blk) > 1 else self._blk[0]
        t0 = self._blk_t0
        if self.unit is None:
            self.w.write_adc_block(t0, self.period, self._blk_first, counts)
            self.w.write_rate_block(t0, self.period, self._blk_first, self.config.to_dps(counts))
        else:
            u = self.unit
            self.w.write_adc_block(t0, self.period, self._blk_first, counts, unit=u)
            dps = self.config.to_dps(counts)
            self.w.write_rate_block(t0, self.period, self._blk_first, dps, unit=u)
        self.samples += len(counts)
        self._blk_first += len(counts)
        self._blk = []
        self._blk_n = 0

    def _log_counter_changes(self, t: float) -> None:
        c = self.dev.counters()
        bad = int(c.get("frames_bad", 0)) - self._counters_seen.get("frames_bad", 0)
        if bad > 0:
            # Damaged frames are dropped by the reader (CRC); say so, with the totals.
            self.log(
                "warning",
                self.name,
                f"{bad} damaged ADC frame(s) rejected "
                "(CRC/framing); their samples are reported as gaps",
                "corruption",
                {k: int(v) for k, v in c.items()},
                t,
            )
        self._counters_seen = {k: int(v) for k, v in c.items()}

    def record_tail_gap(self, t_stop: float) -> None:
        """A stream that stopped before the run ended: a gap from the sample after the
        last one received up to ``t_stop`` (the gap count and samples missing say so).

        A tail within the stream's normal latency (``TAIL_LATENCY_FACTOR`` × its median
        arrival lag, at least ``TAIL_MIN_S``) is samples in flight when the run stopped,
        not a stopped stream, and is not counted."""
        start = self.t_start if self.idx0 is None else self.received_to
        lag = float(np.median(self._adc_lags)) if self._adc_lags else 0.0
        tail = t_stop - start
        if not math.isfinite(tail) or tail <= max(TAIL_MIN_S, TAIL_LATENCY_FACTOR * lag):
            return
        missing = int(round(tail / self.period))
        first = self._base if self._next_idx is None else self._run(self._next_idx)
        self.gaps += 1
        self.missing += missing
        what = "never started" if self.idx0 is None else "stopped"
        self.log(
            "warning",
            self.name,
            f"ADC gap: stream {what}; {missing} sample(s) missing from index {first} "
            f"to the end of the run ({tail:.1f} s)",
            "gap",
            {
                "first_missing_index": first,
                "n_missing": missing,
                "t_first_missing": round(start, 6),
                "t_end": round(t_stop, 6),
                "cause": f"stream {what}",
            },
            t_stop,
        )
