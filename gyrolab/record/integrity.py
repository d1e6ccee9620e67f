"""Checked reads of MCAP files: the bytes a reader uses are verified before it uses them.

MCAP (https://mcap.dev/spec) carries three CRC-32s, each 0 when its writer did not compute it:

* every **chunk**'s, of its uncompressed records (gyrolab and the mcap libraries always write it);
* the **summary section**'s (in the Footer), over the summary and the footer's own offsets —
  schemas, channels, chunk indexes, metadata indexes, statistics;
* the **data section**'s (in the DataEnd record), over every byte before it: header,
  metadata records, chunks, message indexes. gyrolab writes it from this version on
  (:class:`~gyrolab.record.writer.McapFile`); older files have 0, and their metadata records
  (which MCAP gives no CRC of their own) are read unchecked.

:func:`check_file` checks the file's end (footer, DataEnd), the summary's CRC and the data
section's CRC — one pass of ``zlib.crc32`` over the file (≈ 3 GB/s) — and, on a mismatch,
finds the first damaged record (:func:`locate_damage`). :func:`chunk_data` decompresses a
chunk and checks its size and CRC; :func:`chunk_messages` frames its records on their
lengths. Each raises :class:`Damage`; :mod:`gyrolab.record.reader` turns it into the
one-line error that names the chunk's byte offset and time span. ``gyrolab recover``
(:mod:`gyrolab.record.recover`) uses the same chunk check to salvage the rest.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import BinaryIO

MAGIC = b"\x89MCAP0\r\n"
OP_HEADER = 0x01
OP_FOOTER = 0x02
OP_SCHEMA = 0x03
OP_CHANNEL = 0x04
OP_MESSAGE = 0x05
OP_CHUNK = 0x06
OP_METADATA = 0x0C
OP_DATA_END = 0x0F

_FOOTER = struct.Struct("<BQQQI")  # opcode, length 20, summary start, summary offset start, CRC
_FOOTER_CRC_PART = struct.Struct("<BQQQ")  # what the summary CRC covers of the footer
_DATA_END = struct.Struct("<BQI")  # opcode, length 4, data section CRC
_RECORD_HEAD = struct.Struct("<BQ")  # opcode, length
_CHUNK_HEAD = struct.Struct("<QQQII")  # start, end, uncompressed size, CRC, compression length
_U64 = struct.Struct("<Q")
#: Message record body: channel id, sequence, log time, publish time, then the data.
MESSAGE_HEAD = struct.Struct("<HIQQ")
#: A chunk that claims more uncompressed bytes than this is damage (the mcap library's own
#: record limit is 4 GiB; gyrolab's chunks are ≤ 1 MiB).
MAX_CHUNK_BYTES = 1 << 32
_BLOCK = 1 << 18  # bytes per read while summing the data section's CRC (one buffer)


class Damage(ValueError):
    """A damaged part of an MCAP file: what is wrong, where (``offset``, bytes from the
    start of the file) and, for a chunk, the span of log times (ns) its messages cover."""

    def __init__(
        self,
        problem: str,
        *,
        offset: int | None = None,
        what: str = "chunk",
        span_ns: tuple[int, int] | None = None,
    ) -> None:
        super().__init__(problem)
        self.problem = problem
        self.offset = offset
        self.what = what
        self.span_ns = span_ns

    def located(self, offset: int, span_ns: tuple[int, int] | None) -> Damage:
        """The same damage, placed in the file (a chunk's offset and its indexed span)."""
        return Damage(self.problem, offset=offset, what=self.what, span_ns=span_ns)

    def describe(self, origin_ns: int | None) -> str:
        """``damaged chunk at byte 1234 (messages at t=10.000–11.000 s): CRC mismatch``;
        times in seconds after ``origin_ns`` (the file's first message). Damage to the
        file as a whole (``what="file"``) is its problem alone: ``truncated: …``."""
        if self.what == "file":
            return self.problem
        where = f"damaged {self.what}" + (
            f" at byte {self.offset}" if self.offset is not None else ""
        )
        if self.span_ns is not None:
            a, b = self.span_ns
            o = a if origin_ns is None else origin_ns
            where += f" (messages at t={(a - o) / 1e9:.3f}–{(b - o) / 1e9:.3f} s)"
        return f"{where}: {self.problem}"


@dataclass(frozen=True)
class Layout:
    """Where a complete MCAP file's sections are (bytes from the start of the file)."""

    size: int
    data_end: int  # offset of the DataEnd record: the data section is [0, data_end)
    summary_start: int  # 0: no summary section
    data_crc: int  # 0: not computed by the writer
    summary_crc: int


def _crc_of(fh: BinaryIO, start: int, end: int, crc: int = 0) -> int:
    """CRC-32 of the file's bytes ``[start, end)``, read through one small buffer."""
    buf = memoryview(bytearray(min(_BLOCK, max(0, end - start))))
    fh.seek(start)
    left = end - start
    while left > 0:
        n = fh.readinto(buf[: min(len(buf), left)])
        if not n:
            raise Damage("the file ends inside its data section", what="file")
        crc = zlib.crc32(buf[:n], crc)
        left -= n
    return crc


def check_layout(fh: BinaryIO) -> Layout:
    """The file's footer and DataEnd record where MCAP puts them, and the summary's CRC.
    Raises :class:`Damage` for a file cut short (no footer) or damaged at its end."""
    size = fh.seek(0, 2)
    footer_at = size - _FOOTER.size - len(MAGIC)
    if footer_at < len(MAGIC):
        raise Damage(f"truncated: {size} bytes, no MCAP footer", what="file")
    fh.seek(footer_at)
    tail = fh.read(_FOOTER.size + len(MAGIC))
    op, length, ss, sos, scrc = _FOOTER.unpack_from(tail)
    if tail[_FOOTER.size :] != MAGIC or op != OP_FOOTER or length != _FOOTER.size - 9:
        raise Damage(
            "truncated: no MCAP footer at its end (the writer never finished it, or its end "
            "is damaged)",
            what="file",
        )
    if ss and not len(MAGIC) < ss <= footer_at or sos and not (ss or 0) <= sos <= footer_at:
        raise Damage(
            "the footer's section offsets point outside the file", what="footer", offset=footer_at
        )
    if scrc:
        crc = _crc_of(fh, ss or footer_at, footer_at)
        crc = zlib.crc32(_FOOTER_CRC_PART.pack(OP_FOOTER, _FOOTER.size - 9, ss, sos), crc)
        if crc != scrc:
            raise Damage("its CRC does not match", what="summary section", offset=ss or footer_at)
    data_end = (ss or footer_at) - _DATA_END.size
    fh.seek(data_end)
    op, length, dcrc = _DATA_END.unpack(fh.read(_DATA_END.size))
    if op != OP_DATA_END or length != 4:
        raise Damage(
            "its opcode or length is wrong (it ends the data section)",
            what="DataEnd record",
            offset=data_end,
        )
    return Layout(size, data_end, ss, dcrc, scrc)


def check_data_section(
    fh: BinaryIO, layout: Layout, spans: Mapping[int, tuple[int, int]] | None = None
) -> None:
    """Compare the data section's CRC with the DataEnd record's (nothing to do when the
    writer left it 0); on a mismatch raise the first damage :func:`locate_damage` finds.
    ``spans``: chunk offset → indexed log-time span (from the checked summary)."""
    if layout.data_crc and _crc_of(fh, 0, layout.data_end) != layout.data_crc:
        raise locate_damage(fh, layout.data_end, spans)


def locate_damage(
    fh: BinaryIO, end: int, spans: Mapping[int, tuple[int, int]] | None = None
) -> Damage:
    """The first damaged record of ``[8, end)``: a length that runs past ``end``, or a chunk
    whose data does not decompress to its size and CRC; when every record frames and
    checks, the damage is in bytes no record CRC covers (header, metadata, message
    indexes) and the data section's CRC is all that caught it."""
    pos = len(MAGIC)
    while pos < end:
        fh.seek(pos)
        head = fh.read(_RECORD_HEAD.size)
        if len(head) < _RECORD_HEAD.size:
            return Damage("the file ends inside a record", what="record", offset=pos)
        op, length = _RECORD_HEAD.unpack(head)
        if pos + _RECORD_HEAD.size + length > end:
            return Damage("its length runs past the data section", what="record", offset=pos)
        if op == OP_CHUNK:
            span = (spans or {}).get(pos)
            try:
                chunk_data(fh.read(length))
            except Damage as d:
                return d.located(pos, span)
        pos += _RECORD_HEAD.size + length
    return Damage(
        "the data section's CRC does not match, in bytes outside the chunks (the header, a "
        "metadata record or a message index)",
        what="data section",
    )


def chunk_data(body: bytes | memoryview, check_crc: bool = True) -> bytes:
    """The uncompressed records of a chunk record's ``body`` (everything after its opcode
    and length), checked: the fields frame the body exactly, the data decompresses to the
    declared size, and its CRC-32 matches (when the writer computed one). ``check_crc=False``
    where the data section's CRC, which covers every byte of the chunk record, was checked
    already: computing the chunk's own over its uncompressed bytes would add nothing."""
    mv = memoryview(body)
    if len(mv) < _CHUNK_HEAD.size:
        raise Damage("its header is cut short")
    _start, _end, usize, crc, clen = _CHUNK_HEAD.unpack_from(mv)
    at = _CHUNK_HEAD.size + clen
    if at + 8 > len(mv):
        raise Damage("its compression name runs past the chunk")
    try:
        compression = str(mv[_CHUNK_HEAD.size : at], "utf-8")
    except UnicodeDecodeError:
        raise Damage("its compression name is not text") from None
    (dlen,) = _U64.unpack_from(mv, at)
    data = mv[at + 8 :]
    if dlen != len(data):
        raise Damage(f"its records take {dlen} bytes of a {len(data)}-byte body")
    if usize > MAX_CHUNK_BYTES:
        raise Damage(f"it claims {usize} uncompressed bytes")
    raw = _decompress(compression, data, usize)
    if len(raw) != usize:
        raise Damage(f"it decompresses to {len(raw)} bytes, not {usize}")
    if check_crc and crc and zlib.crc32(raw) != crc:
        raise Damage("CRC mismatch")
    return raw


def _decompress(compression: str, data: memoryview, usize: int) -> bytes:
    if compression == "":
        return bytes(data)
    if compression == "zstd":
        import zstandard

        # The frame's own size field is checked first: a damaged one would otherwise make
        # the decompressor allocate whatever it says.
        try:
            declared = zstandard.frame_content_size(data)
        except zstandard.ZstdError as e:
            raise Damage(f"zstd: {e}") from None
        if declared not in (-1, usize):
            raise Damage(f"its zstd frame declares {declared} bytes, the chunk {usize}")
        try:
            return zstandard.ZstdDecompressor().decompress(data, max_output_size=usize)
        except zstandard.ZstdError as e:
            raise Damage(f"zstd: {e}") from None
    if compression == "lz4":
        import lz4.frame  # type: ignore[import-not-found]

        try:
            return bytes(lz4.frame.decompress(bytes(data)))
        except RuntimeError as e:
            raise Damage(f"lz4: {e}") from None
    raise Damage(f"unknown compression {compression!r}")


def records(raw: bytes | memoryview) -> Iterator[tuple[int, int, int]]:
    """``(opcode, body offset, body length)`` of every record in ``raw`` (a chunk's
    uncompressed data), framed on their lengths; a length past the end is :class:`Damage`."""
    head, size = _RECORD_HEAD.unpack_from, len(raw)
    pos = 0
    while pos < size:
        if pos + _RECORD_HEAD.size > size:
            raise Damage("its records end inside a record header")
        op, length = head(raw, pos)
        body = pos + _RECORD_HEAD.size
        if body + length > size:
            raise Damage("a record's length runs past the chunk")
        yield op, body, length
        pos = body + length


def chunk_messages(
    raw: bytes, channels: Mapping[int, str]
) -> list[tuple[int, int, int, int, str, bytes]]:
    """``(log_time, channel_id, sequence, publish_time, topic, data)`` of the messages in a
    chunk's records (``raw``) on ``channels`` (id → topic), in chunk order; the records
    framed on their lengths as :func:`records` does (inlined: this is the hot loop of every
    read). A record past the end, or a message shorter than its header, is :class:`Damage`."""
    head, head_size = MESSAGE_HEAD.unpack_from, MESSAGE_HEAD.size
    record = _RECORD_HEAD.unpack_from
    size = len(raw)
    out = []
    pos = 0
    while pos + 9 <= size:
        op, length = record(raw, pos)
        body = pos + 9
        end = body + length
        if end > size:
            raise Damage("a record's length runs past the chunk")
        if op == OP_MESSAGE:
            if length < head_size:
                raise Damage("a message record is shorter than its header")
            cid, seq, log_time, pub = head(raw, body)
            topic = channels.get(cid)
            if topic is not None:
                out.append((log_time, cid, seq, pub, topic, raw[body + head_size : end]))
        pos = end
    if pos != size:
        raise Damage("its records end inside a record header")
    return out
