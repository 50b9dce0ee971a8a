"""Writing recordings: an MCAP file with the contract's schemas, channels and metadata,
written to a temporary name and renamed into place only when complete."""

from __future__ import annotations

import os
from pathlib import Path
from types import TracebackType

from mcap.writer import CompressionType, Writer

from schemas.messages import (
    MESSAGE_ENCODING,
    METADATA_NAME,
    MSG_DEFINITIONS,
    SCHEMA_ENCODING,
    SCHEMA_VERSION,
    TOPICS_BY_KIND,
)


class RecordingWriter:
    """Context manager writing one recording of a given kind.

    ``write(topic, stamp_ns, data)`` takes CDR bytes (see ``touch2robot.recording.cdr``);
    the message's log time is its header stamp. On an exception the partial file is
    removed and nothing appears at ``path``.
    """

    def __init__(self, path: Path, kind: str, metadata: dict[str, str], chunk_size: int = 1 << 20) -> None:
        if kind not in TOPICS_BY_KIND:
            raise ValueError(f"unknown recording kind {kind!r}")
        self.path = Path(path)
        self.kind = kind
        self.metadata = {"kind": kind, "schema_version": SCHEMA_VERSION, **metadata}
        self._tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        self._chunk_size = chunk_size
        self._channels: dict[str, int] = {}

    def __enter__(self) -> RecordingWriter:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self._tmp, "wb")
        # the data-section CRC covers the metadata record too: a flipped bit in it is caught at ingest
        self._writer = Writer(
            self._file, chunk_size=self._chunk_size, compression=CompressionType.ZSTD, enable_data_crcs=True
        )
        self._writer.start(profile="ros2", library="touch2robot")
        schema_ids: dict[str, int] = {}
        for topic in TOPICS_BY_KIND[self.kind]:
            if topic.msg_type not in schema_ids:
                schema_ids[topic.msg_type] = self._writer.register_schema(
                    name=topic.msg_type, encoding=SCHEMA_ENCODING, data=MSG_DEFINITIONS[topic.msg_type].encode()
                )
            self._channels[topic.name] = self._writer.register_channel(
                topic=topic.name, message_encoding=MESSAGE_ENCODING, schema_id=schema_ids[topic.msg_type]
            )
        return self

    def write(self, topic: str, stamp_ns: int, data: bytes) -> None:
        self._writer.add_message(self._channels[topic], log_time=stamp_ns, data=data, publish_time=stamp_ns)

    def __exit__(self, exc_type: type | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        try:
            if exc_type is None:
                self._writer.add_metadata(METADATA_NAME, {k: str(v) for k, v in self.metadata.items()})
                self._writer.finish()
            self._file.close()
            if exc_type is None:
                os.replace(self._tmp, self.path)
        finally:
            self._tmp.unlink(missing_ok=True)
