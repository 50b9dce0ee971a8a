"""Reading one recording (an MCAP file or a rosbag2 folder: ``touch2robot.ingest.sources``) into decoded,
validated columns.

An MCAP file is read in one linear pass with chunk and data-section CRCs checked, so a
truncated or corrupt file is detected before anything is written. Any problem raises
``RecordingError`` with a reason that names the topic/field; ingestion quarantines the
file with that reason and writes none of its rows (no partial recovery: a file is taken
whole or not at all)."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from schemas import plausibility as plaus
from schemas.messages import (
    MESSAGE_ENCODING,
    METADATA_KEYS,
    OPTIONAL_METADATA_KEYS,
    SCHEMA_VERSION,
    STREAMS_BY_KIND,
    Topic,
)
from schemas.rig import DEFAULT_RIG, RIG_SUFFIX, Rig
from schemas.vocabulary import Method
from touch2robot.ingest.sources import (
    SourceError,
    TopicMessages,
    read_container,
    read_sidecar,
    session_metadata,
    sidecar_path,
    where_to_give,
)
from touch2robot.recording.cdr import Batch, CdrError, decode_batch
from touch2robot.scenes import TASKS


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
    rig: Rig = DEFAULT_RIG

    @property
    def kind(self) -> str:
        return self.metadata["kind"]


def content_id(data: bytes) -> str:
    """Recording id: the first 16 hex digits of the file's sha256 (content, not path)."""
    return hashlib.sha256(data).hexdigest()[:16]


def read_recording(
    path: Path, session: Mapping[str, str] | None = None, rigs: Mapping[str, Rig] | None = None
) -> DecodedRecording:
    """Read, check and decode one recording (an MCAP file or a rosbag2 folder), or raise RecordingError.
    ``session``: fields given on the command line, used where no other source gives them
    (``touch2robot.ingest.sources``); ``rigs``: the rigs by name (default: the built-in one), the
    recording's session field ``rig`` picks its own."""
    path = Path(path)
    try:
        container = read_container(path)
        sidecar = read_sidecar(sidecar_path(path))
    except OSError as e:
        raise RecordingError(path, f"cannot read the file: {e.strerror}") from None
    except SourceError as e:
        raise RecordingError(path, str(e)) from None
    metadata = session_metadata(container.record, container.custom_data, sidecar, session or {})
    kind = metadata.get("kind", "")
    if not kind:
        raise RecordingError(
            path,
            f"no session metadata 'kind' ({', '.join(STREAMS_BY_KIND)}): give it in {where_to_give(path)}",
        )
    if kind not in STREAMS_BY_KIND:
        raise RecordingError(path, f"metadata 'kind' is {kind!r}; expected one of {sorted(STREAMS_BY_KIND)}")
    missing_keys = [k for k in METADATA_KEYS[kind] if not metadata.get(k)]
    if missing_keys:
        raise RecordingError(
            path,
            f"metadata lacks {', '.join(missing_keys)} for a {kind} recording: give it in {where_to_give(path)}",
        )
    _check_metadata(path, kind, metadata)
    rigs = rigs or {DEFAULT_RIG.name: DEFAULT_RIG}
    rig = rigs.get(metadata.get("rig") or DEFAULT_RIG.name)
    if rig is None:
        raise RecordingError(
            path,
            f"metadata 'rig' is {metadata['rig']!r}, a rig ingest does not know (it knows {', '.join(sorted(rigs))}): "
            f"put {metadata['rig']}{RIG_SUFFIX} in the recordings folder or give `touch2robot ingest --rig FILE`",
        )

    topics = container.topics
    wanted = rig.topics(kind)
    missing = [t.name for t in wanted if t.name not in topics or not topics[t.name].payloads]
    if missing:
        raise RecordingError(
            path, f"missing topic(s) {', '.join(missing)} (required for a {kind} recording on rig {rig.name!r})"
        )

    decoded = {topic.name: _decode_topic(path, topic, topics[topic.name]) for topic in wanted}
    start = min(int(b.stamp_ns[0]) for b in decoded.values())
    end = max(int(b.stamp_ns[-1]) for b in decoded.values())
    _check_span(path, decoded, start, end)
    return DecodedRecording(
        path=path,
        recording_id=container.digest[:16],
        size_bytes=container.size_bytes,
        metadata=metadata,
        topics=decoded,
        start_ns=start,
        end_ns=end,
        message_counts={name: len(messages.payloads) for name, messages in topics.items()},
        rig=rig,
    )


def _decode_topic(path: Path, topic: Topic, messages: TopicMessages) -> Batch:
    where = f"topic {topic.name}"
    if messages.schema_name != topic.msg_type:
        raise RecordingError(path, f"{where} has schema {messages.schema_name!r}, expected {topic.msg_type!r}")
    if messages.encoding != MESSAGE_ENCODING:
        raise RecordingError(path, f"{where} has message encoding {messages.encoding!r}, expected {MESSAGE_ENCODING!r}")
    try:
        batch = decode_batch(topic.msg_type, messages.payloads)
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
        _check_plausible(path, topic, name, values)
    return batch


def _check_metadata(path: Path, kind: str, metadata: dict[str, str]) -> None:
    """Metadata values name tasks and methods and end up in tables and file names: each must be one the
    contract knows, or a short plain name."""

    def refuse(key: str, expected: str) -> None:
        shown = metadata[key] if len(metadata[key]) <= 80 else metadata[key][:80] + "..."
        raise RecordingError(path, f"metadata {key!r} is {shown!r}; expected {expected}")

    if metadata.get("schema_version") != SCHEMA_VERSION:
        refuse("schema_version", repr(SCHEMA_VERSION))
    if "task" in METADATA_KEYS[kind] and metadata["task"] not in TASKS:
        refuse("task", f"one of {', '.join(TASKS)}")
    if "subject" in METADATA_KEYS[kind] and not plaus.NAME_PATTERN.fullmatch(metadata["subject"]):
        refuse("subject", "a plain name (letters, digits, '_', '.', '-'; at most 64)")
    if "method" in METADATA_KEYS[kind] and metadata["method"] not in set(Method):
        refuse("method", f"one of {', '.join(Method)}")
    for key in ("reference_recording", "calibration_recording"):
        if key in METADATA_KEYS[kind] and not plaus.FILE_NAME_PATTERN.fullmatch(metadata[key]):
            refuse(key, "the plain file name of a recording in the same folder")
    trajectory = metadata.get("trajectory")
    if "trajectory" in OPTIONAL_METADATA_KEYS[kind] and trajectory and not plaus.NAME_PATTERN.fullmatch(trajectory):
        refuse("trajectory", "a rollout id (letters, digits, '_', '.', '-'; at most 64)")
    seed = metadata.get("seed")
    if "seed" in OPTIONAL_METADATA_KEYS[kind] and seed is not None and not plaus.SEED_PATTERN.fullmatch(seed):
        refuse("seed", "a sweep seed: a whole number >= 0 of at most 9 digits")


def _check_plausible(path: Path, topic: Topic, name: str, values: np.ndarray) -> None:
    """Values a sensor cannot physically report (schemas/plausibility.py says why each bound)."""
    where = f"topic {topic.name}, field {name!r}"
    if name in plaus.POSE_FIELDS:
        poses = values.reshape(len(values), -1, 7)
        _check_bounds(path, where, poses[..., :3].reshape(len(values), -1), plaus.POSITION)
        if topic.table in plaus.POSITION_ONLY_STREAMS:
            return
        with np.errstate(over="ignore"):  # a huge component is reported below, not warned about
            norm = np.linalg.norm(poses[..., 3:], axis=-1)
        bad = np.abs(norm - 1.0) > plaus.QUATERNION_TOLERANCE
        if bad.any():
            i, j = (int(v[0]) for v in np.nonzero(bad))
            raise RecordingError(
                path,
                f"{where}: orientation {poses[i, j, 3:].tolist()} at message {i} is not a unit quaternion "
                f"(norm {norm[i, j]:.6g}, tolerance {plaus.QUATERNION_TOLERANCE})",
            )
        return
    bounds = plaus.FIELD_BOUNDS.get((topic.msg_type, name))
    if bounds is not None:
        _check_bounds(path, where, values, bounds)


def _check_bounds(path: Path, where: str, values: np.ndarray, bounds: plaus.Bounds) -> None:
    bad = (values < bounds.low) | (values > bounds.high)
    if bad.any():
        i, j = (int(v[0]) for v in np.nonzero(bad))
        raise RecordingError(
            path,
            f"{where}: implausible value {values[i, j]:.6g} at message {i}, index {j} "
            f"(expected {bounds.low:g}..{bounds.high:g} {bounds.what})",
        )


def _check_span(path: Path, decoded: dict[str, Batch], start: int, end: int) -> None:
    """Every stream's stamps lie inside one plausible recording span (a clock jump shows as a stream far
    from the others, or as a span of years)."""
    for topic, batch in decoded.items():
        if batch.stamp_ns[0] < 0:
            raise RecordingError(
                path, f"topic {topic}: negative timestamp {batch.stamp_ns[0] / 1e9:.9g} s at message 0"
            )
        late = (int(batch.stamp_ns[0]) - start) / 1e9
        if late > plaus.MAX_STREAM_START_SPREAD_S:
            raise RecordingError(
                path,
                f"topic {topic}: first message at {late:.6g} s after the recording's first "
                f"(at most {plaus.MAX_STREAM_START_SPREAD_S:g} s: the recorder starts every stream together)",
            )
    if (end - start) / 1e9 > plaus.MAX_RECORDING_S:
        raise RecordingError(
            path,
            f"recording spans {(end - start) / 1e9:.6g} s (at most {plaus.MAX_RECORDING_S:g} s; "
            "a stream's clock jumped)",
        )


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
