"""Following a glove session while it is being written: the complete records of a growing MCAP file, read
from where the last poll stopped, and the human's contacts and the retargeted robot hand of its newest frame.

A recorder appends whole chunks (or single records); a poll that meets a record still being written stops
before it and resumes there next time, so a file cut mid-chunk is never read past what is complete."""

from __future__ import annotations

import io
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Message, Schema
from mcap.stream_reader import breakup_chunk

from schemas.rig import DEFAULT_RIG, Rig
from touch2robot.contacts import glove_contacts
from touch2robot.contacts.config import ContactsConfig
from touch2robot.recording.cdr import CdrError, decode_batch
from touch2robot.recording.writer import MAGIC

_RECORD_HEAD = struct.Struct("<BQ")  # opcode, content length
# A record longer than this is corruption, not data: the recorder's chunks are ~1 MiB.
MAX_RECORD_BYTES = 1 << 28
# Glove contacts are thresholded on this much of the newest glove data (the noise estimate needs a few
# seconds; the whole session would make each update slower as it grows).
CONTACT_WINDOW_S = 8.0


class FollowError(ValueError):
    """A followed file that cannot be read further; the message names the file and the byte offset."""


@dataclass
class McapTail:
    """The messages appended to an MCAP file since the last :meth:`poll`, decoded per topic."""

    path: Path
    offset: int = 0
    finished: bool = False
    error: FollowError | None = None
    _schemas: dict[int, str] = field(default_factory=dict)
    _channels: dict[int, tuple[str, str]] = field(default_factory=dict)  # id -> (topic, schema name)

    def poll(self) -> dict[str, list[tuple[int, bytes]]]:
        """New messages per topic as (log time ns, CDR payload). Raises ``FollowError`` on a file that is
        not MCAP, shrank, or holds a corrupt record (what was read before stays valid)."""
        if self.error is not None:
            raise self.error
        try:
            with open(self.path, "rb") as f:
                f.seek(0, io.SEEK_END)
                size = f.tell()
                if size < self.offset:
                    raise FollowError(f"{self.path}: the file shrank from {self.offset} to {size} bytes")
                f.seek(self.offset)
                data = f.read()
        except FileNotFoundError:
            if self.offset:
                raise FollowError(f"{self.path}: the file was removed while being followed") from None
            return {}  # the recorder has not started yet
        except OSError as e:
            raise FollowError(f"{self.path}: cannot read ({e.strerror or e})") from None
        start = 0
        if self.offset == 0:
            if len(data) < len(MAGIC):
                return {}
            if data[: len(MAGIC)] != MAGIC:
                raise FollowError(f"{self.path}: not an MCAP file (no MCAP magic at byte 0)")
            start = len(MAGIC)
        end = start
        while end + _RECORD_HEAD.size <= len(data):
            _, length = _RECORD_HEAD.unpack_from(data, end)
            if length > MAX_RECORD_BYTES:
                self.error = FollowError(f"{self.path}: corrupt record at byte {self.offset + end} (length {length})")
                break
            if end + _RECORD_HEAD.size + length > len(data):
                break  # still being written
            end += _RECORD_HEAD.size + length
        out: dict[str, list[tuple[int, bytes]]] = {}
        at = start
        while at < end:
            opcode, length = _RECORD_HEAD.unpack_from(data, at)
            content = data[at + _RECORD_HEAD.size : at + _RECORD_HEAD.size + length]
            try:
                self._take(opcode, content, out)
            except (McapError, ValueError, EOFError, struct.error, zstandard.ZstdError) as e:
                # the records before it are good: return them now, the error on the next poll
                self.error = FollowError(
                    f"{self.path}: corrupt record at byte {self.offset + at}: {e or type(e).__name__}"
                )
                break
            at += _RECORD_HEAD.size + length
        self.offset += at
        return out

    def _take(self, opcode: int, content: bytes, out: dict[str, list[tuple[int, bytes]]]) -> None:
        stream = ReadDataStream(io.BytesIO(content))
        if opcode == Opcode.CHUNK:
            for record in breakup_chunk(Chunk.read(stream), validate_crc=True):
                if isinstance(record, Schema | Channel | Message):
                    self._keep(record, out)
        elif opcode == Opcode.SCHEMA:
            self._keep(Schema.read(stream), out)
        elif opcode == Opcode.CHANNEL:
            self._keep(Channel.read(stream), out)
        elif opcode == Opcode.MESSAGE:
            self._keep(Message.read(stream, len(content)), out)
        elif opcode in (Opcode.DATA_END, Opcode.FOOTER):
            self.finished = True

    def _keep(self, record: Schema | Channel | Message, out: dict[str, list[tuple[int, bytes]]]) -> None:
        if isinstance(record, Schema):
            self._schemas[record.id] = record.name
        elif isinstance(record, Channel):
            self._channels[record.id] = (record.topic, self._schemas.get(record.schema_id, ""))
        elif record.channel_id in self._channels:
            out.setdefault(self._channels[record.channel_id][0], []).append((record.log_time, record.data))

    def schema_of(self, topic: str) -> str | None:
        return next((s for t, s in self._channels.values() if t == topic), None)


@dataclass(frozen=True)
class LiveFrame:
    """The newest state of a followed session: its stamp (log time ns of the newest glove message), the
    human's 9 region contacts, the keypoints (21, 3) and the retargeted robot hand (joints, wrist)."""

    stamp_ns: int
    t: float
    contacts: np.ndarray
    keypoints: np.ndarray | None
    joints: np.ndarray | None
    wrist: np.ndarray | None


class LiveSession:
    """Follows one glove session file: each :meth:`update` reads what was appended and returns the newest
    :class:`LiveFrame` (None until the glove has sent data). ``retarget`` maps world keypoints (21, 3) and the
    wrist pose to robot joints (16,) and the robot wrist (7,), or is None to show the human side only."""

    def __init__(
        self,
        path: Path,
        rig: Rig = DEFAULT_RIG,
        contacts: ContactsConfig | None = None,
        retarget: Callable[[np.ndarray, np.ndarray, float], tuple[np.ndarray, np.ndarray]] | None = None,
    ) -> None:
        self.tail = McapTail(Path(path))
        self.rig = rig
        self.config = contacts or ContactsConfig()
        self.retarget = retarget
        self._taxel_t: list[float] = []
        self._taxels: list[np.ndarray] = []
        self._first_ns: int | None = None
        self._keypoints: np.ndarray | None = None
        self._wrist: np.ndarray | None = None
        self._frame: LiveFrame | None = None

    def _decode(self, topic: str, messages: list[tuple[int, bytes]], field_name: str) -> tuple[np.ndarray, np.ndarray]:
        msg_type = self.tail.schema_of(topic) or ""
        try:
            batch = decode_batch(msg_type, [m[1] for m in messages])
        except (CdrError, KeyError) as e:
            raise FollowError(f"{self.tail.path}: topic {topic}: {e}") from None
        return np.array([m[0] for m in messages], np.int64), batch.fields[field_name]

    def update(self) -> LiveFrame | None:
        new = self.tail.poll()
        streams = self.rig.streams
        taxel_msgs = new.get(streams["taxels"].topic, [])
        if taxel_msgs:
            stamps, values = self._decode(streams["taxels"].topic, taxel_msgs, "values")
            if self._first_ns is None:
                self._first_ns = int(stamps[0])
            self._taxel_t.extend(((stamps - self._first_ns) * 1e-9).tolist())
            self._taxels.extend(values.astype(np.float64))
            cut = np.searchsorted(self._taxel_t, self._taxel_t[-1] - CONTACT_WINDOW_S)
            if cut > 0:
                del self._taxel_t[:cut], self._taxels[:cut]
        if kp := new.get(streams["hand_keypoints"].topic):
            self._keypoints = self._decode(streams["hand_keypoints"].topic, kp[-1:], "poses")[1][0].reshape(-1, 7)[
                :, :3
            ]
        if wr := new.get(streams["wrist_pose"].topic):
            pose = self._decode(streams["wrist_pose"].topic, wr[-1:], "pose")[1][0]
            self._wrist = np.concatenate([pose[:3], pose[6:7], pose[3:6]])  # x y z qx qy qz qw -> px py pz qw qx qy qz
        if not taxel_msgs or self._first_ns is None:
            return self._frame
        if len(self._taxels) < max(2, self.config.smoothing_samples):
            return self._frame
        contact, _, _ = glove_contacts(np.asarray(self._taxel_t), np.stack(self._taxels), self.config, self.rig.glove)
        joints = wrist = None
        if self.retarget is not None and self._keypoints is not None and self._wrist is not None:
            joints, wrist = self.retarget(self._keypoints, self._wrist, self._taxel_t[-1])
        self._frame = LiveFrame(int(taxel_msgs[-1][0]), self._taxel_t[-1], contact[-1], self._keypoints, joints, wrist)
        return self._frame


def live_retargeter() -> Callable[[np.ndarray, np.ndarray, float], tuple[np.ndarray, np.ndarray]]:
    """Frame-by-frame kinematic retargeting (the retarget stage's solver, warm-started from the previous
    frame); the hand's scale is taken from its first frame."""
    from touch2robot.retarget.retargeter import (
        HandMotion,
        Retargeter,
        keypoints_in_wrist,
        motion_scaling,
        robot_wrist_pose,
    )

    retargeter = Retargeter()
    started = False

    def step(keypoints: np.ndarray, wrist: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        nonlocal started
        pos, quat = wrist[None, :3], wrist[None, 3:]
        if not started:
            motion = HandMotion("live", np.array([t]), keypoints[None], pos, quat)
            retargeter.reset(motion_scaling(motion, retargeter.config))
            started = True
        local = keypoints_in_wrist(keypoints[None], pos, quat)[0]
        joints = retargeter.step(local, t)[0]
        robot_pos, robot_quat = robot_wrist_pose(pos, quat)
        return joints, np.concatenate([robot_pos[0], robot_quat[0]])

    return step


def replay_in_real_time(source: Path, target: Path, stop: threading.Event, speed: float = 1.0) -> int:
    """Write the messages of the recording ``source`` to ``target`` as a recorder would while the session
    happens: each message when its time comes (relative to the first, at ``speed``), stamped with the wall
    clock at that moment, one unchunked record each, flushed every ``FLUSH_S``. Returns the messages
    written (fewer if ``stop`` is set)."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    with open(source, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        if summary is None:
            raise FollowError(f"{source}: no MCAP summary (is the recording complete?)")
        messages = [(m.channel_id, m.log_time, m.data) for _, _, m in reader.iter_messages(log_time_order=True)]
        schemas, channels = summary.schemas, summary.channels
    written = 0
    with open(target, "wb") as out:
        writer = Writer(out, use_chunking=False, compression=CompressionType.NONE, enable_crcs=True)
        writer.start(profile="ros2", library="touch2robot-live")
        schema_ids = {sid: writer.register_schema(s.name, s.encoding, s.data) for sid, s in schemas.items()}
        channel_ids = {
            cid: writer.register_channel(c.topic, c.message_encoding, schema_ids.get(c.schema_id, 0), c.metadata)
            for cid, c in channels.items()
        }
        out.flush()
        if messages:
            first, start = messages[0][1], time.monotonic()
            last_flush = start
            for channel, log_time, data in messages:
                due = start + (log_time - first) * 1e-9 / speed
                while not stop.is_set() and (wait := due - time.monotonic()) > 0:
                    out.flush()
                    last_flush = time.monotonic()
                    stop.wait(min(wait, FLUSH_S))
                if stop.is_set():
                    break
                now = time.time_ns()
                writer.add_message(channel_ids[channel], log_time=now, data=data, publish_time=now)
                written += 1
                if time.monotonic() - last_flush >= FLUSH_S:
                    out.flush()
                    last_flush = time.monotonic()
        writer.finish()
    return written


FLUSH_S = 0.005  # a recorder flushing every 5 ms keeps the file <= 5 ms behind the session
