"""The peer of gyrolab's MCAP records: the ``mcap`` library's ``Writer`` behind the methods
of :class:`gyrolab.record.writer.McapFile` (``tests/test_mcap_file.py`` compares the
files byte for byte, ``bench_mcap_write.py`` times both)."""

from __future__ import annotations

from mcap.writer import CompressionType, Writer

from gyrolab.record.format import PROFILE
from gyrolab.record.writer import LIBRARY

COMPRESSION = {
    "zstd": CompressionType.ZSTD,
    "lz4": CompressionType.LZ4,
    "none": CompressionType.NONE,
}


class LibraryMcapFile:
    """``McapFile``'s calls on the ``mcap`` library's ``Writer`` (what gyrolab used before
    it wrote its own records): the reference its bytes are compared with."""

    def __init__(
        self, fh, *, profile=PROFILE, library=LIBRARY, chunk_size=1 << 20, compression="zstd"
    ) -> None:
        self.w = Writer(
            fh, chunk_size=chunk_size, compression=COMPRESSION[compression], enable_data_crcs=True
        )
        self.w.start(profile=profile, library=library)

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        return int(self.w.register_schema(name, encoding, data))

    def register_channel(self, topic, encoding, schema_id, metadata=None) -> int:
        return int(self.w.register_channel(topic, encoding, schema_id, dict(metadata or {})))

    def add_message(self, chan, log_time, data, publish_time, sequence) -> None:
        self.w.add_message(
            chan, log_time=log_time, data=data, publish_time=publish_time, sequence=sequence
        )

    def add_messages(self, messages) -> None:
        for chan, ts, data, seq in messages:
            self.add_message(chan, ts, data, ts, seq)

    def close_chunk(self) -> None:
        self.w.flush()

    def add_metadata(self, name, values) -> None:
        self.w.add_metadata(name, dict(values))

    def flush(self) -> None:
        self.w.flush()

    def finish(self) -> None:
        self.w.finish()
