"""The live view over a real WebSocket: a ``websockets`` client speaking the Foxglove
WebSocket protocol subscribes, receives and decodes what the recorder writes.

The protocol's subprotocol name is ``foxglove.websocket.v1``; the foxglove-sdk server (0.30)
accepts it under its new name ``foxglove.sdk.v1`` (same wire format: JSON control messages,
binary ``messageData`` frames). The client offers both, as Foxglove and Lichtblick do."""

from __future__ import annotations

import json
import socket
import struct
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from websockets.sync.client import connect

from gyrolab.acquisition.live import TOPIC_LIVE_STATUS, LiveServer
from gyrolab.record.blocks import decode_block
from gyrolab.record.format import TOPIC_LOG_FOXGLOVE, TOPIC_PT100, TOPIC_RATE, TOPIC_RATE_SUMMARY
from gyrolab.record.reader import iter_messages
from gyrolab.record.writer import RecordingWriter

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
START_NS = 1_700_000_000_000_000_000


class Client:
    """A minimal foxglove.websocket.v1 client: advertise -> subscribe -> messageData."""

    def __init__(self, url: str, timeout: float = 10.0) -> None:
        deadline = time.monotonic() + timeout
        while True:
            try:
                self._cm = connect(url, subprotocols=SUBPROTOCOLS, open_timeout=2)  # type: ignore[arg-type]
                self.ws = self._cm.__enter__()
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.05)
        assert self.ws.subprotocol in SUBPROTOCOLS
        self.channels: dict[int, dict] = {}
        self.server_info: dict = {}
        self.received: list[tuple[str, int, bytes]] = []
        self.sub_topic: dict[int, str] = {}

    def read_advertise(self, topics: set[str], timeout: float = 5.0) -> None:
        deadline = time.monotonic() + timeout
        while not topics <= {c["topic"] for c in self.channels.values()}:
            msg = self.ws.recv(timeout=max(0.01, deadline - time.monotonic()))
            self._handle(msg)

    def subscribe(self, topics: set[str]) -> None:
        subs = []
        for cid, ch in self.channels.items():
            if ch["topic"] in topics:
                sid = len(self.sub_topic) + 1
                self.sub_topic[sid] = ch["topic"]
                subs.append({"id": sid, "channelId": cid})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def _handle(self, msg: str | bytes) -> None:
        if isinstance(msg, str):
            m = json.loads(msg)
            if m["op"] == "serverInfo":
                self.server_info = m
            elif m["op"] == "advertise":
                for ch in m["channels"]:
                    self.channels[ch["id"]] = ch
        elif msg[0] == 0x01:  # messageData: opcode, u32 subscription, u64 log time, payload
            sid, ts = struct.unpack_from("<IQ", msg, 1)
            self.received.append((self.sub_topic[sid], ts, bytes(msg[13:])))

    def close(self) -> None:
        self._cm.__exit__(None, None, None)

    def pump(self, until: float) -> None:
        while time.monotonic() < until:
            try:
                self._handle(self.ws.recv(timeout=0.05))
            except TimeoutError:
                continue


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_client_subscribes_and_decodes_what_is_recorded(tmp_path: Path) -> None:
    with LiveServer(port=0) as live:
        assert live.host == "127.0.0.1"
        w = RecordingWriter(tmp_path / "r.mcap", start_time_ns=START_NS)
        live.attach(w)
        c = Client(live.url)
        want = {TOPIC_RATE, TOPIC_PT100, TOPIC_RATE_SUMMARY, TOPIC_LOG_FOXGLOVE}
        c.read_advertise(want | {TOPIC_LIVE_STATUS})
        by_topic = {ch["topic"]: ch for ch in c.channels.values()}
        assert by_topic[TOPIC_RATE]["encoding"] == "protobuf"
        assert by_topic[TOPIC_RATE]["schemaName"] == "gyrolab.GyroRateBlock"
        assert by_topic[TOPIC_LOG_FOXGLOVE]["schemaName"] == "foxglove.Log"
        c.subscribe(want)
        c.pump(time.monotonic() + 0.3)  # the server registers the subscription
        rng = np.random.default_rng(0)
        blocks = [rng.normal(size=100).astype(np.float32) for _ in range(20)]
        for k, b in enumerate(blocks):
            w.write_rate_block(k * 1.0, 0.01, k * 100, b)
            w.write_pt100(k + 0.5, 109.7 + k * 0.01, 25.0 + k * 0.02)
        w.write_log(20.0, "warning", "adc", "gap of 5 samples", "gap")
        w.close()
        deadline = time.monotonic() + 5.0
        while len(c.received) < 61 and time.monotonic() < deadline:
            c.pump(time.monotonic() + 0.1)
        c.close()
    got: dict[str, list[tuple[int, bytes]]] = {}
    for topic, ts, data in c.received:
        got.setdefault(topic, []).append((ts, data))
    assert {t: len(v) for t, v in got.items()} == {
        TOPIC_RATE: 20,
        TOPIC_PT100: 20,
        TOPIC_RATE_SUMMARY: 20,
        TOPIC_LOG_FOXGLOVE: 1,
    }
    for k, (ts, data) in enumerate(got[TOPIC_RATE]):
        t0, period, first, arr = decode_block(data, "rate")
        assert (t0, period, first) == (k * 1.0, 0.01, k * 100) and ts == START_NS + k * 10**9
        np.testing.assert_array_equal(arr, blocks[k])
    summ = json.loads(got[TOPIC_RATE_SUMMARY][3][1])
    assert summ["mean_dps"] == pytest.approx(float(blocks[3].astype(float).mean()), rel=1e-12)
    log = json.loads(got[TOPIC_LOG_FOXGLOVE][0][1])
    assert log["level"] == 3 and log["name"] == "adc" and log["message"] == "[gap] gap of 5 samples"
    # the viewer saw byte for byte what the file holds
    on_disk = [(ts, d) for tp, ts, d in iter_messages(tmp_path / "r.mcap") if tp == TOPIC_PT100]
    assert on_disk == got[TOPIC_PT100]


def test_every_unit_s_topics_are_advertised_and_served(tmp_path: Path) -> None:
    """A multi-unit recording: the viewer is offered exactly the file's channels (each
    unit's /unit/<serial>/… topics with the recording's schemas, no single-unit topic) and
    receives every unit's messages, byte for byte; /live/status carries each unit's state."""
    from mcap.reader import make_reader

    from gyrolab.acquisition.runner import Status, UnitStatus
    from gyrolab.record.format import TOPIC_OVEN, TOPIC_TEMPERATURE_INTERNAL, unit_topic

    serials = ["A1", "B2"]
    rate = {s: unit_topic(TOPIC_RATE, s) for s in serials}
    pt = {s: unit_topic(TOPIC_PT100, s) for s in serials}
    with LiveServer(port=0) as live:
        w = RecordingWriter(
            tmp_path / "u.mcap", start_time_ns=START_NS, units=serials, internal_temperature=["B2"]
        )
        live.attach(w)
        c = Client(live.url)
        want = {*rate.values(), *pt.values(), TOPIC_OVEN, TOPIC_LIVE_STATUS}
        c.read_advertise(want)
        by_topic = {ch["topic"]: ch for ch in c.channels.values()}
        assert TOPIC_RATE not in by_topic and TOPIC_PT100 not in by_topic
        assert by_topic[rate["B2"]]["encoding"] == "protobuf"
        assert by_topic[rate["B2"]]["schemaName"] == "gyrolab.GyroRateBlock"
        assert by_topic[pt["A1"]]["schemaName"] == "gyrolab.Pt100Reading"
        c.subscribe(want)
        c.pump(time.monotonic() + 0.3)
        for k in range(5):
            for j, s in enumerate(serials):
                block = np.full(100, k + 10 * j, dtype=np.float32)
                w.write_rate_block(k * 1.0, 0.01, k * 100, block, unit=s)
                w.write_pt100(k + 0.5, 109.7 + j, 25.0 + j, unit=s)
        w.write_oven(4.9, 25.0, 25.1, "run")
        st = Status(t=5.0, step=0, n_steps=2, samples=1000)
        st.units = [UnitStatus("A1", "recording", 25.0, 500), UnitStatus("B2", "pt100_lost")]
        live.offer_status(st)
        w.close()
        deadline = time.monotonic() + 5.0
        while len(c.received) < 22 and time.monotonic() < deadline:
            c.pump(time.monotonic() + 0.1)
        c.close()
    with open(tmp_path / "u.mcap", "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    advertised = {ch["topic"] for ch in c.channels.values()}
    assert advertised == {ch.topic for ch in summary.channels.values()} | {TOPIC_LIVE_STATUS}
    assert unit_topic(TOPIC_TEMPERATURE_INTERNAL, "B2") in advertised  # B2's internal sensor
    assert unit_topic(TOPIC_TEMPERATURE_INTERNAL, "A1") not in advertised
    got: dict[str, list[tuple[int, bytes]]] = {}
    for topic, ts, data in c.received:
        got.setdefault(topic, []).append((ts, data))
    assert {t: len(got.get(t, [])) for t in want - {TOPIC_LIVE_STATUS}} == {
        **{t: 5 for t in (*rate.values(), *pt.values())},
        TOPIC_OVEN: 1,
    }
    on_disk: dict[str, list[tuple[int, bytes]]] = {}
    for tp, ts, d in iter_messages(tmp_path / "u.mcap"):
        on_disk.setdefault(tp, []).append((ts, d))
    for t in (*rate.values(), *pt.values()):
        assert got[t] == on_disk[t]
    assert decode_block(got[rate["B2"]][3][1], "rate")[3][0] == 13.0  # B2's own data
    (status,) = [json.loads(d) for _ts, d in got[TOPIC_LIVE_STATUS]]
    assert status["units"] == [
        {"serial": "A1", "state": "recording", "temperature_c": 25.0, "samples": 500,
         "frames_lost": 0, "frames_bad": 0},
        {"serial": "B2", "state": "pt100_lost", "samples": 0, "frames_lost": 0,
         "frames_bad": 0},
    ]  # fmt: skip


def test_a_stalled_viewer_drops_messages_not_samples(tmp_path: Path) -> None:
    """A client that subscribes and then never reads: the server's per-client backlog drops
    the oldest messages; the recorder is never held up and records everything."""
    with LiveServer(port=0, backlog=8) as live:
        w = RecordingWriter(tmp_path / "s.mcap", start_time_ns=START_NS)
        live.attach(w)
        c = Client(live.url)
        c.read_advertise({TOPIC_RATE})
        c.subscribe({TOPIC_RATE})
        c.pump(time.monotonic() + 0.3)
        big = np.zeros(50_000, dtype=np.float32)  # 200 kB per message: fills the socket
        worst = 0.0
        for k in range(150):
            t = time.perf_counter()
            w.write_rate_block(k * 500.0, 0.01, k * 50_000, big + k)
            worst = max(worst, time.perf_counter() - t)
        w.close()
        time.sleep(0.5)
        c.pump(time.monotonic() + 1.0)  # now read whatever the server still holds
        c.close()
    n_rec = sum(1 for tp, _ts, _d in iter_messages(tmp_path / "s.mcap") if tp == TOPIC_RATE)
    assert n_rec == 150  # every block recorded
    got = [decode_block(d, "rate")[2] for tp, _ts, d in c.received if tp == TOPIC_RATE]
    assert 0 < len(got) < 150  # the viewer lost messages ...
    assert got == sorted(got)  # ... whole ones, in order
    assert worst < 1.0, worst  # a write never waited for the stalled viewer (it never reads)


def test_offer_never_blocks_when_the_queue_is_full() -> None:
    live = LiveServer(port=0, queue_size=8)
    live.close()  # publisher gone: nothing drains the queue any more
    # An offer that blocked on the full queue would wait forever, so the offers ending at
    # all is the check (a time bound on them, < 0.05 s, failed under load); the join's
    # limit only keeps such a hang from hanging the suite.
    th = threading.Thread(target=lambda: [live.offer(TOPIC_RATE, k, b"x") for k in range(100)])
    th.start()
    th.join(60.0)
    assert not th.is_alive(), "an offer blocked on the full queue"
    assert live.dropped >= 92 and live.offered == 100


@pytest.mark.parametrize("units", [0, 2])
def test_acquire_live_at_300x_with_a_client(tmp_path: Path, units: int) -> None:
    """A whole ``acquire --bench sim --live`` run with a client, single-unit and with
    ``--units 2`` (every unit's topics and per-unit status reach the viewer)."""
    from gyrolab.cli import main
    from gyrolab.record.format import unit_topic
    from gyrolab.record.reader import read_recording

    prof = tmp_path / "p.toml"
    prof.write_text(
        'name = "live"\n[[step]]\nsetpoint_c = 25\nduration_s = 60\n'
        "[[step]]\nsetpoint_c = 40\nduration_s = 60\n"
    )
    port = _free_port()
    out = tmp_path / "live.mcap"
    box: dict = {}

    serials = [f"SIM0-{k:02d}" for k in range(1, units + 1)] or [None]
    summ = {unit_topic(TOPIC_RATE_SUMMARY, s) for s in serials}
    pt = {unit_topic(TOPIC_PT100, s) for s in serials}

    def watch() -> None:
        c = Client(f"ws://127.0.0.1:{port}", timeout=30)
        topics = summ | pt | {TOPIC_LIVE_STATUS, TOPIC_LOG_FOXGLOVE}
        c.read_advertise(topics, timeout=30)  # advertised once the recording opens
        c.subscribe(topics)
        try:
            c.pump(time.monotonic() + 30)
        except Exception:  # the server closes the connection when the run ends
            pass
        box["c"] = c

    th = threading.Thread(target=watch, daemon=True)
    th.start()
    more = ["--units", str(units)] if units else []
    rc = main(
        ["acquire", "--bench", "sim", "--out", str(out), "--profile", str(prof),
         "--speed", "300", "--live", str(port), *more]
    )  # fmt: skip
    assert rc == 0
    th.join(timeout=40)
    c = box["c"]
    for s in serials:
        rate = read_recording(out, unit=s).rate
        assert rate is not None and rate.gaps() == []  # the viewer cost no sample
    topics = {tp for tp, _ts, _d in c.received}
    assert summ | pt | {TOPIC_LIVE_STATUS} <= topics  # every unit's
    status = [json.loads(d) for tp, _ts, d in c.received if tp == TOPIC_LIVE_STATUS]
    assert status[-1]["n_steps"] == 2 and status[-1]["step_text"].startswith("step ")
    if units:
        assert [u["serial"] for u in status[-1]["units"]] == serials
        assert {u["state"] for u in status[-1]["units"]} == {"recording"}
        assert all(u["samples"] > 0 for u in status[-1]["units"])
    else:
        assert "units" not in status[-1]
    # what the viewer got of each rate summary is what the file holds
    disk = {(tp, ts): d for tp, ts, d in iter_messages(out, sorted(summ))}
    live_summ = [(tp, ts, d) for tp, ts, d in c.received if tp in summ]
    assert live_summ and all(disk[(tp, ts)] == d for tp, ts, d in live_summ)


def _leaf_panels(node: object) -> list[str]:
    if isinstance(node, str):
        return [node]
    assert isinstance(node, dict)
    return _leaf_panels(node["first"]) + _leaf_panels(node["second"])


def test_shipped_layout_names_topics_and_fields_that_exist() -> None:
    """Every panel of docs/foxglove/gyrolab-layout.json reads a topic and field that the
    recording or the live server publishes (schema properties), and every panel is placed."""
    from gyrolab.acquisition.live import LIVE_STATUS_SCHEMA
    from gyrolab.record.format import JSON_SCHEMAS

    layout = json.loads(
        (
            Path(__file__).resolve().parents[1] / "docs" / "foxglove" / "gyrolab-layout.json"
        ).read_text(encoding="utf-8")
    )
    schemas = {**JSON_SCHEMAS, TOPIC_LIVE_STATUS: LIVE_STATUS_SCHEMA}
    cfg = layout["configById"]
    assert sorted(_leaf_panels(layout["layout"])) == sorted(cfg)
    seen = set()
    for panel, c in cfg.items():
        for p in c.get("paths", []):
            topic, fld = p["value"].split(".", 1)
            assert fld.split(".")[0] in schemas[topic]["properties"], p["value"]
            if p["timestampMethod"] == "headerStamp":
                assert "header" in schemas[topic]["properties"]
            seen.add(topic)
        for key in ("topicPath", "topicToRender"):
            if key in c:
                assert c[key] in schemas, (panel, c[key])
                seen.add(c[key])
    assert schemas[TOPIC_LOG_FOXGLOVE]["title"] == "foxglove.Log"  # what the RosOut panel takes
    assert {TOPIC_RATE_SUMMARY, TOPIC_PT100, TOPIC_LOG_FOXGLOVE, TOPIC_LIVE_STATUS} <= seen


def test_port_in_use_is_one_line_exit_2_and_nothing_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from gyrolab.cli import main

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        out = tmp_path / "x.mcap"
        rc = main(["acquire", "--bench", "sim", "--out", str(out), "--profile", "short",
                   "--speed", "300", "--live", str(port)])  # fmt: skip
    assert rc == 2
    err = capsys.readouterr().err
    assert f"cannot serve on 127.0.0.1:{port}" in err
    assert not out.exists()
