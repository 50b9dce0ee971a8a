"""Reading one MCAP recording into decoded, validated columns.

The file is read in one linear pass with chunk and data-section CRCs checked, so a
truncated or corrupt file is detected before anything is written. Any problem raises
``RecordingError`` with a reason that names the topic/field; ingestion quarantines the
file with that reason and writes none of its rows (no partial recovery: a file is taken
whole or not at all)."""

from __future__ import annotations

import hashlib
import io
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mcap.exceptions import McapError
from mcap.records import Channel, DataEnd, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader

from schemas.messages import MESSAGE_ENCODING, METADATA_KEYS, METADATA_NAME, TOPICS_BY_KIND, Topic
from touch2robot.recording.cdr import Batch, CdrError, decode_batch


class RecordingError(ValueError):
    """A recording that cannot be ingested; ``reason`` says why, naming the topic/field."""

    def __init__(self, path: Path | str, reason: str) -> None:
        super().__init__(f"{path}: {reason}")
        self.path = str(path)
        self.reason = reason


@dataclass
class DecodedRecording:
    """A validated recording: metadata and one decoded batch per contract topic."""

    path: Path
    recording_id: str
    size_bytes: int
    metadata: dict[str, str]
    topics: dict[str, Batch]
    start_ns: int
    end_ns: int
    message_counts: dict[str, int] = field(default_factory=dict)

    @property
    def kind(self) -> str:
        return self.metadata["kind"]


def content_id(data: bytes) -> str:
    """Recording id: the first 16 hex digits of the file's sha256 (content, not path)."""
    return hashlib.sha256(data).hexdigest()[:16]


def read_recording(path: Path) -> DecodedRecording:
    """Read, check and decode one MCAP recording, or raise RecordingError."""
    path = Path(path)
    data = path.read_bytes()
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    messages: dict[int, list[bytes]] = {}
    metadata: dict[str, str] | None = None
    seen_footer = seen_data_end = False
    try:
        for record in StreamReader(io.BytesIO(data), validate_crcs=True, skip_magic=False).records:
            if isinstance(record, Message):
                messages.setdefault(record.channel_id, []).append(record.data)
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Metadata) and record.name == METADATA_NAME:
                metadata = dict(record.metadata)
            elif isinstance(record, DataEnd):
                seen_data_end = True
            elif isinstance(record, Footer):
                seen_footer = True
    except (McapError, ValueError, EOFError, OSError, KeyError, IndexError) as e:
        # mcap raises EndOfFile/CRCValidationError/InvalidMagic/RecordLengthLimitExceeded
        # and zstd raises plain errors on damaged chunk bytes
        raise RecordingError(path, f"corrupt or truncated MCAP ({type(e).__name__}: {e})") from None
    except Exception as e:  # decompressor errors have no common base class
        raise RecordingError(path, f"corrupt or truncated MCAP ({type(e).__name__}: {e})") from None
    if not (seen_footer and seen_data_end):
        raise RecordingError(path, "truncated MCAP: no data-end/footer record (the recorder did not finish the file)")
    if metadata is None:
        raise RecordingError(path, f"no '{METADATA_NAME}' metadata record (kind, task, subject ...)")
    kind = metadata.get("kind", "")
    if kind not in TOPICS_BY_KIND:
        raise RecordingError(path, f"metadata 'kind' is {kind!r}; expected one of {sorted(TOPICS_BY_KIND)}")
    missing_keys = [k for k in METADATA_KEYS[kind] if not metadata.get(k)]
    if missing_keys:
        raise RecordingError(path, f"metadata lacks {', '.join(missing_keys)} for a {kind} recording")

    by_topic = {c.topic: c for c in channels.values()}
    missing = [t.name for t in TOPICS_BY_KIND[kind] if t.name not in by_topic or not messages.get(by_topic[t.name].id)]
    if missing:
        raise RecordingError(path, f"missing topic(s) {', '.join(missing)} (required for a {kind} recording)")

    decoded: dict[str, Batch] = {}
    for topic in TOPICS_BY_KIND[kind]:
        channel = by_topic[topic.name]
        decoded[topic.name] = _decode_topic(path, topic, channel, schemas.get(channel.schema_id), messages[channel.id])
    start = min(int(b.stamp_ns[0]) for b in decoded.values())
    end = max(int(b.stamp_ns[-1]) for b in decoded.values())
    return DecodedRecording(
        path=path,
        recording_id=content_id(data),
        size_bytes=len(data),
        metadata=metadata,
        topics=decoded,
        start_ns=start,
        end_ns=end,
        message_counts={c.topic: len(messages.get(c.id, [])) for c in channels.values()},
    )


def _decode_topic(path: Path, topic: Topic, channel: Channel, schema: Schema | None, payloads: list[bytes]) -> Batch:
    where = f"topic {topic.name}"
    if schema is None or schema.name != topic.msg_type:
        raise RecordingError(
            path, f"{where} has schema {schema.name if schema else None!r}, expected {topic.msg_type!r}"
        )
    if channel.message_encoding != MESSAGE_ENCODING:
        raise RecordingError(
            path, f"{where} has message encoding {channel.message_encoding!r}, expected {MESSAGE_ENCODING!r}"
        )
    try:
        batch = decode_batch(topic.msg_type, payloads)
    except CdrError as e:
        raise RecordingError(path, f"{where}: {e}") from None
    steps = np.diff(batch.stamp_ns)
    if (steps <= 0).any():
        i = int(np.flatnonzero(steps <= 0)[0]) + 1
        raise RecordingError(
            path,
            f"{where}: timestamps not strictly increasing at message {i} ({batch.stamp_ns[i]} ns after "
            f"{batch.stamp_ns[i - 1]} ns)",
        )
    if topic.joint_names is not None:
        batch = _order_joints(path, topic.name, topic.joint_names, batch)
    for name, values in batch.fields.items():
        if name in ("velocity", "effort") and values.shape[1] == 0:
            continue  # optional in sensor_msgs/JointState
        expected = _expected_width(topic, name)
        if expected is not None and values.shape[1] != expected:
            raise RecordingError(path, f"{where}: field {name!r} has {values.shape[1]} values, expected {expected}")
        bad = ~np.isfinite(values)
        if bad.any():
            i, j = (int(v[0]) for v in np.nonzero(bad))
            raise RecordingError(
                path, f"{where}: non-finite value ({values[i, j]}) in field {name!r} at message {i}, index {j}"
            )
    return batch


def _expected_width(topic: Topic, name: str) -> int | None:
    if name == "poses" and topic.array_len is not None:
        return 7 * topic.array_len
    if name in ("values", "position", "velocity", "effort"):
        return topic.array_len
    if name == "pose":
        return 7
    return None


def _order_joints(path: Path, topic_name: str, joint_names: tuple[str, ...], batch: Batch) -> Batch:
    """Put JointState columns in the contract's joint order (rigs may order them differently)."""
    names = tuple(batch.names or ())
    if names == joint_names:
        return batch
    absent = [n for n in joint_names if n not in names]
    if absent:
        raise RecordingError(
            path,
            f"topic {topic_name}: joint names lack {', '.join(absent)} ({len(names)} joints, expected "
            f"{len(joint_names)})",
        )
    order = [names.index(n) for n in joint_names]
    fields = {k: (v[:, order] if v.shape[1] == len(names) else v) for k, v in batch.fields.items()}
    return Batch(batch.stamp_ns, fields, batch.frame_ids, joint_names)


def counts_json(counts: dict[str, int]) -> str:
    return json.dumps(dict(sorted(counts.items())))
