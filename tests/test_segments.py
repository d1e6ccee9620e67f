"""A resumed run's segments read as one run (gyrolab/record/reader.py ``segments``;
docs/recording-format.md "Segments"), on small files written here: the interruption is a
gap nobody fills in — not the reader, not apply's copy, not the 3.6 s averaging — and a
continuation whose earlier segment is missing or foreign is refused in one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gyrolab.acquisition.resume import bench_differences, resume_point
from gyrolab.errors import InputError
from gyrolab.numerics.averaging import BlockAverager
from gyrolab.profiles.profile import Profile, Step
from gyrolab.record.reader import iter_messages, read_metadata, read_recording, segments
from gyrolab.record.rewrite import rewrite_recording
from gyrolab.record.writer import RecordingWriter

START_NS = 1_700_000_000_000_000_000
PROFILE = Profile("p", (Step(25.0, 10.0), Step(35.0, 20.0), Step(30.0, 10.0))).to_dict()


def _segment(path: Path, run: dict, t0: float, t1: float, index0: int, events=()) -> None:
    """Samples at 100 Hz from ``t0`` to ``t1`` (run s) with run indices from ``index0``,
    a PT100 reading a second, the ``events``."""
    w = RecordingWriter(path, start_time_ns=START_NS, run=run, bench={"name": "b"})
    for t, event, step in events:
        w.write_event(t, event, step, None, "")
    n = round((t1 - t0) * 100)
    for k in range(0, n, 50):
        counts = np.arange(index0 + k, index0 + k + 50, dtype=np.int32)
        w.write_adc_block(t0 + k / 100, 0.01, index0 + k, counts)
        w.write_rate_block(t0 + k / 100, 0.01, index0 + k, counts * 1e-3)
    for t in np.arange(t0, t1, 1.0):
        w.write_pt100(float(t), 110.0, 25.0 + 0.1 * t)
    w.close()


def _run(tmp_path: Path, previous: str = "seg1.mcap", run_id: str = "r1") -> Path:
    first = {"source": "acquire", "profile": PROFILE, "run_id": "r1", "segment": 1}
    _segment(
        tmp_path / "seg1.mcap",
        first,
        0.0,
        15.0,
        0,
        [(0.0, "run_started", -1), (0.0, "step_started", 0), (10.0, "step_ended", 0)],
    )
    cont = {
        **first,
        "run_id": run_id,
        "segment": 2,
        "previous_segment": {"file": previous, "segment": 1, "run_id": run_id},
        "resumed": {"after_t": 15.0, "at_t": 40.0, "step": 1},
    }
    _segment(tmp_path / "seg2.mcap", cont, 40.0, 70.0, 4000, [(40.0, "run_resumed", 1)])
    return tmp_path / "seg2.mcap"


def test_the_last_segment_reads_the_whole_run_with_its_gap_unfilled(tmp_path: Path) -> None:
    last = _run(tmp_path)
    assert segments(last) == [tmp_path / "seg1.mcap", last]
    rec = read_recording(last)
    rate = rec.require_rate()
    assert rate.t.size == 1500 + 3000 and rate.gaps() == [(pytest.approx(14.99), 2500)]
    assert not ((rate.t > 15.0) & (rate.t < 40.0)).any()  # nothing in the gap
    assert rec.interruptions == [(15.0, 40.0)]
    assert [s["file"] for s in rec.run["segments"]] == ["seg1.mcap", "seg2.mcap"]
    assert rec.run["run_id"] == "r1" and rec.pt100_t.size == 15 + 30
    assert [e["event"] for e in rec.events] == ["run_started", "step_started", "step_ended"] + [
        "run_resumed"
    ]
    times = [ts for _t, ts, _d in iter_messages(last)]
    assert times == sorted(times)  # one run clock: the segments follow one another
    # the first segment alone still reads as the run up to its end
    assert read_recording(tmp_path / "seg1.mcap").require_rate().t.size == 1500


def test_apply_s_copy_holds_the_whole_run_in_one_file(tmp_path: Path) -> None:
    last = _run(tmp_path)
    out = tmp_path / "copy.mcap"
    rewrite_recording(last, out)
    assert segments(out) == [out]
    a, b = read_recording(last), read_recording(out)
    assert np.array_equal(a.require_rate().values, b.require_rate().values)
    assert np.array_equal(a.require_rate().index, b.require_rate().index)
    assert b.interruptions == [(15.0, 40.0)] and b.events == a.events


def test_the_3_6_s_averaging_never_fills_an_interruption() -> None:
    t = np.concatenate([np.arange(0, 1500) / 100, 40.0 + np.arange(0, 3000) / 100])
    x = np.sin(t)
    acc = BlockAverager(3.6)
    acc.add(t, x, 0.01)
    tb_filled, _xb, filled = acc.result()
    assert filled > 0 and ((tb_filled > 15.0) & (tb_filled < 40.0)).any()  # the old rule
    tb, xb, filled = acc.result([(15.0, 40.0)])
    assert filled == 0 and np.isfinite(xb).all()
    # no block inside the gap; the ones at its edges average samples they hold
    assert not ((tb > 15.0) & (tb < 40.0)).any() and tb.size == tb_filled.size - 7


def test_a_continuation_without_its_earlier_segment_is_refused(tmp_path: Path) -> None:
    last = _run(tmp_path, previous="elsewhere.mcap")
    with pytest.raises(InputError, match="continues elsewhere.mcap .* not beside it"):
        read_recording(last)
    last = _run(tmp_path, run_id="another")
    with pytest.raises(InputError, match="continues seg1.mcap, which is not segment 1"):
        read_metadata(last)


def test_resume_point_re_soaks_the_step_that_was_running(tmp_path: Path) -> None:
    first = {"source": "acquire", "profile": PROFILE, "run_id": "r9", "segment": 1}
    cut = tmp_path / "run.mcap"
    events = [(0.0, "run_started", -1), (0.0, "step_started", 0), (10.0, "step_ended", 0)]
    _segment(cut, first, 0.0, 15.0, 0, [*events, (10.0, "step_started", 1)])
    p = resume_point(cut, now_s=cut.stat().st_mtime + 7.0)
    assert (p.step, p.segment, p.run_id) == (1, 2, "r9")
    assert p.after_t == pytest.approx(15.0) and p.at_t == pytest.approx(22.0)  # 7 s down
    assert p.next_index == {None: (1500, pytest.approx(15.0))}
    assert p.start_time_ns == START_NS
    assert p.previous_segment == {"file": "run.mcap", "segment": 1, "run_id": "r9"}
    done = tmp_path / "done.mcap"
    _segment(done, first, 0.0, 5.0, 0, [*events, (40.0, "run_ended", -1)])
    with pytest.raises(InputError, match="nothing to resume"):
        resume_point(done)


def test_bench_differences_name_what_changed() -> None:
    then = {
        "name": "b",
        "simulated": False,
        "oven": {"driver": "watlowf4", "model": "Watlow F4", "serial": "A1"},
        "adc": {"driver": "gyroadc", "sample_rate_hz": 100.0},
        "units": {"U1": {}, "U2": {}},
    }
    assert bench_differences(then, json.loads(json.dumps(then))) == []
    now = json.loads(json.dumps(then))
    now["oven"]["serial"], now["adc"]["sample_rate_hz"] = "B2", 200.0
    now["units"] = {"U1": {}, "U3": {}}
    assert bench_differences(then, now) == [
        "adc sample_rate_hz: 100.0 then, 200.0 now",
        "oven serial: 'A1' then, 'B2' now",
        "unit serials: ['U1', 'U2'] then, ['U1', 'U3'] now",
    ]
