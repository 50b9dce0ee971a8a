"""Ingestion: good files land whole, bad files are quarantined whole with a clear reason."""

from __future__ import annotations

import shutil
import struct
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from mcap.writer import Writer

from schemas.glove import GLOVE_JOINT_NAMES
from schemas.messages import METADATA_NAME, MSG_DEFINITIONS, SCHEMA_VERSION
from schemas.rig import DEFAULT_RIG
from touch2robot import lake as lake_io
from touch2robot.ingest import ingest_file, link_replays, recording_rows, superseded_ids
from touch2robot.recording import cdr
from touch2robot.recording.writer import RecordingWriter


def _glove(smoke_data: Path) -> Path:
    return next((smoke_data / "recordings").glob("pick_*_glove.mcap"))


def _ids_in_lake(lake: Path) -> set[str]:
    return {p.stem for p in lake.rglob("*.parquet") if "recordings" not in p.parts}


def test_glove_session_lands_in_every_stream_table(smoke_data: Path, tmp_path: Path) -> None:
    lake = tmp_path / "lake"
    result = ingest_file(_glove(smoke_data), lake)
    assert result.status == "ingested" and result.kind == "glove_session"
    for topic in DEFAULT_RIG.topics("glove_session"):
        table = pq.read_table(lake_io.file_path(lake, topic.table, result.recording_id))
        assert table.num_rows > 0
        t = table["t"].to_numpy()
        assert (np.diff(t) > 0).all() and t[0] >= 0
    taxels = pq.read_table(lake / "taxels" / f"{result.recording_id}.parquet")
    assert taxels.num_rows == pytest.approx(taxels["t"].to_numpy()[-1] * 100, rel=0.05)  # 100 Hz
    row = recording_rows(lake).to_pylist()[0]
    assert row["status"] == "ingested" and row["task"] == "pick" and row["subject"] == "s01"


def test_reingest_changes_nothing_and_changed_file_gets_new_id(smoke_data: Path, tmp_path: Path) -> None:
    lake = tmp_path / "lake"
    path = tmp_path / "rec.mcap"
    shutil.copy(_glove(smoke_data), path)
    first = ingest_file(path, lake)
    before = {p: p.stat().st_mtime_ns for p in lake.rglob("*.parquet")}
    assert ingest_file(path, lake).status == "unchanged"
    assert {p: p.stat().st_mtime_ns for p in lake.rglob("*.parquet")} == before
    shutil.copy(next((smoke_data / "recordings").glob("wipe_*_glove.mcap")), path)
    second = ingest_file(path, lake)
    assert second.recording_id != first.recording_id
    assert superseded_ids(lake, {str(path.resolve()): second.recording_id}) == [first.recording_id]


def _flip_chunk_byte(data: bytes) -> bytes:
    """Damage one byte inside the first chunk's compressed records."""
    opcode_chunk = 0x06
    pos = 8  # after the magic
    while pos < len(data):
        opcode, length = data[pos], struct.unpack_from("<Q", data, pos + 1)[0]
        if opcode == opcode_chunk:
            b = bytearray(data)
            b[pos + 9 + length // 2] ^= 0xFF
            return bytes(b)
        pos += 9 + length
    raise AssertionError("no chunk")


def _rewrite(
    src_smoke: Path, path: Path, *, drop: str = "", mutate=None, schema_name: str | None = None, metadata=None
) -> None:
    """A small glove session written from scratch with one defect injected."""
    meta = {"task": "pick", "subject": "s09"} if metadata is None else metadata
    # a wrong schema comes from another recorder (ours cannot write one): mcap's own writer
    opened = _OtherRecorder(path, meta, schema_name) if schema_name else RecordingWriter(path, "glove_session", meta)
    with opened as w:
        for i in range(20):
            s = 1_000_000_000 + i * 10_000_000
            values = np.full(256, 100.0)
            stamp = s
            if mutate:
                values, stamp = mutate(i, values, stamp)
            if drop != "/glove/taxels":
                # logged in order: a header stamp that goes back while the log time goes on is the defect
                # (messages merely stored out of log-time order are sorted: tests/test_ingest_sources.py)
                w.write("/glove/taxels", s, cdr.encode_tactile(stamp, "glove", values))
            if drop != "/glove/hand_joints":
                w.write("/glove/hand_joints", s, cdr.encode_joint_state(s, "glove", GLOVE_JOINT_NAMES, np.zeros(20)))
            w.write("/glove/keypoints", s, cdr.encode_pose_array(s, "world", np.zeros((21, 3))))
            w.write("/glove/wrist_pose", s, cdr.encode_pose_stamped(s, "world", np.zeros(3), np.array([1.0, 0, 0, 0])))
            w.write("/object/pose", s, cdr.encode_pose_stamped(s, "box", np.zeros(3), np.array([1.0, 0, 0, 0])))


class _OtherRecorder:
    """A glove session written with mcap's ``Writer``, the taxel topic registered under ``taxel_schema``."""

    def __init__(self, path: Path, metadata: dict[str, str], taxel_schema: str) -> None:
        self.path, self.taxel_schema = path, taxel_schema
        self.metadata = {"kind": "glove_session", "schema_version": SCHEMA_VERSION, **metadata}

    def __enter__(self) -> _OtherRecorder:
        self.file = open(self.path, "wb")
        self.writer = Writer(self.file)
        self.writer.start(profile="ros2")
        self.channels = {}
        for topic in DEFAULT_RIG.topics("glove_session"):
            name = self.taxel_schema if topic.name == "/glove/taxels" else topic.msg_type
            schema = self.writer.register_schema(name, "ros2msg", MSG_DEFINITIONS[topic.msg_type].encode())
            self.channels[topic.name] = self.writer.register_channel(topic.name, "cdr", schema)
        return self

    def write(self, topic: str, stamp_ns: int, data: bytes) -> None:
        self.writer.add_message(self.channels[topic], log_time=stamp_ns, data=data, publish_time=stamp_ns)

    def __exit__(self, *exc: object) -> None:
        self.writer.add_metadata(METADATA_NAME, self.metadata)
        self.writer.finish()
        self.file.close()


def _nan(i, values, stamp):
    if i == 7:
        values = values.copy()
        values[3] = np.nan
    return values, stamp


def _short(i, values, stamp):
    return (values[:255], stamp) if i == 4 else (values, stamp)


def _backwards(i, values, stamp):
    return values, (stamp - 25_000_000 if i == 5 else stamp)


BAD_INPUTS = {
    "truncated": ("truncated", lambda good, p, s: p.write_bytes(good.read_bytes()[: good.stat().st_size * 2 // 3])),
    "corrupt_chunk": ("corrupt or truncated", lambda good, p, s: p.write_bytes(_flip_chunk_byte(good.read_bytes()))),
    "missing_topic": (
        "missing topic(s) /glove/hand_joints",
        lambda good, p, s: _rewrite(s, p, drop="/glove/hand_joints"),
    ),
    "wrong_schema": (
        "topic /glove/taxels has schema 'std_msgs/msg/Float32MultiArray'",
        lambda good, p, s: _rewrite(s, p, schema_name="std_msgs/msg/Float32MultiArray"),
    ),
    "non_monotonic": (
        "timestamps not strictly increasing at message 5",
        lambda good, p, s: _rewrite(s, p, mutate=_backwards),
    ),
    "nan_taxels": (
        "non-finite value (nan) in field 'values' at message 7, index 3",
        lambda good, p, s: _rewrite(s, p, mutate=_nan),
    ),
    "wrong_length": (
        "topic /glove/taxels: field 'values' has length 255 in message 4",
        lambda good, p, s: _rewrite(s, p, mutate=_short),
    ),
    "no_metadata": ("metadata lacks task, subject", lambda good, p, s: _rewrite(s, p, metadata={"task": ""})),
}


@pytest.mark.parametrize("case", sorted(BAD_INPUTS))
def test_bad_input_is_quarantined_with_reason_and_no_rows(case: str, smoke_data: Path, tmp_path: Path) -> None:
    expected, make = BAD_INPUTS[case]
    lake = tmp_path / "lake"
    good = ingest_file(_glove(smoke_data), lake)  # something already stored must survive
    bad = tmp_path / f"{case}.mcap"
    make(_glove(smoke_data), bad, smoke_data)
    result = ingest_file(bad, lake)
    assert result.status == "quarantined"
    assert expected in result.reason
    rows = {r["recording_id"]: r for r in recording_rows(lake).to_pylist()}
    assert rows[result.recording_id]["status"] == "quarantined" and expected in rows[result.recording_id]["reason"]
    assert _ids_in_lake(lake) == {good.recording_id}
    assert rows[good.recording_id]["status"] == "ingested"


def test_joint_order_follows_the_contract(tmp_path: Path) -> None:
    """A rig that lists the joints in another order is reordered by name."""
    path = tmp_path / "g.mcap"
    names = tuple(reversed(GLOVE_JOINT_NAMES))
    with RecordingWriter(path, "glove_session", {"task": "pick", "subject": "s01"}) as w:
        for i in range(3):
            s = 10**9 + i * 10**7
            w.write("/glove/taxels", s, cdr.encode_tactile(s, "g", np.zeros(256)))
            w.write("/glove/hand_joints", s, cdr.encode_joint_state(s, "g", names, np.arange(20.0) / 16))
            w.write("/glove/keypoints", s, cdr.encode_pose_array(s, "world", np.zeros((21, 3))))
            w.write("/glove/wrist_pose", s, cdr.encode_pose_stamped(s, "world", np.zeros(3), np.array([1.0, 0, 0, 0])))
            w.write("/object/pose", s, cdr.encode_pose_stamped(s, "box", np.zeros(3), np.array([1.0, 0, 0, 0])))
    result = ingest_file(path, tmp_path / "lake")
    joints = pq.read_table(tmp_path / "lake" / "hand_joints" / f"{result.recording_id}.parquet")
    np.testing.assert_array_equal(joints["position"][0].as_py(), (np.arange(20.0) / 16)[::-1])


def test_replays_link_to_calibration_and_reference(replay_data: Path, tmp_path: Path) -> None:
    lake = tmp_path / "lake"
    for p in sorted((replay_data / "recordings").glob("pick_*.mcap")):
        assert ingest_file(p, lake).status == "ingested"
    gloves, links, problems = link_replays(recording_rows(lake).to_pylist())
    assert len(gloves) == 1 and len(links) == 1 and problems == []
    reference = links[0].reference
    assert reference is not None and reference["recording_id"] == gloves[0]["recording_id"]
    # the trajectory the replay executed is on its recordings row: tactile fidelity pairs them by it
    assert links[0].replay["trajectory"] == "teacher-touch2robot-pick-000" and gloves[0]["trajectory"] is None


def test_a_copied_recordings_folder_keeps_its_replays_linked(replay_data: Path, tmp_path: Path) -> None:
    """Unchanged recordings found at a new place (a copied data folder) have their rows follow them: a
    replay written there later links to its glove session by folder."""
    lake, first, copy = tmp_path / "lake", tmp_path / "first", tmp_path / "copy"
    first.mkdir()
    for p in (replay_data / "recordings").glob("pick_*.mcap"):
        shutil.copy(p, first / p.name)
    for p in sorted(first.glob("*.mcap")):
        ingest_file(p, lake)
    shutil.copytree(first, copy)
    shutil.rmtree(first)
    assert {ingest_file(p, lake).status for p in sorted(copy.glob("*.mcap"))} == {"unchanged"}
    rows = recording_rows(lake).to_pylist()
    assert {Path(r["path"]).parent for r in rows} == {copy.resolve()}
    _, links, problems = link_replays(rows)
    assert problems == [] and len(links) == 1 and links[0].reference is not None


def test_a_glove_session_carries_the_wrist_as_tf_and_the_robot_description_for_foxglove(smoke_data: Path) -> None:
    """/tf (the wrist, world -> the URDF's root) and /robot_description (the LEAP Hand's URDF), read back with
    rosbags' own ROS 2 message types: what Foxglove's 3D panel needs to show the hand."""
    import xml.etree.ElementTree as ET

    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    messages: dict[str, list] = {}
    with open(_glove(smoke_data), "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.topic in ("/tf", "/robot_description", "/glove/wrist_pose"):
                messages.setdefault(channel.topic, []).append(
                    (message.log_time, store.deserialize_cdr(message.data, schema.name if schema else ""))
                )
    (_, description), *more = messages["/robot_description"]
    assert not more
    urdf = ET.fromstring(description.data)
    root_link = urdf.find("link")
    assert urdf.get("name") == "leap_hand_right" and root_link is not None and root_link.get("name") == "base"
    tf, wrist = messages["/tf"], messages["/glove/wrist_pose"]
    assert len(tf) == len(wrist) > 0
    for (t_tf, msg), (t_wrist, pose) in zip(tf, wrist, strict=True):
        (transform,) = msg.transforms
        assert t_tf == t_wrist and transform.header.frame_id == "world" and transform.child_frame_id == "base"
        p, q = transform.transform.translation, transform.transform.rotation
        assert (p.x, p.y, p.z) == (pose.pose.position.x, pose.pose.position.y, pose.pose.position.z)
        assert (q.w, q.x, q.y, q.z) == (
            pose.pose.orientation.w,
            pose.pose.orientation.x,
            pose.pose.orientation.y,
            pose.pose.orientation.z,
        )
