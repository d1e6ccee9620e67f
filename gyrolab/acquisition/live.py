"""Live view of a run: the recording's channels served over the Foxglove WebSocket protocol.

``gyrolab acquire … --live [PORT]`` starts a :class:`LiveServer` (the ``foxglove-sdk``
WebSocket server, subprotocol ``foxglove.websocket.v1``) on 127.0.0.1 (another interface
only with ``--live-host``). It publishes every message the recorder writes, on the same
topics with the same schemas and log times (protobuf ``FileDescriptorSet`` for the gyro
blocks, JSON Schema for the rest, viewer topics included; a multi-unit run's
``/unit/<serial>/…`` topics for every unit: the channels are the recording's own,
:func:`gyrolab.record.format.recording_channels`), plus ``/live/status``: the run's
progress (step, setpoint, temperatures, time left, samples, frames lost, messages dropped
by the live path; on a multi-unit run each unit's state). docs/live-view.md shows how to
watch a run with the shipped layout ``docs/foxglove/gyrolab-layout.json``.

The run comes first. The recorder's only cost is :meth:`LiveServer.offer`: one
``put_nowait`` into a bounded queue (``queue_size`` messages) — it never blocks and never
raises; when the queue is full the message is dropped for the viewer (counted in
``dropped``), never for the recording. A publisher thread drains the queue into the SDK,
whose server keeps a bounded backlog per client (``backlog`` messages) and drops the oldest
for a slow client. A viewer that connects, lags or disconnects changes nothing on disk.
"""

from __future__ import annotations

import json
import math
import queue
import threading
import time
from collections.abc import Callable
from typing import Any

from gyrolab.errors import GyrolabError
from gyrolab.record.format import recording_channels
from gyrolab.record.writer import RecordingWriter

TOPIC_LIVE_STATUS = "/live/status"
DEFAULT_PORT = 8765
LIVE_STATUS_SCHEMA: dict[str, Any] = {
    "title": "gyrolab.LiveStatus",
    "type": "object",
    "properties": {
        "t": {"type": "number", "description": "s since run start"},
        "step": {"type": "integer", "description": "1-based step number, 0 before the first"},
        "n_steps": {"type": "integer"},
        "step_text": {"type": "string", "description": "e.g. 'step 3/12 at 50 °C'"},
        "setpoint_c": {"type": "number", "description": "°C"},
        "chamber_c": {"type": "number", "description": "oven process value, °C"},
        "temperature_c": {
            "type": "number",
            "description": "the temperature the profile's stability rule watches, °C",
        },
        "temperature_source": {
            "type": "string",
            "description": "what temperature_c is: pt100 | internal (the unit's own sensor)",
        },
        "pt100_c": {"type": "number", "description": "temperature_c when it is a PT100's, °C"},
        "remaining_s": {"type": "number", "description": "nominal run time left, s"},
        "samples": {"type": "integer", "description": "gyro samples recorded"},
        "frames_lost": {"type": "integer"},
        "frames_bad": {"type": "integer"},
        "live_published": {"type": "integer", "description": "messages sent to the server"},
        "live_dropped": {"type": "integer", "description": "messages the live view dropped"},
        "suspended": {
            "type": "array",
            "items": {"type": "string"},
            "description": "the conditions holding the run now (chamber alarm, temperature "
            "lost, stream stall, operator pause); absent while it runs",
        },
        "units": {
            "type": "array",
            "description": "multi-unit runs only: each unit, in bench order",
            "items": {
                "type": "object",
                "properties": {
                    "serial": {"type": "string"},
                    "state": {
                        "type": "string",
                        "description": "recording | pt100_lost (its PT100 channel reads "
                        "overload; the rate is still recorded) | dropped (its stream "
                        "was given up)",
                    },
                    "temperature_c": {
                        "type": "number",
                        "description": "its last temperature reading (PT100, or its internal "
                        "sensor), °C",
                    },
                    "samples": {"type": "integer", "description": "its gyro samples recorded"},
                    "frames_lost": {"type": "integer"},
                    "frames_bad": {"type": "integer"},
                },
                "required": ["serial", "state", "samples"],
            },
        },
    },
    "required": ["t", "step", "n_steps"],
}


class LiveServer:
    """A Foxglove WebSocket server fed from the recorder through a bounded queue.

    ``port=0`` picks a free port (read :attr:`port`). ``host`` defaults to loopback.
    """

    def __init__(
        self,
        port: int = DEFAULT_PORT,
        host: str = "127.0.0.1",
        queue_size: int = 4096,
        backlog: int = 1024,
        name: str = "gyrolab",
    ) -> None:
        try:
            import foxglove
        except ImportError:  # pragma: no cover - a dependency; clear message if removed
            raise GyrolabError(
                "--live needs the foxglove-sdk package (pip install foxglove-sdk)"
            ) from None
        self._ctx = foxglove.Context()
        try:
            self._server = foxglove.start_server(
                name=name,
                host=host,
                port=port,
                context=self._ctx,
                message_backlog_size=backlog,
            )
        except Exception as e:
            raise GyrolabError(f"--live: cannot serve on {host}:{port} ({e})") from None
        self.host = host
        self.port = int(self._server.port)
        self.start_time_ns = 0
        self._fg = foxglove
        self._channels: dict[str, Any] = {}
        # The recording's own channels are advertised when a writer is attached (its
        # layout, single- or multi-unit, decides them); the status topic from the start.
        data = json.dumps(LIVE_STATUS_SCHEMA, sort_keys=True).encode()
        self._add(TOPIC_LIVE_STATUS, LIVE_STATUS_SCHEMA["title"], "jsonschema", data, "json")
        self._q: queue.Queue[tuple[str, int, bytes] | None] = queue.Queue(maxsize=queue_size)
        self.offered = 0
        self.dropped = 0
        self.published = 0
        self._closed = False
        self._thread = threading.Thread(target=self._publish, name="live-view", daemon=True)
        self._thread.start()

    def _add(self, topic: str, name: str, enc: str, data: bytes, msg_enc: str) -> None:
        if topic in self._channels:
            return
        schema = self._fg.Schema(name=name, encoding=enc, data=data)
        self._channels[topic] = self._fg.Channel(
            topic, schema=schema, message_encoding=msg_enc, context=self._ctx
        )

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    # -- the recorder's side: O(1), never blocks, never raises
    def offer(self, topic: str, log_time_ns: int, data: bytes) -> None:
        """Queue one recorded message for the viewers; dropped (counted) if the queue is full."""
        self.offered += 1
        try:
            self._q.put_nowait((topic, log_time_ns, data))
        except queue.Full:
            self.dropped += 1

    def attach(self, writer: RecordingWriter) -> None:
        """Advertise ``writer``'s channels (every unit's on a multi-unit recording, with the
        recording's schemas) and tap it: every message it records is offered to the viewers."""
        for c in recording_channels(writer.units, writer.internal_temperature):
            self._add(c.topic, c.schema_name, c.schema_encoding, c.schema_data, c.message_encoding)
        self.start_time_ns = writer.start_time_ns
        writer.tap = self.offer

    def status_hook(self, inner: Callable[[Any], None] | None) -> Callable[[Any], None]:
        """An ``on_status`` callback that also publishes ``/live/status`` (then calls inner)."""

        def hook(st: Any) -> None:
            self.offer_status(st)
            if inner is not None:
                inner(st)

        return hook

    def offer_status(self, st: Any) -> None:
        """Publish an :class:`~gyrolab.acquisition.runner.Status` snapshot."""

        def num(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None  # JSON has no NaN

        step = int(st.step) + 1
        sp = num(st.setpoint_c)
        text = f"step {step}/{st.n_steps}" + (f" at {sp:g} °C" if sp is not None else "")
        msg = {
            "t": float(st.t),
            "step": step,
            "n_steps": int(st.n_steps),
            "step_text": text,
            "setpoint_c": sp,
            "chamber_c": num(st.chamber_c),
            "temperature_c": num(st.temperature_c),
            "temperature_source": st.temperature_source,
            "pt100_c": num(st.pt100_c),
            "remaining_s": num(st.remaining_s),
            "samples": int(st.samples),
            "frames_lost": int(st.frames_lost),
            "frames_bad": int(st.frames_bad),
            "live_published": self.published,
            "live_dropped": self.dropped,
        }
        msg = {k: v for k, v in msg.items() if v is not None}
        if getattr(st, "suspended", None):
            msg["suspended"] = list(st.suspended)
        units = [
            {
                k: v
                for k, v in {
                    "serial": u.serial,
                    "state": u.state,
                    "temperature_c": num(u.temperature_c),
                    "samples": int(u.samples),
                    "frames_lost": int(u.frames_lost),
                    "frames_bad": int(u.frames_bad),
                }.items()
                if v is not None
            }
            for u in st.units
        ]
        if units:
            msg["units"] = units
        ts = self.start_time_ns + int(round(float(st.t) * 1e9))
        self.offer(TOPIC_LIVE_STATUS, ts, json.dumps(msg, separators=(",", ":")).encode())

    # -- the publisher thread
    def _publish(self) -> None:
        while True:
            item = self._q.get()
            if item is None:
                return
            topic, ts, data = item
            ch = self._channels.get(topic)
            if ch is None:
                continue
            try:
                ch.log(data, log_time=ts)
                self.published += 1
            except Exception:  # a viewer problem must not end the thread (nor the run)
                self.dropped += 1

    def close(self, drain_s: float = 1.0) -> None:
        """Stop publishing (after up to ``drain_s`` s to send what is queued) and the server."""
        if self._closed:
            return
        self._closed = True
        deadline = time.monotonic() + drain_s
        while not self._q.empty() and time.monotonic() < deadline:
            time.sleep(0.01)
        try:
            self._q.put(None, timeout=1.0)
        except queue.Full:
            pass
        self._thread.join(timeout=2.0)
        self._server.stop()

    def __enter__(self) -> LiveServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
