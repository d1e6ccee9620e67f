"""An open, checked MCAP file: :func:`opened` gives a :class:`Source` — its header, summary,
metadata records and messages — after :mod:`gyrolab.record.integrity` has checked the file,
and checks every chunk it decompresses. Every reader of MCAP files in gyrolab comes through
here (gyrolab's recordings, ``gyrolab apply``'s copy, users' ROS 2 bags); the mcap library
parses the summary, header and metadata records, never the chunks.

A damaged or cut file is an :class:`~gyrolab.errors.InputError`: one line naming the file,
the damaged chunk's byte offset and time span (seconds after the file's first message) and
the ``gyrolab recover`` hint.
"""

from __future__ import annotations

import contextlib
import heapq
import io
import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any, BinaryIO, Literal, NamedTuple

from gyrolab.errors import InputError, existing_file
from gyrolab.record.integrity import (
    MAGIC,
    MESSAGE_HEAD,
    OP_CHANNEL,
    OP_CHUNK,
    OP_MESSAGE,
    OP_SCHEMA,
    Damage,
    Layout,
    check_data_section,
    check_layout,
    chunk_data,
    chunk_messages,
    records,
)

RECOVER_HINT = "; try `gyrolab recover`"

#: A message as :meth:`Source.messages` yields it: topic (or channel id), log time (ns),
#: data, channel id, sequence, publish time (ns).
Message = tuple[Any, int, bytes, int, int, int]

#: Message orders: every message by log time, or each topic's messages by log time
#: (topics interleaved as the file holds them).
Order = Literal["log_time", "topic"]


def chunks_in_file_order(summary: Any, topics: list[str] | None) -> list[Any] | None:
    """The chunk indexes holding ``topics``, in file order, when reading those chunks in that
    order gives each topic's messages in log-time order once each chunk's own are sorted:
    every topic's chunks follow one another in time (one's last message time ≤ the next's
    first). ``None`` when that does not hold or cannot be known from the summary (no chunk
    index, or one without message indexes): the caller reads through the log-time merge.

    Why it holds: the merge yields messages by (log time, chunk offset, position in chunk);
    chunks of a topic that do not overlap in time, read in offset order, each sorted stably
    by log time, give that same order for the topic."""
    if summary is None or not summary.chunk_indexes:
        return None
    wanted = {cid for cid, ch in summary.channels.items() if topics is None or ch.topic in topics}
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    last_end: dict[int, int] = {}
    out = []
    for ci in chunks:
        if not ci.message_index_offsets:  # which channels it holds is unknown
            return None
        held = wanted.intersection(ci.message_index_offsets)
        if not held:
            continue
        for cid in held:
            if last_end.get(cid, ci.message_start_time) > ci.message_start_time:
                return None
            last_end[cid] = ci.message_end_time
        out.append(ci)
    return out


class Source:
    """A checked MCAP file open for reading (from :func:`opened`)."""

    def __init__(
        self,
        path: Path,
        fh: BinaryIO,
        reader: Any,
        layout: Layout,
        hint: str = RECOVER_HINT,
        summary: Any = None,
    ) -> None:
        self.path = path
        self.fh = fh
        self.reader = reader  # the mcap library's: summary, header and metadata records only
        self.layout = layout
        self.hint = hint
        # ``summary``: this file's summary section as parsed before (see _summary_of)
        if summary is None and layout.summary_start:
            summary = reader.get_summary()
        self.summary = summary
        indexes = self.summary.chunk_indexes if self.summary is not None else []
        self.spans = {
            c.chunk_start_offset: (c.message_start_time, c.message_end_time) for c in indexes
        }
        self.origin_ns = min((a for a, _b in self.spans.values()), default=None)
        # True once the data section's CRC (which covers every chunk) has been checked
        self.verified = False

    def error(self, e: Exception) -> InputError:
        """``e``, raised while reading this file, as the one-line :class:`InputError`."""
        return as_input_error(self.path, e, self.origin_ns, self.hint)

    def header(self) -> Any:
        """The MCAP Header record (``profile``, ``library``)."""
        try:
            return self.reader.get_header()
        except Exception as e:  # mcap raises many types on damaged files
            raise self.error(e) from None

    def metadata(self) -> list[Any]:
        """The metadata records (``name``, ``metadata``: a string map)."""
        try:
            return list(self.reader.iter_metadata())
        except Exception as e:
            raise self.error(e) from None

    def metadata_record(self, name: str) -> dict[str, str] | None:
        """The string map of the metadata record ``name`` (the first of that name), read
        alone through the summary's metadata index: no other record is opened (a file
        without a summary: the records in file order). None when there is none."""
        try:
            if self.summary is None:
                return next(
                    (m.metadata for m in self.reader.iter_metadata() if m.name == name), None
                )
            from mcap.records import Metadata
            from mcap.stream_reader import StreamReader

            for idx in self.summary.metadata_indexes:
                if idx.name == name:
                    self.fh.seek(idx.offset)
                    record = next(StreamReader(self.fh, skip_magic=True).records)
                    if not isinstance(record, Metadata) or record.name != name:
                        raise ValueError(f"metadata index of {name!r} points at no such record")
                    return dict(record.metadata)
            return None
        except Exception as e:
            raise self.error(e) from None

    def channels(self) -> dict[int, Any]:
        """Channel id → the mcap library's Channel record (``topic``, ``schema_id``, …)."""
        if self.summary is not None:
            return dict(self.summary.channels)
        return self._linear()[0]

    def schemas(self) -> dict[int, Any]:
        """Schema id → the mcap library's Schema record."""
        if self.summary is not None:
            return dict(self.summary.schemas)
        return self._linear()[1]

    def messages(
        self, topics: list[str] | None = None, order: Order = "log_time"
    ) -> Iterator[Message]:
        """The messages on ``topics`` (default all) as :data:`Message` tuples, in log-time
        order (ties: file order, as the mcap library's merge gives them) or, ``"topic"``,
        each topic's in log-time order, chunk after chunk in file order where the summary
        shows that is exact (:func:`chunks_in_file_order`). Every chunk is checked as it is
        decompressed (:func:`~gyrolab.record.integrity.chunk_data`); damage is an
        :class:`InputError` (only this file's: the caller's own errors pass untouched)."""
        try:
            summary = self.summary
            if summary is None or not summary.chunk_indexes:
                yield from self._unindexed(topics)
                return
            names = {
                cid: ch.topic
                for cid, ch in summary.channels.items()
                if topics is None or ch.topic in topics
            }
            chunks = chunks_in_file_order(summary, topics) if order == "topic" else None
            if chunks is None:
                yield from self._merged(names)
                return
            for ci in chunks:
                msgs = self._chunk(ci, names)
                if any(a[0] > b[0] for a, b in zip(msgs, msgs[1:], strict=False)):
                    msgs.sort(key=lambda m: m[0])  # stable: ties keep their place in the chunk
                for lt, cid, seq, pub, topic, data in msgs:
                    yield topic, lt, data, cid, seq, pub
        except Exception as e:
            raise self.error(e) from None

    def _chunk(self, ci: Any, names: dict[int, str]) -> list[Any]:
        """The messages on ``names``' channels of the chunk ``ci`` indexes, checked."""
        self.fh.seek(ci.chunk_start_offset)
        head = self.fh.read(9)
        length = ci.chunk_length - 9
        try:
            if len(head) < 9 or head[0] != OP_CHUNK or int.from_bytes(head[1:], "little") != length:
                raise Damage("the chunk index points at no chunk of that length")
            return chunk_messages(chunk_data(self.fh.read(length), not self.verified), names)
        except Damage as d:
            raise d.located(
                ci.chunk_start_offset, (ci.message_start_time, ci.message_end_time)
            ) from None

    def _merged(self, names: dict[int, str]) -> Iterator[Message]:
        """Every message on ``names``' channels by (log time, chunk offset, place in chunk):
        the order of the mcap library's log-time merge, one chunk decompressed when the
        merge reaches its first message time."""
        summary = self.summary
        wanted = set(names)
        todo = sorted(
            (
                ci
                for ci in summary.chunk_indexes
                if not ci.message_index_offsets or wanted.intersection(ci.message_index_offsets)
            ),
            key=lambda c: (c.message_start_time, c.chunk_start_offset),
        )
        heap: list[tuple[int, int, int, Any]] = []
        k = 0
        while k < len(todo) or heap:
            while k < len(todo) and (
                not heap or (todo[k].message_start_time, todo[k].chunk_start_offset) < heap[0][:2]
            ):
                ci = todo[k]
                k += 1
                off = ci.chunk_start_offset
                for i, m in enumerate(self._chunk(ci, names)):
                    heapq.heappush(heap, (m[0], off, i, m))
            if heap:
                lt, cid, seq, pub, topic, data = heapq.heappop(heap)[3]
                yield topic, lt, data, cid, seq, pub

    _walked: tuple[dict[int, Any], dict[int, Any], list[Message]] | None = None

    def _linear(self) -> tuple[dict[int, Any], dict[int, Any], list[Message]]:
        """Channels, schemas and every message of a file without a chunk index, from one
        walk over its data section (every chunk checked), messages in file order."""
        if self._walked is None:
            try:
                self._walked = self._walk()
            except Exception as e:
                raise self.error(e) from None
        return self._walked

    def _walk(self) -> tuple[dict[int, Any], dict[int, Any], list[Message]]:
        from mcap.data_stream import ReadDataStream
        from mcap.records import Channel, Schema

        channels: dict[int, Any] = {}
        schemas: dict[int, Any] = {}
        raw_msgs: list[Any] = []

        def take(op: int, buf: bytes, body: int, length: int) -> None:
            if op == OP_CHANNEL:
                ch = Channel.read(ReadDataStream(io.BytesIO(buf[body : body + length])))
                channels.setdefault(ch.id, ch)
            elif op == OP_SCHEMA:
                s = Schema.read(ReadDataStream(io.BytesIO(buf[body : body + length])))
                schemas.setdefault(s.id, s)
            elif op == OP_MESSAGE:
                if length < MESSAGE_HEAD.size:
                    raise Damage("a message record is shorter than its header", what="record")
                cid, seq, lt, pub = MESSAGE_HEAD.unpack_from(buf, body)
                raw_msgs.append((lt, cid, seq, pub, buf[body + MESSAGE_HEAD.size : body + length]))

        fh, pos, end = self.fh, len(MAGIC), self.layout.data_end
        while pos < end:
            fh.seek(pos)
            head = fh.read(9)
            op, length = head[0], int.from_bytes(head[1:9], "little")
            if pos + 9 + length > end:
                raise Damage("its length runs past the data section", what="record", offset=pos)
            body = fh.read(length)
            if op == OP_CHUNK:
                try:
                    raw = chunk_data(body)
                    for iop, ib, iln in records(raw):
                        take(iop, raw, ib, iln)
                except Damage as d:
                    raise d.located(pos, None) from None
            else:
                take(op, head + body, 9, length)
            pos += 9 + length
        msgs: list[Message] = []
        for lt, cid, seq, pub, data in raw_msgs:
            if cid not in channels:
                raise Damage(f"a message on undeclared channel {cid}", what="record")
            msgs.append((channels[cid].topic, lt, data, cid, seq, pub))
        return channels, schemas, msgs

    def _unindexed(self, topics: list[str] | None) -> Iterator[Message]:
        """Messages of a file without a chunk index: sorted stably by log time (ties in file
        order), which is each topic's log-time order too (either order)."""
        msgs = [m for m in self._linear()[2] if topics is None or m[0] in topics]
        msgs.sort(key=lambda m: m[1])
        yield from msgs


@contextlib.contextmanager
def opened(path: str | os.PathLike[str], hint: str = RECOVER_HINT) -> Iterator[Source]:
    """A :class:`Source` of ``path``, checked (:func:`~gyrolab.record.integrity.check_layout`,
    :func:`~gyrolab.record.integrity.check_data_section`), closed on exit. A missing or
    foreign file, a damaged one, and any error the mcap library raises on one is an
    :class:`InputError` (``hint`` appended), also from the :class:`Source`'s methods; an
    error of the caller's own code inside the ``with`` passes untouched."""
    p = existing_file(path)
    fh = open(p, "rb")
    try:
        src = _open(p, fh, hint)
        yield src
    finally:
        fh.close()


class FileIdentity(NamedTuple):
    """An open file's identity, from one ``fstat``: which file (device, inode) and its
    state (size, modification and status-change times, ns). Both caches below key on it."""

    dev: int
    ino: int
    size: int
    mtime_ns: int
    ctime_ns: int

    @classmethod
    def of(cls, fh: BinaryIO) -> FileIdentity:
        st = os.fstat(fh.fileno())
        return cls(st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)


#: Files whose data section's CRC this process has checked, by their whole identity: a
#: command opens its recording several times (metadata, units, each pass), and reading one
#: unit of a many-unit file would otherwise check every unit's bytes each time. Any write
#: changes the ctime, which nobody can set back; a file changed within :data:`_SETTLE_NS`
#: of the check is not remembered, as its stamps may not show a change that follows at
#: once (file-system timestamps have a granularity).
_CHECKED: set[FileIdentity] = set()
_SETTLE_NS = 2_000_000_000
_CHECKED_MAX = 4096


def _remember(ident: FileIdentity) -> None:
    if time.time_ns() - max(ident.mtime_ns, ident.ctime_ns) > _SETTLE_NS:
        if len(_CHECKED) >= _CHECKED_MAX:
            _CHECKED.clear()
        _CHECKED.add(ident)


#: The summary section last parsed, by the file (device, inode) and its summary (size,
#: summary offset, summary CRC): a command opens its recording several times (registration
#: after ``acquire``: five times), and parsing a long multi-unit run's chunk indexes is most
#: of an open's cost (0.45 s CPU for 8 units × 2 h, 35 000 chunks). ``check_layout`` has
#: checked the summary's bytes against that CRC on this very open, so the parse is of the
#: same bytes, however recently the file was written. One entry: a summary can be large.
_SUMMARY: dict[tuple[int, ...], Any] = {}


def _summary_key(ident: FileIdentity, layout: Layout) -> tuple[int, ...] | None:
    if not layout.summary_start or not layout.summary_crc:
        return None  # no summary, or one without a CRC to tell it is the same
    return (ident.dev, ident.ino, layout.size, layout.summary_start, layout.summary_crc)


def _open(p: Path, fh: BinaryIO, hint: str) -> Source:
    from mcap.reader import make_reader

    src: Source | None = None
    try:
        if fh.read(len(MAGIC)) != MAGIC:
            raise InputError(p, "not an MCAP file")
        layout = check_layout(fh)
        fh.seek(0)
        ident = FileIdentity.of(fh)
        skey = _summary_key(ident, layout)
        src = Source(p, fh, make_reader(fh), layout, hint, _SUMMARY.get(skey) if skey else None)
        if skey is not None and skey not in _SUMMARY:
            _SUMMARY.clear()
            _SUMMARY[skey] = src.summary
        if layout.data_crc:
            if ident not in _CHECKED:
                check_data_section(fh, layout, src.spans)
                _remember(ident)
            src.verified = True
        return src
    except InputError:
        raise
    except Exception as e:  # Damage, and the many types mcap raises on damaged files
        raise as_input_error(p, e, src.origin_ns if src else None, hint) from None


def as_input_error(
    path: Path, e: Exception, origin_ns: int | None, hint: str = RECOVER_HINT
) -> InputError:
    """``e``, raised while reading ``path``, as its one-line :class:`InputError`: a
    :class:`Damage` says where (times after ``origin_ns``), anything else what the mcap
    library said."""
    if isinstance(e, InputError):
        return e
    if isinstance(e, Damage):
        return InputError(path, e.describe(origin_ns) + hint)
    return InputError(path, f"damaged MCAP ({type(e).__name__}: {e}){hint}")
