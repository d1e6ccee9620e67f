"""Salvage a recording cut short by a crash (``gyrolab recover``).

A recording written by :class:`~gyrolab.recording.RecordingWriter` is an append-only
sequence of MCAP records: magic, header, the ``run`` and ``bench`` metadata, then one
chunk (schemas, channels, messages; zstd; CRC-32 of the uncompressed bytes) plus its
message indexes per flush. A ``kill -9`` or a power cut leaves every record that reached
the file intact and at most one record cut short at the end, with no summary or footer.

:func:`recover_recording` walks the records one by one on their length prefixes (it never
trusts a summary), keeps every complete record whose CRC checks, skips a damaged chunk
(and says so) and stops at the first record that runs past the end of the file. It writes
the salvaged schemas, channels, messages and metadata to a new, complete MCAP file, and
returns a :class:`RecoveryReport` saying what was kept and what was lost: the truncated
tail's size and, when the cut chunk's header survived, the time span its messages covered.

Why not ``mcap.stream_reader.StreamReader``: on a cut file it yields records until it
raises ``EndOfFile`` (or a struct error) inside the last one, and a damaged chunk (with
``validate_crcs``) ends the iteration too; it cannot skip a bad chunk and go on, nor say
what the cut record held. Walking the length prefixes here does both.
"""

from __future__ import annotations

import contextlib
import io
import os
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gyrolab.errors import InputError
from gyrolab.outputs import atomic_file

MAGIC = b"\x89MCAP0\r\n"
_OP_HEADER = 0x01
_OP_FOOTER = 0x02
_OP_SCHEMA = 0x03
_OP_CHANNEL = 0x04
_OP_MESSAGE = 0x05
_OP_CHUNK = 0x06
_OP_METADATA = 0x0C
_OP_DATA_END = 0x0F
# A single record larger than this is damage, not data (a 13-h run's chunks are ~kB).
_MAX_RECORD = 1 << 31


@dataclass
class RecoveryReport:
    """What :func:`recover_recording` kept and what it could not."""

    source: str
    out: str = ""
    size_bytes: int = 0
    complete: bool = False  # the source already had its footer
    salvaged_bytes: int = 0  # bytes of the source covered by records that were kept
    truncated_tail_bytes: int = 0  # bytes of an incomplete last record, dropped
    chunks_ok: int = 0
    chunks_damaged: int = 0
    messages: dict[str, int] = field(default_factory=dict)
    metadata: list[str] = field(default_factory=list)
    last_log_time_ns: dict[str, int] = field(default_factory=dict)
    first_log_time_ns: int | None = None
    # Time span (log_time ns) of messages known to be lost: the cut chunk's header, when
    # its first 16 bytes survived, and every damaged chunk.
    lost_spans_ns: list[tuple[int, int]] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)

    @property
    def message_count(self) -> int:
        return sum(self.messages.values())

    def lost_seconds(self) -> float:
        """Length of the known-lost spans, in seconds (0 when nothing is known lost)."""
        return sum(max(0, b - a) for a, b in self.lost_spans_ns) / 1e9

    def summary(self) -> str:
        """A few human lines for the command line."""
        lines = [
            f"recovered {self.message_count} messages in {self.chunks_ok} chunks "
            f"from {self.source} ({self.salvaged_bytes} of {self.size_bytes} bytes)"
            + (" — the file was already complete" if self.complete else ""),
        ]
        for topic in sorted(self.messages):
            last = self.last_log_time_ns.get(topic)
            rel = (
                f", last at t={(last - self.first_log_time_ns) / 1e9:.3f} s"
                if last is not None and self.first_log_time_ns is not None
                else ""
            )
            lines.append(f"  {topic}: {self.messages[topic]} messages{rel}")
        if self.truncated_tail_bytes:
            lines.append(f"lost: an incomplete last record of {self.truncated_tail_bytes} bytes")
        if self.chunks_damaged:
            lines.append(f"lost: {self.chunks_damaged} damaged chunk(s) (bad CRC or data)")
        if self.lost_spans_ns and self.first_log_time_ns is not None:
            for a, b in self.lost_spans_ns:
                lines.append(
                    f"lost: messages from t={(a - self.first_log_time_ns) / 1e9:.3f} s "
                    f"to t={(b - self.first_log_time_ns) / 1e9:.3f} s"
                )
        lines.extend(f"note: {p}" for p in self.problems)
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        return {
            "source": self.source,
            "out": self.out,
            "size_bytes": self.size_bytes,
            "complete": self.complete,
            "salvaged_bytes": self.salvaged_bytes,
            "truncated_tail_bytes": self.truncated_tail_bytes,
            "chunks_ok": self.chunks_ok,
            "chunks_damaged": self.chunks_damaged,
            "messages": dict(self.messages),
            "metadata": list(self.metadata),
            "lost_seconds": self.lost_seconds(),
            "problems": list(self.problems),
        }


# ---------------------------------------------------------------- record parsing


class _Buf:
    """A little-endian cursor over one record's bytes; raises ValueError past the end."""

    def __init__(self, data: bytes | memoryview) -> None:
        self.mv = memoryview(data)
        self.i = 0

    def take(self, n: int) -> memoryview:
        if n < 0 or self.i + n > len(self.mv):
            raise ValueError("record field runs past the record")
        out = self.mv[self.i : self.i + n]
        self.i += n
        return out

    def u16(self) -> int:
        return struct.unpack("<H", self.take(2))[0]

    def u32(self) -> int:
        return struct.unpack("<I", self.take(4))[0]

    def u64(self) -> int:
        return struct.unpack("<Q", self.take(8))[0]

    def string(self) -> str:
        return str(self.take(self.u32()), "utf-8")

    def bytes32(self) -> bytes:
        return bytes(self.take(self.u32()))

    def string_map(self) -> dict[str, str]:
        end = self.u32() + self.i
        out: dict[str, str] = {}
        while self.i < end:
            k = self.string()
            out[k] = self.string()
        return out


@dataclass
class _Schema:
    id: int
    name: str
    encoding: str
    data: bytes


@dataclass
class _Channel:
    id: int
    schema_id: int
    topic: str
    message_encoding: str
    metadata: dict[str, str]


@dataclass
class _Message:
    channel_id: int
    sequence: int
    log_time: int
    publish_time: int
    data: bytes


def _parse_schema(b: _Buf) -> _Schema:
    sid = b.u16()
    name = b.string()
    enc = b.string()
    return _Schema(sid, name, enc, b.bytes32())


def _parse_channel(b: _Buf) -> _Channel:
    cid = b.u16()
    sid = b.u16()
    topic = b.string()
    enc = b.string()
    return _Channel(cid, sid, topic, enc, b.string_map())


def _parse_message(b: _Buf, length: int) -> _Message:
    cid = b.u16()
    seq = b.u32()
    log_time = b.u64()
    pub = b.u64()
    return _Message(cid, seq, log_time, pub, bytes(b.take(length - 22)))


def _chunk_records(body: memoryview) -> Iterator[tuple[int, _Buf, int]]:
    """Decompress and CRC-check one chunk record; yield its inner records."""
    b = _Buf(body)
    b.u64()  # message_start_time
    b.u64()  # message_end_time
    usize = b.u64()
    crc = b.u32()
    compression = b.string()
    data = b.take(b.u64())
    if compression == "zstd":
        import zstandard

        raw = zstandard.ZstdDecompressor().decompress(bytes(data), max_output_size=usize)
    elif compression == "lz4":
        import lz4.frame  # type: ignore[import-not-found]

        raw = lz4.frame.decompress(bytes(data))
    elif compression == "":
        raw = bytes(data)
    else:
        raise ValueError(f"unknown chunk compression {compression!r}")
    if len(raw) != usize:
        raise ValueError("chunk decompressed to the wrong size")
    if crc and zlib.crc32(raw) != crc:
        raise ValueError("chunk CRC mismatch")
    inner = _Buf(raw)
    # Parse everything first so that a chunk is taken whole or not at all.
    out = []
    while inner.i < len(raw):
        op = inner.take(1)[0]
        ln = inner.u64()
        out.append((op, _Buf(inner.take(ln)), ln))
    yield from out


# ---------------------------------------------------------------------- recovery


def scan(path: str | os.PathLike[str]) -> tuple[RecoveryReport, dict[str, Any]]:
    """Read every complete record of ``path``; return the report and the salvaged content."""
    p = Path(path)
    if not p.is_file():
        raise InputError(p, "file not found")
    data = p.read_bytes()
    rep = RecoveryReport(source=str(p), size_bytes=len(data))
    if len(data) < len(MAGIC) or data[: len(MAGIC)] != MAGIC:
        raise InputError(p, "not an MCAP file (bad magic); nothing to recover")
    content: dict[str, Any] = {
        "header": ("", ""),
        "schemas": {},
        "channels": {},
        "messages": [],
        "metadata": [],
    }
    mv = memoryview(data)
    i = len(MAGIC)
    n = len(data)
    while i < n:
        if n - i < 9:
            rep.truncated_tail_bytes = n - i
            break
        op = mv[i]
        (ln,) = struct.unpack_from("<Q", mv, i + 1)
        if ln > _MAX_RECORD or i + 9 + ln > n:
            rep.truncated_tail_bytes = n - i
            if op == _OP_CHUNK and n - i >= 9 + 16:
                # The chunk header (start/end log time) is the first thing in the record:
                # it says which span of messages went with the cut.
                a, b = struct.unpack_from("<QQ", mv, i + 9)
                if a <= b:
                    rep.lost_spans_ns.append((a, b))
            break
        body = mv[i + 9 : i + 9 + ln]
        try:
            _take_record(op, body, ln, content, rep)
        except Exception as e:  # damage shows up as any of several decode errors
            if op == _OP_CHUNK:
                rep.chunks_damaged += 1
                with contextlib.suppress(struct.error):
                    a, b = struct.unpack_from("<QQ", body, 0)
                    if a <= b:
                        rep.lost_spans_ns.append((a, b))
            else:
                rep.problems.append(f"skipped a damaged record (opcode 0x{op:02x}): {e}")
        i += 9 + ln
        rep.salvaged_bytes = i
        if op == _OP_FOOTER:
            rep.complete = True
            if data[i : i + len(MAGIC)] == MAGIC:
                rep.salvaged_bytes += len(MAGIC)
            break
    return rep, content


def _take_record(
    op: int, body: memoryview, ln: int, content: dict[str, Any], rep: RecoveryReport
) -> None:
    b = _Buf(body)
    if op == _OP_HEADER:
        content["header"] = (b.string(), b.string())
    elif op == _OP_SCHEMA:
        s = _parse_schema(b)
        content["schemas"].setdefault(s.id, s)
    elif op == _OP_CHANNEL:
        c = _parse_channel(b)
        content["channels"].setdefault(c.id, c)
    elif op == _OP_MESSAGE:
        _add_message(_parse_message(b, ln), content, rep)
    elif op == _OP_METADATA:
        name = b.string()
        content["metadata"].append((name, b.string_map()))
        rep.metadata.append(name)
    elif op == _OP_CHUNK:
        staged_s: dict[int, _Schema] = {}
        staged_c: dict[int, _Channel] = {}
        staged_m: list[_Message] = []
        for iop, ib, iln in _chunk_records(body):
            if iop == _OP_SCHEMA:
                s = _parse_schema(ib)
                staged_s[s.id] = s
            elif iop == _OP_CHANNEL:
                c = _parse_channel(ib)
                staged_c[c.id] = c
            elif iop == _OP_MESSAGE:
                staged_m.append(_parse_message(ib, iln))
        for sid, s in staged_s.items():
            content["schemas"].setdefault(sid, s)
        for cid, c in staged_c.items():
            content["channels"].setdefault(cid, c)
        for m in staged_m:
            _add_message(m, content, rep)
        rep.chunks_ok += 1
    # Message indexes, chunk indexes, statistics, summary offsets: rebuilt by the writer.


def _add_message(m: _Message, content: dict[str, Any], rep: RecoveryReport) -> None:
    ch = content["channels"].get(m.channel_id)
    if ch is None:
        rep.problems.append(f"message on unknown channel {m.channel_id} dropped")
        return
    content["messages"].append(m)
    rep.messages[ch.topic] = rep.messages.get(ch.topic, 0) + 1
    prev = rep.last_log_time_ns.get(ch.topic)
    rep.last_log_time_ns[ch.topic] = m.log_time if prev is None else max(prev, m.log_time)
    if rep.first_log_time_ns is None or m.log_time < rep.first_log_time_ns:
        rep.first_log_time_ns = m.log_time


def write_salvaged(content: dict[str, Any], fh: io.BufferedWriter | Any) -> None:
    """Write salvaged content as a complete MCAP file (chunked, zstd, indexed)."""
    from mcap.writer import CompressionType, Writer

    w = Writer(fh, chunk_size=1 << 20, compression=CompressionType.ZSTD)
    profile, library = content["header"]
    w.start(profile=profile, library=library or "gyrolab recover")
    # mcap's Writer numbers schemas and channels itself (1, 2, …); map the old ids.
    sid_map: dict[int, int] = {0: 0}
    for sid in sorted(content["schemas"]):
        s = content["schemas"][sid]
        sid_map[sid] = w.register_schema(s.name, s.encoding, s.data)
    cid_map: dict[int, int] = {}
    for cid in sorted(content["channels"]):
        c = content["channels"][cid]
        cid_map[cid] = w.register_channel(
            c.topic, c.message_encoding, sid_map.get(c.schema_id, 0), c.metadata
        )
    for name, values in content["metadata"]:
        w.add_metadata(name, values)
    for m in content["messages"]:
        w.add_message(
            cid_map[m.channel_id],
            log_time=m.log_time,
            data=m.data,
            publish_time=m.publish_time,
            sequence=m.sequence,
        )
    w.finish()


def recover_recording(
    broken: str | os.PathLike[str], out: str | os.PathLike[str], force: bool = False
) -> RecoveryReport:
    """Salvage ``broken`` into a new, complete recording at ``out`` (written atomically)."""
    if Path(out).resolve() == Path(broken).resolve():
        raise InputError(out, "--out must differ from the broken file (it is kept as evidence)")
    rep, content = scan(broken)
    if not content["channels"] and not content["metadata"]:
        raise InputError(broken, "no complete record survived; nothing to recover")
    if not content["channels"]:
        # Killed before its first flush: the header and metadata are still a valid (empty)
        # recording of the run, and say what it was.
        rep.problems.append("no chunk was complete: the recovered file holds no messages")
    with atomic_file(out, force, inputs=(broken,)) as tmp:
        with open(tmp, "wb") as fh:
            write_salvaged(content, fh)
    rep.out = str(out)
    return rep
