"""Flicker-noise chunks made ahead of time, in another thread: the same numbers, and the
simulated bench never makes one while holding its physics lock (a chunk costs 0.1-0.3 s,
during which every Modbus/SCPI reply used to wait)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np
import pytest

from gyrolab.sim import noise
from gyrolab.sim.bench import SimBench
from gyrolab.sim.model import SimModel, make_effect_spec, nominal_model
from gyrolab.sim.noise import FlickerStream, effect_rng
from gyrolab.sim.physics import Physics


def _hammer(fn: Callable[[], None], stop: threading.Event, pause_s: float) -> threading.Thread:
    """Call ``fn`` in a loop in another thread until ``stop``."""

    def run() -> None:
        while not stop.is_set():
            fn()
            time.sleep(pause_s)

    th = threading.Thread(target=run, daemon=True)
    th.start()
    return th


def test_flicker_prefetch_from_another_thread_changes_nothing() -> None:
    def make() -> FlickerStream:
        return FlickerStream(1.0, effect_rng(0, "bias_instability"), nfft=1 << 10, chunk=1 << 7)

    whole = make().value_at(0, 60_000, 100.0)
    fl = make()
    pos = {"i": 0}
    stop = threading.Event()
    # Races the consumer at every chunk boundary: prefetching 0-3 chunks ahead of it.
    rng = np.random.default_rng(2)
    th = _hammer(lambda: fl.prefetch(pos["i"], int(rng.integers(1, 4000)), 100.0), stop, 0.0)
    parts, i = [], 0
    try:
        while i < 60_000:
            n = int(min(np.random.default_rng(i).integers(1, 900), 60_000 - i))
            parts.append(fl.value_at(i, n, 100.0))
            i += n
            pos["i"] = i
    finally:
        stop.set()
        th.join(2.0)
    np.testing.assert_array_equal(whole, np.concatenate(parts))
    assert len(fl._chunks) <= 4  # still bounded: behind dropped, at most a few ahead


def test_physics_prefetch_across_chunk_boundaries_is_bit_identical() -> None:
    # 10 Hz ADC: the default 3.6 h flicker chunk is 131072 samples; run past two.
    m = SimModel(effects=(make_effect_spec("arw"), make_effect_spec("bias_instability")))
    plain = Physics(m, rate_hz=10.0, seed=5)
    ahead = Physics(m, rate_hz=10.0, seed=5)
    stop = threading.Event()
    th = _hammer(lambda: ahead.prefetch(40_000), stop, 0.002)
    try:
        a = np.concatenate([plain.advance(5_000).rate_dps for _ in range(60)])
        b = np.concatenate([ahead.advance(5_000).rate_dps for _ in range(60)])
    finally:
        stop.set()
        th.join(5.0)
    np.testing.assert_array_equal(a, b)


def test_bench_never_makes_a_noise_chunk_under_its_lock(monkeypatch: pytest.MonkeyPatch) -> None:
    made: list[tuple[int, str, bool]] = []  # (chunk, thread, bench lock held by it)
    bench_box: list[SimBench] = []
    real = noise.FlickerStream._make_chunk

    def spy(self: FlickerStream) -> None:
        held = bool(bench_box) and bench_box[0].lock._is_owned()  # type: ignore[attr-defined]
        made.append((self._next, threading.current_thread().name, held))
        real(self)

    monkeypatch.setattr(noise.FlickerStream, "_make_chunk", spy)
    physics = Physics(nominal_model(), rate_hz=10.0, seed=0)
    physics.advance(95_000)  # 9500 s: chunk 1 (from 13107 s) is due within the hour ahead
    made.clear()
    bench = SimBench(physics, speed=20.0, tcp=False)
    bench_box.append(bench)
    with bench:
        # Until it is made or the clock nears the time it is needed (9.5 ks to 13 ks at 20x:
        # about 175 s of wall), not a fixed 10 s of wall time that load could use up
        while not any(c == 1 for c, _, _ in made) and bench.clock.now() < 13_000.0:
            time.sleep(0.01)
        assert bench.clock.now() < 13_000.0  # made ahead, long before it is needed
    assert [(c, name) for c, name, _ in made] == [(1, "sim-bench-prefetch")]
    assert not any(held for _, _, held in made)
    assert bench.error is None


def test_bench_start_makes_the_first_chunk_before_the_first_tick(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    names: list[str] = []
    real = noise.FlickerStream._make_chunk

    def spy(self: FlickerStream) -> None:
        names.append(threading.current_thread().name)
        real(self)

    monkeypatch.setattr(noise.FlickerStream, "_make_chunk", spy)
    with SimBench(speed=20.0, tcp=False) as bench:
        bench.clock.wait_until(1.0, timeout_wall_s=5.0)
    # Made once, in start() (the warm-up copy reuses it), never by the tick thread.
    assert names == [threading.current_thread().name]
