"""Writing recordings: an MCAP file with the contract's schemas, channels and metadata,
written to a temporary name and renamed into place only when complete.

The file has the layout of mcap's own ``Writer`` (zstd chunks with per-channel message indexes; a
summary with schemas, channels, statistics, chunk and metadata indexes and summary offsets; data-section
and summary CRCs), and every record other than a message is mcap's record class. Message records are
built here instead, with NumPy for a batch (:meth:`RecordingWriter.write_batch`): mcap's ``Writer``
builds each message in Python, about 7 µs each, which was most of a twin replay's time (8,000 messages
a replay); a batch of a twin replay's five streams costs about 1.2 µs a message. mcap's and rosbags'
readers read the files back (tests/test_recording_codec.py).
"""

from __future__ import annotations

import os
import struct
import zlib
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType

import numpy as np
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

from schemas.messages import (
    MESSAGE_ENCODING,
    METADATA_NAME,
    MSG_DEFINITIONS,
    SCHEMA_ENCODING,
    SCHEMA_VERSION,
    STREAMS_BY_KIND,
    VIEWER_TOPICS,
)
from schemas.rig import DEFAULT_RIG, Rig

MAGIC = b"\x89MCAP0\r\n"
# a message record: opcode u8, length u64, then channel id u16, sequence u32, log time u64, publish time u64
_MESSAGE_HEAD = struct.Struct("<BQHIQQ")
_MESSAGE_FIELDS = _MESSAGE_HEAD.size - 9  # the record length counts what follows opcode and length
_MESSAGE_DTYPE = np.dtype(
    [("opcode", "u1"), ("length", "<u8"), ("channel", "<u2"), ("sequence", "<u4"), ("log", "<u8"), ("pub", "<u8")]
)


class _OpenChunk:
    """The messages not yet written to the file: their records, and each one's channel, log time and offset
    (from the chunk's start). Single messages and batches are gathered alike and indexed once, when the
    chunk is written."""

    def __init__(self) -> None:
        self.records: list[bytes] = []
        self.size = 0
        self.batches: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self.singles: list[tuple[int, int, int]] = []

    @property
    def empty(self) -> bool:
        return not self.records

    def add_one(self, record: bytes, channel: int, stamp: int) -> None:
        self.singles.append((channel, stamp, self.size))
        self.records.append(record)
        self.size += len(record)

    def add(self, records: bytes, channels: np.ndarray, stamps: np.ndarray, offsets: np.ndarray) -> None:
        self.batches.append(
            (channels.astype(np.uint64), stamps.astype(np.uint64), offsets.astype(np.uint64) + self.size)
        )
        self.records.append(records)
        self.size += len(records)

    def messages(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Channel ids, log times and offsets of every message, by channel and then offset."""
        parts = list(self.batches)
        if self.singles:
            channel, stamp, offset = (np.array(column, np.uint64) for column in zip(*self.singles, strict=True))
            parts.append((channel, stamp, offset))
        channels, stamps, offsets = (np.concatenate([p[i] for p in parts]) for i in range(3))
        order = np.lexsort((offsets, channels))
        return channels[order], stamps[order], offsets[order]


class RecordingWriter:
    """Context manager writing one recording of a given kind.

    ``write(topic, stamp_ns, data)`` takes CDR bytes (see ``touch2robot.recording.cdr``), ``write_batch``
    many messages at once; the message's log time is its header stamp. On an exception the partial file is
    removed and nothing appears at ``path``. The channels are the ``rig``'s topics of ``kind``, and with
    ``viewer`` also ``/tf`` and ``/robot_description`` (for Foxglove's 3D panel).
    """

    def __init__(
        self,
        path: Path,
        kind: str,
        metadata: dict[str, str],
        chunk_size: int = 1 << 20,
        rig: Rig = DEFAULT_RIG,
        viewer: bool = False,
    ) -> None:
        if kind not in STREAMS_BY_KIND:
            raise ValueError(f"unknown recording kind {kind!r}")
        self.path = Path(path)
        self.kind = kind
        self._topics = rig.topics(kind) + (VIEWER_TOPICS if viewer else ())
        self.metadata = {"kind": kind, "schema_version": SCHEMA_VERSION, **metadata, "rig": rig.name}
        self._tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        self._chunk_size = chunk_size
        self._channels: dict[str, int] = {}
        self._schemas: list[Schema] = []
        self._channel_records: list[Channel] = []
        self._chunk = _OpenChunk()
        # one per writer: a compressor is not thread-safe (the replay stage writes on several threads); the
        # default level, 3, as mcap's Writer (zstandard.compress)
        self._compressor = zstandard.ZstdCompressor()
        self._chunk_indexes: list[ChunkIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._message_counts: dict[int, int] = {}
        self._start = self._end = 0
        self._data_crc = 0
        self._offset = 0

    def __enter__(self) -> RecordingWriter:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self._tmp, "wb")
        self._emit(MAGIC)
        builder = RecordBuilder()
        Header(profile="ros2", library="touch2robot").write(builder)
        schema_ids: dict[str, int] = {}
        for topic in self._topics:
            if topic.msg_type not in schema_ids:
                schema_ids[topic.msg_type] = len(self._schemas) + 1
                self._schemas.append(
                    Schema(
                        id=schema_ids[topic.msg_type],
                        name=topic.msg_type,
                        encoding=SCHEMA_ENCODING,
                        data=MSG_DEFINITIONS[topic.msg_type].encode(),
                    )
                )
                self._schemas[-1].write(builder)
            channel = Channel(
                id=len(self._channel_records) + 1,
                topic=topic.name,
                message_encoding=MESSAGE_ENCODING,
                schema_id=schema_ids[topic.msg_type],
                metadata={},
            )
            channel.write(builder)
            self._channel_records.append(channel)
            self._channels[topic.name] = channel.id
        self._emit(builder.end())
        return self

    def write(self, topic: str, stamp_ns: int, data: bytes) -> None:
        channel = self._channels[topic]
        head = _MESSAGE_HEAD.pack(Opcode.MESSAGE, _MESSAGE_FIELDS + len(data), channel, 0, stamp_ns, stamp_ns)
        self._chunk.add_one(head + data, channel, stamp_ns)
        self._maybe_write_chunk()

    def write_batch(self, streams: Sequence[tuple[str, np.ndarray, np.ndarray]], order: np.ndarray) -> None:
        """Many messages at once. ``streams``: per stream its topic, stamps (n,) in ns (log and publish time, as
        in ``write``) and payloads, (n, size) uint8, one message a row (a stream's messages share one size, as
        the twin's template encodings do); ``order``: (messages, 2) pairs of (stream, row), in the order
        written."""
        if not len(order):
            return
        stream, row = np.asarray(order, np.int64).T
        blobs, sizes = [], []
        channels = np.empty(len(order), np.uint64)
        stamps = np.empty(len(order), np.uint64)
        for k, (topic, stamp, payloads) in enumerate(streams):
            n, size = payloads.shape
            if not n:  # nothing of this stream in the batch
                blobs.append(b"")
                sizes.append(0)
                continue
            head = np.zeros(n, _MESSAGE_DTYPE)
            head["opcode"], head["length"], head["channel"] = (
                Opcode.MESSAGE,
                _MESSAGE_FIELDS + size,
                self._channels[topic],
            )
            head["log"] = head["pub"] = stamp
            records = np.empty((n, _MESSAGE_HEAD.size + size), np.uint8)
            records[:, : _MESSAGE_HEAD.size] = head.view(np.uint8).reshape(n, -1)
            records[:, _MESSAGE_HEAD.size :] = payloads
            blobs.append(records.tobytes())
            sizes.append(records.shape[1])
            at = stream == k
            channels[at], stamps[at] = self._channels[topic], np.asarray(stamp, np.int64)[row[at]]
        # slices of each stream's records joined in order: 3x faster than scattering the bytes with NumPy
        data = b"".join([blobs[k][r * sizes[k] : (r + 1) * sizes[k]] for k, r in order.tolist()])
        lengths = np.asarray(sizes, np.uint64)[stream]
        self._chunk.add(data, channels, stamps, np.cumsum(lengths) - lengths)
        self._maybe_write_chunk()

    def flush(self) -> None:
        """Write the messages so far as a chunk now (a writer waiting for more data does this in the wait)."""
        self._write_chunk()

    def _maybe_write_chunk(self) -> None:
        if self._chunk.size > self._chunk_size:
            self._write_chunk()

    def _emit(self, data: bytes) -> None:
        """Append to the data section (its CRC covers everything from the magic to the DataEnd record)."""
        self._file.write(data)
        self._data_crc = zlib.crc32(data, self._data_crc)
        self._offset += len(data)

    def _write_chunk(self) -> None:
        chunk = self._chunk
        if chunk.empty:
            return
        channels, stamps, offsets = chunk.messages()
        start, end = int(stamps.min()), int(stamps.max())
        first = not self._message_counts
        self._start, self._end = (start, end) if first else (min(self._start, start), max(self._end, end))
        data = b"".join(chunk.records)
        compressed = self._compressor.compress(data)
        builder = RecordBuilder()
        Chunk(
            compression="zstd",
            data=compressed,
            message_start_time=start,
            message_end_time=end,
            uncompressed_crc=zlib.crc32(data),
            uncompressed_size=len(data),
        ).write(builder)
        chunk_record = builder.end()
        chunk_start = self._offset
        index_start = chunk_start + len(chunk_record)
        index_offsets: dict[int, int] = {}
        indexes = []
        bounds = np.flatnonzero(np.diff(channels)) + 1
        for at in np.split(np.arange(len(channels)), bounds):
            channel = int(channels[at[0]])
            self._message_counts[channel] = self._message_counts.get(channel, 0) + len(at)
            entries = np.stack([stamps[at], offsets[at]], 1).astype("<u8").tobytes()
            index_offsets[channel] = index_start + sum(len(i) for i in indexes)
            head = struct.pack("<BQHI", Opcode.MESSAGE_INDEX, 6 + len(entries), channel, len(entries))
            indexes.append(head + entries)
        self._emit(chunk_record)
        self._emit(b"".join(indexes))
        self._chunk_indexes.append(
            ChunkIndex(
                message_start_time=start,
                message_end_time=end,
                chunk_start_offset=chunk_start,
                chunk_length=len(chunk_record),
                message_index_offsets=index_offsets,
                message_index_length=sum(len(i) for i in indexes),
                compression="zstd",
                compressed_size=len(compressed),
                uncompressed_size=len(data),
            )
        )
        self._chunk = _OpenChunk()

    def _finish(self) -> None:
        self._write_chunk()
        builder = RecordBuilder()
        Metadata(name=METADATA_NAME, metadata={k: str(v) for k, v in self.metadata.items()}).write(builder)
        record = builder.end()
        self._metadata_indexes.append(MetadataIndex(offset=self._offset, length=len(record), name=METADATA_NAME))
        self._emit(record)
        DataEnd(self._data_crc).write(builder)
        self._emit(builder.end())

        summary_start = self._offset
        statistics = Statistics(
            message_count=sum(self._message_counts.values()),
            schema_count=len(self._schemas),
            channel_count=len(self._channel_records),
            attachment_count=0,
            metadata_count=len(self._metadata_indexes),
            chunk_count=len(self._chunk_indexes),
            message_start_time=self._start,
            message_end_time=self._end,
            channel_message_counts=dict(sorted(self._message_counts.items())),
        )
        groups = (
            (Opcode.SCHEMA, self._schemas),
            (Opcode.CHANNEL, self._channel_records),
            (Opcode.STATISTICS, [statistics]),
            (Opcode.CHUNK_INDEX, self._chunk_indexes),
            (Opcode.ATTACHMENT_INDEX, []),
            (Opcode.METADATA_INDEX, self._metadata_indexes),
        )
        summary = RecordBuilder()
        offsets: list[SummaryOffset] = []
        for opcode, records in groups:
            group_start = summary.count
            for r in records:
                r.write(summary)
            offsets.append(
                SummaryOffset(
                    group_opcode=opcode,
                    group_start=summary_start + group_start,
                    group_length=summary.count - group_start,
                )
            )
        summary_offset_start = summary_start + summary.count
        for o in offsets:
            o.write(summary)
        summary_data = summary.end()
        footer_head = struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, summary_offset_start)
        summary_crc = zlib.crc32(footer_head, zlib.crc32(summary_data))
        self._file.write(summary_data)
        Footer(summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=summary_crc).write(
            builder
        )
        self._file.write(builder.end() + MAGIC)

    def __exit__(self, exc_type: type | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        try:
            if exc_type is None:
                self._finish()
            self._file.close()
            if exc_type is None:
                os.replace(self._tmp, self.path)
        finally:
            self._tmp.unlink(missing_ok=True)
