"""Salvage a recording cut short by a crash (``gyrolab recover``).

A recording written by :class:`~gyrolab.record.writer.RecordingWriter` is an append-only
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
import json
import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gyrolab.errors import InputError, existing_file
from gyrolab.outputs import atomic_file
from gyrolab.record.blocks import decode_block
from gyrolab.record.integrity import (
    MAGIC,
    OP_CHANNEL,
    OP_CHUNK,
    OP_FOOTER,
    OP_HEADER,
    OP_MESSAGE,
    OP_METADATA,
    OP_SCHEMA,
    chunk_data,
    records,
)
from gyrolab.record.writer import McapFile, json_strings

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
    # Per topic, from the kept messages' sequence numbers (the writer counts each topic's
    # messages from 0): interior losses exactly, in messages and, for the gyro block
    # streams, in samples and seconds (see :func:`account`).
    lost: dict[str, dict[str, Any]] = field(default_factory=dict)
    # Seconds after the last kept gyro sample that the cut record is known to have held.
    tail_lost_s: float = 0.0
    end_event: str = ""  # "run_ended" | "aborted" | "" (no end recorded)
    end_detail: str = ""
    safe_state: str = "not recorded"  # "verified" | "failed" | "not recorded"
    safe_state_detail: str = ""
    cut_span_ns: tuple[int, int] | None = None  # the cut chunk's message time span

    @property
    def message_count(self) -> int:
        return sum(self.messages.values())

    def lost_seconds(self) -> float:
        """Seconds of gyro data known lost: the samples missing between kept blocks of
        ``/gyro/rate`` (else ``/gyro/adc``) plus the cut record's span after the last kept
        sample. Data the process held in memory at a crash never reached the file and is
        not counted (docs/reliability.md bounds it: 1.5 s)."""
        for topic in ("/gyro/rate", "/gyro/adc"):
            if topic in self.lost:
                return float(self.lost[topic].get("seconds", 0.0)) + self.tail_lost_s
        if not self.messages and self.lost_spans_ns:
            return sum(max(0, b - a) for a, b in self.lost_spans_ns) / 1e9
        return self.tail_lost_s

    def rel(self, t_ns: int) -> float:
        """A log time as seconds since the first kept message."""
        return (t_ns - (self.first_log_time_ns or t_ns)) / 1e9

    def account(self) -> str:
        """One line for a report header: ``recovered (1.2 s lost, safe state not confirmed)``."""
        safe = {
            "verified": "safe state confirmed",
            "failed": "safe state FAILED",
        }.get(self.safe_state, "safe state not confirmed")
        return f"recovered ({self.lost_seconds():.1f} s lost, {safe})"

    def summary(self) -> str:
        """The command line's account: what the file was, what was kept, what was lost."""
        if self.complete:
            state = "the file was complete (it had its footer)"
            if self.chunks_damaged:
                state += f", but {self.chunks_damaged} chunk(s) in it were damaged"
        else:
            state = "the file was cut short (no footer: the writer never finished it)"
        lines = [
            f"{self.account()}: {self.source}",
            f"  {state}",
            f"  kept {self.message_count} messages in {self.chunks_ok} chunks "
            f"({self.salvaged_bytes} of {self.size_bytes} bytes)",
        ]
        for topic in sorted(set(self.messages) | set(self.lost)):
            last = self.last_log_time_ns.get(topic)
            when = f", last at t={self.rel(last):.3f} s" if last is not None else ""
            lines.append(f"  {topic}: kept {self.messages.get(topic, 0)} messages{when}")
            lo = self.lost.get(topic)
            if lo and lo.get("messages"):
                what = f"{lo['messages']} message(s)"
                if "samples" in lo:
                    what += f" = {lo['samples']} samples ({lo['seconds']:.3f} s)"
                spans = ", ".join(f"t={a:.3f}–{b:.3f} s" for a, b in lo.get("spans_s", []))
                lines.append(f"    lost: {what}" + (f" at {spans}" if spans else ""))
        if self.truncated_tail_bytes:
            tail = f"lost: an incomplete last record of {self.truncated_tail_bytes} bytes"
            if self.cut_span_ns is not None:
                a, b = self.cut_span_ns
                tail += (
                    f": messages from t={self.rel(a):.3f} s to t={self.rel(b):.3f} s, "
                    f"{self.tail_lost_s:.3f} s after the last kept gyro sample"
                )
            lines.append(tail)
        if self.chunks_damaged:
            lines.append(f"lost: {self.chunks_damaged} damaged chunk(s) (bad CRC or data)")
        lines.append(f"gyro data lost in the file: {self.lost_seconds():.3f} s")
        if self.end_event:
            lines.append(f"run end recorded: {self.end_event} ({self.end_detail})")
        else:
            lines.append("run end: NOT recorded (no run_ended or aborted event survived)")
        if self.safe_state == "verified":
            lines.append(f"oven safe state: confirmed ({self.safe_state_detail})")
        elif self.safe_state == "failed":
            lines.append(f"oven safe state: FAILED ({self.safe_state_detail})")
        else:
            lines.append("oven safe state: never confirmed in the recording — check the chamber")
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
            "lost": {k: dict(v) for k, v in self.lost.items()},
            "tail_lost_s": self.tail_lost_s,
            "end_event": self.end_event,
            "end_detail": self.end_detail,
            "safe_state": self.safe_state,
            "safe_state_detail": self.safe_state_detail,
            "problems": list(self.problems),
        }

    def metadata_record(self) -> dict[str, Any]:
        """The ``recovery`` metadata record written into the recovered file
        (docs/recording-format.md): what recover found, for the report's header."""
        import datetime as _dt

        from gyrolab import __version__

        d = self.to_dict()
        d.pop("out", None)
        d["source"] = Path(self.source).name
        d["recovered_at"] = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
        d["software_version"] = __version__
        d["account"] = self.account()
        return d


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
    """Decompress and check one chunk record (:func:`~gyrolab.record.integrity.chunk_data`:
    size, CRC, framing); yield its inner records. Everything is framed before the first is
    yielded, so that a chunk is taken whole or not at all."""
    raw = chunk_data(body)
    yield from [(op, _Buf(raw[at : at + ln]), ln) for op, at, ln in records(raw)]


# ---------------------------------------------------------------------- recovery


def scan(path: str | os.PathLike[str]) -> tuple[RecoveryReport, dict[str, Any]]:
    """Read every complete record of ``path``; return the report and the salvaged content."""
    p = existing_file(path)
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
            if op == OP_CHUNK and n - i >= 9 + 16:
                # The chunk header (start/end log time) is the first thing in the record:
                # it says which span of messages went with the cut.
                a, b = struct.unpack_from("<QQ", mv, i + 9)
                if a <= b:
                    rep.lost_spans_ns.append((a, b))
                    rep.cut_span_ns = (a, b)
            break
        body = mv[i + 9 : i + 9 + ln]
        try:
            _take_record(op, body, ln, content, rep)
        except Exception as e:  # damage shows up as any of several decode errors
            if op == OP_CHUNK:
                rep.chunks_damaged += 1
                with contextlib.suppress(struct.error):
                    a, b = struct.unpack_from("<QQ", body, 0)
                    if a <= b:
                        rep.lost_spans_ns.append((a, b))
            else:
                rep.problems.append(f"skipped a damaged record (opcode 0x{op:02x}): {e}")
        i += 9 + ln
        rep.salvaged_bytes = i
        if op == OP_FOOTER:
            rep.complete = True
            if data[i : i + len(MAGIC)] == MAGIC:
                rep.salvaged_bytes += len(MAGIC)
            break
    _account(content, rep)
    return rep, content


_BLOCK_TOPICS = ("/gyro/rate", "/gyro/adc")


def _account(content: dict[str, Any], rep: RecoveryReport) -> None:
    """Fill ``rep.lost``, ``rep.tail_lost_s``, the run's end and its safe state.

    Losses inside the file come from each topic's message ``sequence`` (the writer numbers
    a topic's messages 0, 1, 2, …): a jump between kept messages is messages lost in a
    damaged chunk, and for a gyro block stream the jump in sample index across it is the
    samples lost (gaps that the acquisition itself logged, samples lost on the wire, are
    not counted: their messages are all there). The cut record's span after the last kept
    gyro sample is the tail. A file whose sequences are not a count (another writer) gets
    the damaged chunks' time spans instead.
    """
    by_topic: dict[str, list[_Message]] = {}
    for m in content["messages"]:
        by_topic.setdefault(content["channels"][m.channel_id].topic, []).append(m)
    gyro_end_ns: int | None = None
    for topic, msgs in by_topic.items():
        msgs.sort(key=lambda m: (m.sequence, m.log_time))
        seqs = [m.sequence for m in msgs]
        counted = all(b > a for a, b in zip(seqs, seqs[1:], strict=False))
        entry: dict[str, Any] = {"messages": 0}
        block = topic in _BLOCK_TOPICS
        blocks = []
        if block:
            kind = "adc" if topic == "/gyro/adc" else "rate"
            blocks = [decode_block(m.data, kind) for m in msgs]
            entry.update(samples=0, seconds=0.0, spans_s=[])
            t0, period, first, arr = blocks[-1]
            end_ns = msgs[-1].log_time + int(round(arr.size * period * 1e9))
            gyro_end_ns = end_ns if gyro_end_ns is None else max(gyro_end_ns, end_ns)
        if counted:
            prev_seq = -1
            for k, m in enumerate(msgs):
                jump = m.sequence - prev_seq - 1
                if jump > 0:
                    entry["messages"] += jump
                    if block:
                        t0, period, first, arr = blocks[k]
                        if k:
                            p0, pp, pf, parr = blocks[k - 1]
                            n_lost, start = first - (pf + parr.size), p0 + parr.size * pp
                        else:
                            n_lost, start = first, t0 - first * period
                        entry["samples"] += max(0, n_lost)
                        entry["seconds"] += max(0, n_lost) * period
                        entry["spans_s"].append((round(start, 6), round(t0, 6)))
                prev_seq = m.sequence
        elif block and rep.lost_spans_ns:
            for k in range(1, len(blocks)):
                p0, pp, pf, parr = blocks[k - 1]
                t0, period, first, arr = blocks[k]
                n_lost = first - (pf + parr.size)
                a_ns, b_ns = msgs[k - 1].log_time, msgs[k].log_time
                if n_lost > 0 and any(a <= b_ns and b >= a_ns for a, b in rep.lost_spans_ns):
                    entry["messages"] += 1
                    entry["samples"] += n_lost
                    entry["seconds"] += n_lost * period
                    entry["spans_s"].append((round(p0 + parr.size * pp, 6), round(t0, 6)))
        if entry["messages"]:
            rep.lost[topic] = entry
    if rep.cut_span_ns is not None:
        a, b = rep.cut_span_ns
        rep.tail_lost_s = max(0, b - (gyro_end_ns if gyro_end_ns is not None else a)) / 1e9
    for m in sorted(by_topic.get("/profile/event", []), key=lambda m: m.log_time):
        try:
            ev = json.loads(m.data)
        except ValueError:
            continue
        name = str(ev.get("event", ""))
        if name in ("run_ended", "aborted"):
            rep.end_event, rep.end_detail = name, str(ev.get("detail", ""))
        elif name == "safe_state":
            detail = str(ev.get("detail", ""))
            rep.safe_state = "failed" if detail.startswith("FAILED") else "verified"
            rep.safe_state_detail = detail


def _take_record(
    op: int, body: memoryview, ln: int, content: dict[str, Any], rep: RecoveryReport
) -> None:
    b = _Buf(body)
    if op == OP_HEADER:
        content["header"] = (b.string(), b.string())
    elif op == OP_SCHEMA:
        s = _parse_schema(b)
        content["schemas"].setdefault(s.id, s)
    elif op == OP_CHANNEL:
        c = _parse_channel(b)
        content["channels"].setdefault(c.id, c)
    elif op == OP_MESSAGE:
        _add_message(_parse_message(b, ln), content, rep)
    elif op == OP_METADATA:
        name = b.string()
        content["metadata"].append((name, b.string_map()))
        rep.metadata.append(name)
    elif op == OP_CHUNK:
        staged_s: dict[int, _Schema] = {}
        staged_c: dict[int, _Channel] = {}
        staged_m: list[_Message] = []
        for iop, ib, iln in _chunk_records(body):
            if iop == OP_SCHEMA:
                s = _parse_schema(ib)
                staged_s[s.id] = s
            elif iop == OP_CHANNEL:
                c = _parse_channel(ib)
                staged_c[c.id] = c
            elif iop == OP_MESSAGE:
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
    profile, library = content["header"]
    w = McapFile(fh, profile=profile, library=library or "gyrolab recover")
    # The writer numbers schemas and channels itself (1, 2, …); map the old ids.
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
        w.add_message(cid_map[m.channel_id], m.log_time, m.data, m.publish_time, m.sequence)
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
    # What recover found travels with the data: the report's header reads it.
    content["metadata"] = [(n, v) for n, v in content["metadata"] if n != "recovery"]
    content["metadata"].append(("recovery", json_strings(rep.metadata_record())))
    with atomic_file(out, force, inputs=(broken,)) as tmp:
        with open(tmp, "wb") as fh:
            write_salvaged(content, fh)
    rep.out = str(out)
    return rep
