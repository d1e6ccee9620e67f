"""The viewer topics (/gyro/rate_summary, /log/foxglove) checked by an independent reader.

``tests/js/check_viewer_topics.mjs`` reads the recording with ``@mcap/core``, validates the
``foxglove.Log`` messages with ``ajv`` against the schema that ``@foxglove/schemas`` ships
(the one Foxglove's Log panel expects), the summaries against the JSON Schema stored in the
file, and recomputes every summary from the ``/gyro/rate`` block it summarises. npm packages
are installed on first use into ``GYROLAB_JS_CACHE/viewer`` (default ``~/.cache/gyrolab-js``);
skipped only where node or npm is absent.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from jscheck import js_script, run_js

from gyrolab.record.format import FOXGLOVE_LOG_LEVEL, TOPIC_LOG_FOXGLOVE, TOPIC_RATE_SUMMARY
from gyrolab.record.reader import iter_messages, read_recording
from gyrolab.record.writer import RecordingWriter

PACKAGES = ["@mcap/core@2.2.2", "fzstd@0.1.1", "@foxglove/schemas@2.1.0", "ajv@8.17.1"]
START_NS = 1_618_876_800_123_000_000


@pytest.fixture(scope="module")
def js_checker() -> Path:
    return js_script("check_viewer_topics.mjs", PACKAGES, "viewer")


def _recording(path: Path) -> None:
    rng = np.random.default_rng(5)
    with RecordingWriter(path, start_time_ns=START_NS, flush_every_s=1.0) as w:
        first = 0
        for k in range(40):
            n = 100 if k != 7 else 37  # one short block
            if k == 20:
                first += 50  # a gap: the summary follows the block's own first_index
            w.write_rate_block(first * 0.01, 0.01, first, rng.normal(0.1, 0.02, n))
            first += n
        for i, level in enumerate(FOXGLOVE_LOG_LEVEL):
            w.write_log(0.25 * i + 0.001, level, "bench", f"a {level} message", "note")
        w.write_log(3.0, "warning", "adc", "gap", "gap", {"n_missing": 50})


def test_viewer_topics_decode_to_the_panel_schemas(js_checker: Path, tmp_path: Path) -> None:
    f = tmp_path / "run.mcap"
    _recording(f)
    js = run_js(js_checker, f)
    assert js["schema_names"][TOPIC_LOG_FOXGLOVE] == "foxglove.Log"
    assert js["log_schema_equal"] is True  # the schema stored is @foxglove/schemas' Log
    assert js["logs"] == len(FOXGLOVE_LOG_LEVEL) + 1 and js["log_errors"] == []
    assert js["levels"] == {"1": 1, "2": 1, "3": 2, "4": 1, "5": 1}
    assert js["stamp_max_err_ns"] == 0  # timestamp == the message's log time
    assert (
        js["first_log"]["name"] == "bench"
        and js["first_log"]["message"] == "[note] a debug message"
    )
    assert js["summaries"] == js["rate_blocks"] == 40 and js["summary_errors"] == []
    assert js["n_mismatch"] == 0
    assert js["max_mean_diff"] < 1e-12 and js["max_minmax_diff"] == 0


def test_summary_values_and_stamp() -> None:
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        f = Path(d) / "r.mcap"
        _recording(f)
        rec = read_recording(f)
        msgs = [json.loads(m) for _t, _ns, m in iter_messages(f, [TOPIC_RATE_SUMMARY])]
    assert len(msgs) == 40
    blk = msgs[7]
    assert blk["n"] == 37
    sel = (rec.rate.index >= blk["first_index"]) & (rec.rate.index < blk["first_index"] + 37)
    assert blk["mean_dps"] == pytest.approx(rec.rate.values[sel].mean(), rel=1e-12)
    ns = blk["header"]["stamp"]["sec"] * 10**9 + blk["header"]["stamp"]["nsec"]
    assert ns == START_NS + round(blk["t"] * 1e9)
    assert blk["t"] == pytest.approx(blk["t0"] + 18 * 0.01)  # the block's middle sample
    assert msgs[20]["first_index"] == msgs[19]["first_index"] + 100 + 50
