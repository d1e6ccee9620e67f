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
from gyrolab.record.source import opened
from gyrolab.record.writer import McapFile


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
    :class:`InputError`."""
    derived = dict(derived or {})
    metadata = dict(metadata or {})
    # dst is opened first: an error writing it is not the source's damage
    with open(Path(dst), "wb") as out, opened(src) as source:
        header = source.header()
        w = McapFile(out, profile=header.profile or PROFILE)
        schemas, channels = source.schemas(), source.channels()
        sids: dict[int, int] = {}
        cids: dict[int, int] = {}
        by_topic: dict[str, int] = {}

        def put(m: Message) -> None:
            if m.topic not in by_topic:
                raise ValueError(f"no channel {m.topic!r} in the rewritten recording")
            w.add_message(by_topic[m.topic], m.log_time, m.data, m.publish_time, m.sequence)

        for topic, log_time, data, cid, seq, pub in source.messages():
            if cid not in cids:
                channel = channels[cid]
                sid = 0
                if channel.schema_id:
                    if channel.schema_id not in sids:
                        schema = schemas[channel.schema_id]
                        sids[channel.schema_id] = w.register_schema(
                            schema.name, schema.encoding, schema.data
                        )
                    sid = sids[channel.schema_id]
                enc, meta = channel.message_encoding, dict(channel.metadata)
                cids[cid] = w.register_channel(topic, enc, sid, meta)
                by_topic[topic] = cids[cid]
                for name, like in derived.items():
                    if like == topic:
                        by_topic[name] = w.register_channel(name, enc, sid, meta)
            m = Message(topic, log_time, pub, seq, bytes(data))
            for out_msg in [m] if transform is None else transform(m):
                put(out_msg)
        for m in tail:
            put(m)
        for rec in source.metadata():
            if rec.name not in metadata:
                w.add_metadata(rec.name, rec.metadata)
        for name, values in metadata.items():
            w.add_metadata(name, values)
        w.finish()
