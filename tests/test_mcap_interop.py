"""Interoperability: recordings open in an independent MCAP implementation.

The TypeScript reader of the MCAP project (`@mcap/core`, with `fzstd` for zstd chunks)
reads a recording twice — indexed (summary, chunk/message indexes, CRCs validated) and
streamed — and must see the same messages per topic as gyrolab's Python reader. The npm
packages are installed on first use into a cache directory (``GYROLAB_JS_CACHE``, default
``~/.cache/gyrolab-js``); the test is skipped only where node or npm is absent.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from jscheck import js_script, run_js

from gyrolab.record.format import ALL_TOPICS
from gyrolab.record.reader import read_recording
from gyrolab.record.recover import recover_recording
from gyrolab.record.writer import RecordingWriter

PACKAGES = ["@mcap/core@2.2.2", "fzstd@0.1.1"]


@pytest.fixture(scope="module")
def js_reader() -> Path:
    return js_script("read_mcap.mjs", PACKAGES)


def _recording(path: Path, seconds: int = 60, finish: bool = True) -> None:
    rng = np.random.default_rng(0)
    w = RecordingWriter(
        path,
        start_time_ns=1_618_876_800_000_000_000,
        run={"operator": "interop", "profile": {"name": "x", "step": [{"setpoint_c": 25}]}},
        bench={"adc": {"bits": 24}},
        flush_every_s=1.0,
    )
    w.write_event(0.0, "run_started", detail="interop")
    for k in range(seconds * 2):
        t = k * 0.5
        c = rng.integers(-(2**23), 2**23, 50, dtype=np.int32)
        w.write_adc_block(t, 0.01, k * 50, c)
        w.write_rate_block(t, 0.01, k * 50, c * 3e-5)
        if k % 2 == 0:
            w.write_pt100(t, 109.73, 25.0)
            w.write_oven(t, 25.0, 24.9, "run")
        if k % 20 == 0:
            w.write_log(t, "info", "test", f"tick {k}", "note", {"k": k})
    if finish:
        w.write_event(seconds, "run_ended")
        w.close()
    else:
        w._fh.flush()  # as a kill -9 leaves it


def test_typescript_reader_sees_every_message(js_reader: Path, tmp_path: Path) -> None:
    f = tmp_path / "run.mcap"
    _recording(f)
    py = read_recording(f)
    js = run_js(js_reader, f)
    assert js["profile"] == "gyrolab"
    assert js["indexed"] == py.topic_counts == js["streamed"]
    assert set(js["indexed"]) == set(ALL_TOPICS)
    assert js["statistics_message_count"] == sum(py.topic_counts.values())
    assert js["stream_done"] is True
    assert js["encodings"]["/gyro/adc"] == ["protobuf", "protobuf", "gyrolab.GyroAdcBlock"]
    assert js["encodings"]["/temperature/pt100"] == ["json", "jsonschema", "gyrolab.Pt100Reading"]
    assert js["metadata"]["run"]["operator"] == "interop"
    assert json.loads(js["metadata"]["run"]["profile"])["name"] == "x"
    assert js["first_json"]["message"]["event"] == "run_started"


def test_typescript_reader_opens_a_recovered_file(js_reader: Path, tmp_path: Path) -> None:
    broken = tmp_path / "crashed.mcap"
    _recording(broken, finish=False)
    data = broken.read_bytes()
    broken.write_bytes(data[: len(data) - 333])  # cut inside the last records
    fixed = tmp_path / "fixed.mcap"
    rep = recover_recording(broken, fixed)
    js = run_js(js_reader, fixed)
    py = read_recording(fixed)
    assert js["indexed"] == py.topic_counts == js["streamed"] == rep.messages
    assert js["metadata"]["bench"]["adc"] == '{"bits": 24}'
