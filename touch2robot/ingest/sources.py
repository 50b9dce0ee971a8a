"""Where a recording comes from: its container (one MCAP file, or a rosbag2 folder of MCAP or sqlite3
storage, read through rosbags) and its session metadata.

A recorder a lab already runs (``ros2 bag record``, the rosbags writer, Foxglove) cannot write the project's
``touch2robot`` metadata record, so the session's fields (kind, task, subject, the links between a replay,
its glove session and its calibration, the rig) come from the first of these that gives each field:

1. the file's ``touch2robot`` MCAP metadata record;
2. the rosbag2 folder's ``metadata.yaml`` (its ``custom_data``);
3. a sidecar ``<recording>.session.yaml`` beside the file or folder;
4. the command line (``touch2robot ingest --session KEY=VALUE``).

MCAP lets a file store messages out of log-time order; each topic's messages are sorted by log time
(stable) before they are decoded."""

from __future__ import annotations

import hashlib
import io
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from mcap.records import Channel, DataEnd, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader

from schemas.messages import METADATA_NAME, SCHEMA_VERSION, SESSION_KEYS
from touch2robot.ingest.scan import BAG_METADATA, is_bag

SIDECAR_SUFFIX = ".session.yaml"
MCAP_SUFFIX = ".mcap"


class SourceError(ValueError):
    """A recording's container or session metadata that cannot be read; the message names the file and field."""


@dataclass
class TopicMessages:
    """One topic's messages as stored: the schema (message type) name, the encoding, and the payloads in
    log-time order."""

    schema_name: str | None
    encoding: str
    log_times: list[int] = field(default_factory=list)
    payloads: list[bytes] = field(default_factory=list)

    def in_log_order(self) -> TopicMessages:
        times = np.asarray(self.log_times, dtype=np.int64)
        if len(times) < 2 or bool(np.all(np.diff(times) >= 0)):
            return self
        order = np.argsort(times, kind="stable")
        return TopicMessages(
            self.schema_name, self.encoding, [self.log_times[i] for i in order], [self.payloads[i] for i in order]
        )


@dataclass
class Container:
    """What a recording's container holds: messages by topic, the project's metadata record (None when the
    recorder wrote none) and a rosbag2 folder's ``custom_data``."""

    topics: dict[str, TopicMessages]
    record: dict[str, str] | None
    custom_data: dict[str, str]
    size_bytes: int
    digest: str  # recording_digest of what was read


def sidecar_path(recording: Path) -> Path:
    """``<recording>.session.yaml`` beside a file (``x.mcap`` -> ``x.session.yaml``) or a rosbag2 folder."""
    name = recording.name
    stem = name[: -len(MCAP_SUFFIX)] if name.endswith(MCAP_SUFFIX) else name
    return recording.with_name(stem + SIDECAR_SUFFIX)


def _content_files(path: Path) -> list[Path]:
    """The files whose bytes make a recording: the file itself, or every file of a rosbag2 folder."""
    if path.is_dir():
        return sorted(p for p in path.iterdir() if p.is_file())
    return [path]


def content_size(path: Path) -> int:
    """Bytes of a recording's file, or of every file of its rosbag2 folder."""
    return sum(p.stat().st_size for p in _content_files(path))


def recording_digest(path: Path) -> str:
    """sha256 of what a recording is made of: its bytes (every file of a rosbag2 folder, by name) and its
    sidecar's. A plain MCAP file without a sidecar hashes as its bytes alone, as it always has.
    Raises OSError when a file cannot be read."""
    path = Path(path)
    h = hashlib.sha256()
    for p in _content_files(path):
        if path.is_dir():
            h.update(f"\0{p.name}\0".encode())
        with open(p, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    return _with_sidecar(h, path)


def _with_sidecar(h: Any, path: Path) -> str:
    """The digest ``h`` of a recording's bytes, its sidecar's bytes added."""
    sidecar = sidecar_path(path)
    if sidecar.is_file():
        h.update(b"\0" + SIDECAR_SUFFIX.encode() + b"\0" + sidecar.read_bytes())
    return h.hexdigest()


def read_container(path: Path) -> Container:
    """The messages and metadata a recording holds. Raises SourceError naming what is wrong, OSError when
    the file cannot be read."""
    return _read_bag(path) if is_bag(path) else _read_mcap(path)


def peek(path: Path) -> tuple[set[str], dict[str, str] | None, dict[str, str]]:
    """A recording's topics, project record and rosbag2 custom_data, from its summary (an MCAP file) or its
    metadata.yaml (a rosbag2 folder), without reading its messages. Raises SourceError or OSError."""
    if is_bag(path):
        from rosbags.rosbag2 import Reader

        try:
            with Reader(path) as reader:
                topics = {c.topic for c in reader.connections}
        except Exception as e:  # rosbags' ReaderError and its storage plugins' own
            raise SourceError(f"rosbag2 folder cannot be read ({type(e).__name__}: {e})") from None
        return topics, None, _bag_custom_data(path / BAG_METADATA)
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            if summary is None:  # a file without a summary section: read it whole
                container = _read_mcap(path)
                return set(container.topics), container.record, {}
            record = next((dict(m.metadata) for m in reader.iter_metadata() if m.name == METADATA_NAME), None)
            return {c.topic for c in summary.channels.values()}, record, {}
    except OSError:
        raise
    except Exception as e:  # mcap's own errors on a damaged file
        raise SourceError(f"corrupt or truncated MCAP ({type(e).__name__}: {e})") from None


def _read_mcap(path: Path) -> Container:
    data = path.read_bytes()
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    by_channel: dict[int, tuple[list[int], list[bytes]]] = {}
    record: dict[str, str] | None = None
    seen_footer = seen_data_end = False
    try:
        for item in StreamReader(io.BytesIO(data), validate_crcs=True, skip_magic=False).records:
            if isinstance(item, Message):
                times, payloads = by_channel.setdefault(item.channel_id, ([], []))
                times.append(item.log_time)
                payloads.append(item.data)
            elif isinstance(item, Channel):
                channels[item.id] = item
            elif isinstance(item, Schema):
                schemas[item.id] = item
            elif isinstance(item, Metadata) and item.name == METADATA_NAME:
                record = dict(item.metadata)
            elif isinstance(item, DataEnd):
                seen_data_end = True
            elif isinstance(item, Footer):
                seen_footer = True
    except Exception as e:  # mcap's EndOfFile/CRCValidationError/InvalidMagic/...; zstd's and lz4's own errors
        raise SourceError(f"corrupt or truncated MCAP ({type(e).__name__}: {e})") from None
    if not (seen_footer and seen_data_end):
        raise SourceError("truncated MCAP: no data-end/footer record (the recorder did not finish the file)")
    topics: dict[str, TopicMessages] = {}
    for channel in channels.values():
        schema = schemas.get(channel.schema_id)
        times, payloads = by_channel.get(channel.id, ([], []))
        topics[channel.topic] = TopicMessages(
            schema.name if schema else None, channel.message_encoding, times, payloads
        )
    digest = _with_sidecar(hashlib.sha256(data), path)  # the bytes just read: the file is read once
    return Container({t: m.in_log_order() for t, m in topics.items()}, record, {}, len(data), digest)


def _read_bag(path: Path) -> Container:
    from rosbags.rosbag2 import Reader

    custom = _bag_custom_data(path / BAG_METADATA)
    topics: dict[str, TopicMessages] = {}
    try:
        with Reader(path) as reader:
            for connection in reader.connections:
                ext = connection.ext
                encoding = getattr(ext, "serialization_format", "cdr")
                topics.setdefault(connection.topic, TopicMessages(connection.msgtype, encoding))
            for connection, timestamp, raw in reader.messages():
                messages = topics[connection.topic]
                messages.log_times.append(int(timestamp))
                messages.payloads.append(bytes(raw))
    except OSError:
        raise
    except Exception as e:  # rosbags' ReaderError, and its storage plugins' own (sqlite3, mcap, zstd)
        raise SourceError(f"rosbag2 folder cannot be read ({type(e).__name__}: {e})") from None
    topics = {t: m.in_log_order() for t, m in topics.items()}
    return Container(topics, None, custom, content_size(path), recording_digest(path))


def _bag_custom_data(metadata_file: Path) -> dict[str, str]:
    """The session fields a rosbag2 ``metadata.yaml`` carries in ``custom_data`` (other keys are the
    recorder's and are left alone)."""
    try:
        info = yaml.safe_load(metadata_file.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as e:
        raise SourceError(f"{BAG_METADATA} is not valid YAML ({type(e).__name__})") from None
    bag = info.get("rosbag2_bagfile_information") if isinstance(info, dict) else None
    if not isinstance(bag, dict):
        raise SourceError(f"{BAG_METADATA} has no 'rosbag2_bagfile_information' mapping")
    custom = bag.get("custom_data") or {}
    if not isinstance(custom, dict):
        raise SourceError(f"{BAG_METADATA}: custom_data is not a mapping")
    return {str(k): str(v) for k, v in custom.items() if str(k) in SESSION_KEYS and v is not None}


def read_sidecar(path: Path) -> dict[str, str]:
    """A session sidecar's fields ({} when there is none). Raises SourceError naming the file and field."""
    if not path.is_file():
        return {}
    try:
        loaded = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as e:
        raise SourceError(f"sidecar {path.name} is not valid YAML ({type(e).__name__})") from None
    if loaded is None:
        return {}
    if not isinstance(loaded, dict):
        raise SourceError(f"sidecar {path.name} must be a mapping of session fields, not a {type(loaded).__name__}")
    return checked_fields(loaded, f"sidecar {path.name}")


def checked_fields(fields: Mapping[Any, object], where: str) -> dict[str, str]:
    """Session fields as strings; an unknown key, or a value that is not a plain scalar, is refused naming
    ``where`` and the key."""
    out: dict[str, str] = {}
    for key, value in fields.items():
        if key not in SESSION_KEYS:
            raise SourceError(f"{where}: unknown session field {key!r}; the fields are {', '.join(SESSION_KEYS)}")
        if isinstance(value, bool) or not isinstance(value, str | int):
            raise SourceError(f"{where}: field {key!r} must be a string or a whole number, not {value!r}")
        out[str(key)] = str(value)
    return out


def session_metadata(
    record: Mapping[str, str] | None,
    custom_data: Mapping[str, str],
    sidecar: Mapping[str, str],
    options: Mapping[str, str],
) -> dict[str, str]:
    """Each field from the first source that gives it (the file's record, rosbag2 custom_data, sidecar,
    command line). A recording without the project's record is of the contract's schema version unless a
    source says otherwise."""
    merged: dict[str, str] = {}
    for source in (options, sidecar, custom_data, record or {}):
        merged.update({k: v for k, v in source.items() if v != ""})
    if record is None:
        merged.setdefault("schema_version", SCHEMA_VERSION)
    return merged


def where_to_give(path: Path) -> str:
    """The places a missing session field can be given, for an error message."""
    own = f"custom_data in its {BAG_METADATA}" if is_bag(path) else f"the file's {METADATA_NAME!r} metadata record"
    return f"{own}, a sidecar {sidecar_path(path).name} or `touch2robot ingest --session FIELD=VALUE`"
