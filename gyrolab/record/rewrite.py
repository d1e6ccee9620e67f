"""Copy a recording with some of its messages transformed (what ``gyrolab apply`` writes).

:func:`rewrite_recording` copies ``src`` record by record — schemas, channels, messages
with their log times, publish times and sequence numbers, metadata — through the one MCAP
writer (:class:`~gyrolab.record.writer.McapFile`), letting a ``transform`` replace each
message by any number of messages, on its own topic or on new topics that share a source
topic's schema (``derived``). Memory: one message at a time, plus the ``tail``.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

from gyrolab.record.format import PROFILE
from gyrolab.record.reader import opened, read_metadata, segments
from gyrolab.record.writer import McapFile, json_strings


@dataclass(frozen=True)
class Message:
    """One message as the file holds it (times in Unix ns)."""

    topic: str
    log_time: int
    publish_time: int
    sequence: int
    data: bytes


def rewrite_recording(
    src: str | os.PathLike[str],
    dst: str | os.PathLike[str],
    *,
    transform: Callable[[Message], Iterable[Message]] | None = None,
    derived: Mapping[str, str] | None = None,
    tail: Iterable[Message] = (),
    metadata: Mapping[str, Mapping[str, str]] | None = None,
) -> None:
    """Write ``src`` to ``dst`` in log-time order with every message replaced by
    ``transform(message)`` (unchanged when None).

    ``derived``: new topic → the source topic whose schema, encoding and channel metadata it
    takes; registered right after that topic's channel. ``tail``: messages written after
    the copy (on any topic registered by then). ``metadata``: records (MCAP string maps)
    written after the source's, replacing any of the same name. A damaged ``src`` is an
    :class:`InputError`.

    A resumed run (its segments, docs/recording-format.md) is copied whole into one file:
    every segment's messages in turn, each topic on one channel, and the run's metadata as
    :func:`~gyrolab.record.reader.read_metadata` gives it (``run`` with its ``segments``)."""
    derived = dict(derived or {})
    metadata = dict(metadata or {})
    paths = segments(src)
    merged = read_metadata(src) if len(paths) > 1 else None
    w: McapFile | None = None
    sids: dict[tuple[str, str, bytes], int] = {}
    by_topic: dict[str, int] = {}
    records: list[tuple[str, Mapping[str, str]]] = []

    def put(m: Message) -> None:
        if m.topic not in by_topic:
            raise ValueError(f"no channel {m.topic!r} in the rewritten recording")
        assert w is not None
        w.add_message(by_topic[m.topic], m.log_time, m.data, m.publish_time, m.sequence)

    # dst is opened first: an error writing it is not the source's damage
    with open(Path(dst), "wb") as out:
        for path in paths:
            with opened(path, hint="") as reader:
                if w is None:
                    w = McapFile(out, profile=reader.get_header().profile or PROFILE)
                for schema, channel, msg in reader.iter_messages(log_time_order=True):
                    if channel.topic not in by_topic:
                        sid = 0
                        if schema is not None:
                            key = (schema.name, schema.encoding, bytes(schema.data))
                            if key not in sids:
                                sids[key] = w.register_schema(*key)
                            sid = sids[key]
                        enc, meta = channel.message_encoding, dict(channel.metadata)
                        by_topic[channel.topic] = w.register_channel(
                            channel.topic, enc, sid, meta
                        )
                        for topic, like in derived.items():
                            if like == channel.topic:
                                by_topic[topic] = w.register_channel(topic, enc, sid, meta)
                    m = Message(
                        channel.topic, msg.log_time, msg.publish_time, msg.sequence, msg.data
                    )
                    for out_msg in [m] if transform is None else transform(m):
                        put(out_msg)
                if merged is None:  # one file: its records as they are
                    records = [(r.name, r.metadata) for r in reader.iter_metadata()]
        assert w is not None
        for m in tail:
            put(m)
        if merged is not None:
            records = [(name, json_strings(record)) for name, record in merged.items()]
        for name, values in records:
            if name not in metadata:
                w.add_metadata(name, values)
        for name, values in metadata.items():
            w.add_metadata(name, values)
        w.finish()
