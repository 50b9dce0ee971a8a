"""Ingest against a hostile folder and hostile files: odd folder entries are skipped with a reason and never
stop the rest, metadata and values a rig cannot produce are quarantined naming topic, message and value,
replays link to files of their own folder, and random mutations of real recordings never crash the reader,
never leave rows of a quarantined file and never let an implausible value through."""

from __future__ import annotations

import os
import shutil
import struct
import threading
from pathlib import Path

import duckdb
import numpy as np
import pyarrow.parquet as pq
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from schemas import plausibility as plaus
from schemas.glove import GLOVE_JOINT_NAMES
from touch2robot.ingest import ingest_file, link_replays, recording_rows
from touch2robot.ingest.scan import find_recordings, folder_state
from touch2robot.recording import cdr
from touch2robot.recording.writer import RecordingWriter

FLT_MAX = float(np.finfo(np.float32).max)
STEP_NS = 10_000_000


def _glove_session(path: Path, metadata: dict[str, str] | None = None, mutate=None) -> Path:
    """A small, valid glove session; ``mutate(topic, i, stamp, payload) -> (stamp, payload)`` injects one
    defect, where payload is the message's numeric content (values, joint positions or a 7-float pose)."""
    meta = {"task": "pick", "subject": "s09"} if metadata is None else metadata
    identity = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])  # x y z, qw qx qy qz
    with RecordingWriter(path, "glove_session", meta) as w:
        for i in range(20):
            stamps = {}
            payloads = {
                "/glove/taxels": np.full(256, 100.0),
                "/glove/hand_joints": np.zeros(20),
                "/glove/keypoints": np.zeros((21, 3)),
                "/glove/wrist_pose": identity.copy(),
                "/object/pose": identity.copy(),
            }
            for topic, payload in payloads.items():
                stamps[topic] = 1_000_000_000 + i * STEP_NS
                if mutate is not None:
                    stamps[topic], payloads[topic] = mutate(topic, i, stamps[topic], payload)
            s = stamps
            w.write(
                "/glove/taxels",
                max(s["/glove/taxels"], 0),
                cdr.encode_tactile(s["/glove/taxels"], "glove", payloads["/glove/taxels"]),
            )
            w.write(
                "/glove/hand_joints",
                max(s["/glove/hand_joints"], 0),
                cdr.encode_joint_state(
                    s["/glove/hand_joints"], "glove", GLOVE_JOINT_NAMES, payloads["/glove/hand_joints"]
                ),
            )
            w.write(
                "/glove/keypoints",
                max(s["/glove/keypoints"], 0),
                cdr.encode_pose_array(s["/glove/keypoints"], "world", payloads["/glove/keypoints"]),
            )
            for topic, frame in (("/glove/wrist_pose", "world"), ("/object/pose", "box")):
                pose = payloads[topic]
                w.write(topic, max(s[topic], 0), cdr.encode_pose_stamped(s[topic], frame, pose[:3], pose[3:]))
    return path


def _at(topic: str, message: int, change):
    def mutate(t, i, stamp, payload):
        if t == topic and i == message:
            return change(stamp, np.array(payload, dtype=np.float64))
        return stamp, payload

    return mutate


def _value(index: int, value: float):
    def change(stamp, payload):
        payload.reshape(-1)[index] = value
        return stamp, payload

    return change


def _stamp(delta_ns: int):
    return lambda stamp, payload: (stamp + delta_ns, payload)


def _ids_in_lake(lake: Path) -> set[str]:
    return {p.stem for p in lake.rglob("*.parquet") if "recordings" not in p.parts}


# --- a hostile folder ----------------------------------------------------------------------------------------


def test_odd_folder_entries_are_skipped_with_a_reason_and_the_rest_found(tmp_path: Path) -> None:
    folder = tmp_path / "recordings"
    good = _glove_session(folder / "good.mcap")
    (folder / "loop.mcap").symlink_to(folder / "loop.mcap")
    (folder / "dangling.mcap").symlink_to(folder / "gone.mcap")
    (folder / "dir.mcap").mkdir()
    os.mkfifo(folder / "fifo.mcap")
    (folder / "sub").mkdir()
    (folder / "sub" / "up").symlink_to(folder, target_is_directory=True)  # a folder loop
    (folder / "link.mcap").symlink_to(good)
    result: list = []
    walker = threading.Thread(target=lambda: result.append(find_recordings(folder)), daemon=True)
    walker.start()
    walker.join(30)
    assert result, "the walk hung (a FIFO must never be opened)"
    scan = result[0]
    assert scan.recordings == [good.absolute(), (folder / "link.mcap").absolute()]
    reasons = {p.name: why for p, why in scan.skipped}
    assert set(reasons) == {"loop.mcap", "dangling.mcap", "dir.mcap", "fifo.mcap"}
    assert "dangling or looping link" in reasons["loop.mcap"] and "dangling or looping link" in reasons["dangling.mcap"]
    assert reasons["dir.mcap"].startswith("a directory") and reasons["fifo.mcap"].startswith("a FIFO")


def test_a_folder_state_moves_with_every_change_an_ingest_could_see(tmp_path: Path) -> None:
    """The replay stage skips its ingest when the recordings folder is in the state the run's ingest found: the
    state must move with every file written, added, removed or renamed, inside linked folders too."""
    import time

    folder, linked = tmp_path / "recordings", tmp_path / "elsewhere"
    folder.mkdir()
    linked.mkdir()
    (folder / "a.mcap").write_bytes(b"a" * 100)
    (linked / "b.mcap").write_bytes(b"b" * 100)
    (folder / "more").symlink_to(linked)
    states = [folder_state(folder)]
    assert folder_state(folder) == states[0]  # nothing changed: the same state

    def changed(change) -> None:
        time.sleep(0.02)  # past a timestamp tick
        change()
        states.append(folder_state(folder))
        assert states[-1] not in states[:-1], change

    changed(lambda: (folder / "a.mcap").write_bytes(b"A" * 100))  # same size, in place
    changed(lambda: (linked / "b.mcap").write_bytes(b"B" * 100))  # behind a link
    changed(lambda: (folder / "c.mcap").write_bytes(b"c"))
    changed(lambda: (folder / "c.mcap").rename(folder / "d.mcap"))
    changed(lambda: (folder / "d.mcap").unlink())
    changed(lambda: (folder / "a.rig.yaml").write_text("rig"))
    assert folder_state(tmp_path / "missing") != folder_state(tmp_path / "missing")  # never "unchanged"


def test_a_missing_or_non_folder_recordings_path_is_named(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="nowhere"):
        find_recordings(tmp_path / "nowhere")
    (tmp_path / "file").write_text("x")
    with pytest.raises(NotADirectoryError, match="file"):
        find_recordings(tmp_path / "file")


def test_an_unreadable_path_is_quarantined_not_raised(tmp_path: Path) -> None:
    lake = tmp_path / "lake"
    (tmp_path / "dir.mcap").mkdir()
    result = ingest_file(tmp_path / "dir.mcap", lake)
    assert result.status == "quarantined" and "cannot read the file" in result.reason


# --- hostile metadata ----------------------------------------------------------------------------------------

HOSTILE_NAMES = ["..", "/etc", "pi\x00ck", "x" * 5000, "pick=1/x=2", "qick", ""]


@pytest.mark.parametrize("task", HOSTILE_NAMES, ids=["dotdot", "absolute", "nul", "long", "hive", "typo", "empty"])
def test_an_unknown_or_hostile_task_is_quarantined(task: str, tmp_path: Path) -> None:
    result = ingest_file(_glove_session(tmp_path / "g.mcap", {"task": task, "subject": "s01"}), tmp_path / "lake")
    assert result.status == "quarantined"
    assert "metadata" in result.reason and "task" in result.reason
    assert len(result.reason) < 400  # a 5000-character value is not echoed whole
    assert _ids_in_lake(tmp_path / "lake") == set()


@pytest.mark.parametrize("subject", ["..", "a/b", "r\x0001", "s" * 200])
def test_a_hostile_subject_is_quarantined(subject: str, tmp_path: Path) -> None:
    result = ingest_file(_glove_session(tmp_path / "g.mcap", {"task": "pick", "subject": subject}), tmp_path / "lake")
    assert result.status == "quarantined" and "metadata 'subject'" in result.reason


def test_replay_metadata_names_a_known_method_and_plain_file_names(replay_data: Path, tmp_path: Path) -> None:
    from touch2robot.ingest.reader import read_recording

    replay = next((replay_data / "recordings").glob("pick_*_replay.mcap"))
    meta = read_recording(replay).metadata
    for key, value, expected in (
        ("method", "touch2robo", "metadata 'method'"),
        ("calibration_recording", "../other/calib.mcap", "metadata 'calibration_recording'"),
        ("schema_version", "9", "metadata 'schema_version'"),
        ("trajectory", "../../etc/passwd", "metadata 'trajectory'"),
    ):
        bad = tmp_path / f"{key}.mcap"
        _copy_with_metadata(replay, bad, {**meta, key: value})
        result = ingest_file(bad, tmp_path / "lake")
        assert result.status == "quarantined" and expected in result.reason, result.reason


def _copy_with_metadata(src: Path, dst: Path, metadata: dict[str, str]) -> None:
    """The same messages under other metadata (what a bit flip in an unchecked metadata record does)."""
    from mcap.reader import make_reader

    with open(src, "rb") as f:
        reader = make_reader(f)
        kind = metadata["kind"]
        with RecordingWriter(dst, kind, {k: v for k, v in metadata.items() if k != "kind"}) as w:
            for _, channel, message in reader.iter_messages(log_time_order=False):
                w.write(channel.topic, message.log_time, message.data)


# --- implausible values --------------------------------------------------------------------------------------

IMPLAUSIBLE = {
    "taxel_1e30": (_at("/glove/taxels", 3, _value(5, 1e30)), "topic /glove/taxels, field 'values': implausible value"),
    "taxel_flt_max": (
        _at("/glove/taxels", 3, _value(5, FLT_MAX)),
        "implausible value 3.40282e+38 at message 3, index 5",
    ),
    "taxel_negative": (_at("/glove/taxels", 4, _value(0, -1e6)), "implausible value -1e+06 at message 4, index 0"),
    "joint_1e30": (_at("/glove/hand_joints", 2, _value(7, 1e30)), "topic /glove/hand_joints, field 'position'"),
    "zero_quaternion": (
        _at("/glove/wrist_pose", 6, lambda stamp, pose: (stamp, np.array([0, 0, 0, 0, 0, 0, 0.0]))),
        "topic /glove/wrist_pose, field 'pose': orientation [0.0, 0.0, 0.0, 0.0] at message 6 is not a unit quaternion",
    ),
    "position_far": (
        _at("/object/pose", 1, _value(2, 1e3)),
        "topic /object/pose, field 'pose': implausible value 1000",
    ),
    "negative_stamp": (_at("/object/pose", 0, _stamp(-6_000_000_000)), "topic /object/pose: negative timestamp"),
    "late_stream": (
        lambda t, i, stamp, p: (stamp + (10**12 if t == "/object/pose" else 0), p),
        "topic /object/pose: first message at 1000 s after the recording's first",
    ),
}


@pytest.mark.parametrize("case", sorted(IMPLAUSIBLE))
def test_implausible_values_are_quarantined_naming_topic_message_and_value(case: str, tmp_path: Path) -> None:
    mutate, expected = IMPLAUSIBLE[case]
    result = ingest_file(_glove_session(tmp_path / "g.mcap", mutate=mutate), tmp_path / "lake")
    assert result.status == "quarantined"
    assert expected in result.reason, result.reason
    assert _ids_in_lake(tmp_path / "lake") == set()


def test_the_demonstrators_and_the_twins_recordings_are_plausible(replay_data: Path, tmp_path: Path) -> None:
    for path in sorted((replay_data / "recordings").glob("*.mcap")):
        result = ingest_file(path, tmp_path / "lake")
        assert result.status == "ingested", (path.name, result.reason)


# --- links by folder, not by bare file name ------------------------------------------------------------------


def test_replays_link_to_the_calibration_and_session_of_their_own_folder() -> None:
    def row(folder: str, name: str, kind: str, **extra) -> dict:
        return {
            "recording_id": f"{folder}-{name}",
            "path": f"/data/recordings/{folder}/{name}",
            "file_name": name,
            "kind": kind,
            "status": "ingested",
            **extra,
        }

    rows = []
    for folder in ("s1", "s2"):
        rows += [
            row(folder, "glove.mcap", "glove_session"),
            row(folder, "calib.mcap", "robot_calibration"),
            row(
                folder,
                "replay.mcap",
                "robot_replay",
                calibration_recording="calib.mcap",
                reference_recording="glove.mcap",
            ),
        ]
    _, links, problems = link_replays(rows)
    assert problems == []
    for link in links:
        folder = link.replay["recording_id"].split("-")[0]
        assert link.calibration_id == f"{folder}-calib.mcap"
        assert link.reference is not None and link.reference["recording_id"] == f"{folder}-glove.mcap"


# --- fuzzing the reader --------------------------------------------------------------------------------------

TOPIC_FIELDS = {
    "/glove/taxels": 256,
    "/glove/hand_joints": 20,
    "/glove/keypoints": 63,
    "/glove/wrist_pose": 7,
    "/object/pose": 7,
}
HOSTILE_FLOATS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([1e30, -1e30, FLT_MAX, -FLT_MAX, 65536.0, -1e-3, 7.0, 0.0, 1.0, 2.5]),
)


def _assert_lake_holds_only_plausible_rows(lake: Path, result) -> None:
    ids = _ids_in_lake(lake)
    if result.status == "quarantined":
        assert ids == set(), f"rows of a quarantined file stayed: {result.reason}"
        return
    con = duckdb.connect()
    for table, column, bounds in (
        ("taxels", "values", plaus.TACTILE_COUNTS),
        ("hand_joints", "position", plaus.JOINT_ANGLE),
        ("hand_keypoints", "xyz", plaus.POSITION),
    ):
        low, high = con.sql(
            f"SELECT min(list_min({column})), max(list_max({column})) FROM read_parquet($p)",
            params={"p": str(lake / table / f"{result.recording_id}.parquet")},
        ).fetchall()[0]
        assert bounds.low <= low and high <= bounds.high, (table, low, high)
    for table in ("wrist_pose", "object_pose"):
        pose = pq.read_table(lake / table / f"{result.recording_id}.parquet").to_pandas()
        xyz, quat = pose[["px", "py", "pz"]].to_numpy(), pose[["qw", "qx", "qy", "qz"]].to_numpy()
        assert np.isfinite(xyz).all() and (np.abs(xyz) <= plaus.POSITION.high).all()
        assert (np.abs(np.linalg.norm(quat, axis=1) - 1) <= plaus.QUATERNION_TOLERANCE).all()


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    topic=st.sampled_from(sorted(TOPIC_FIELDS)),
    message=st.integers(0, 19),
    index=st.integers(0, 255),
    value=HOSTILE_FLOATS,
    stamp_shift_s=st.sampled_from([0, 0, 0, -0.005, -2.0, 30.0, 120.0, 5000.0]),
)
def test_value_mutations_never_crash_and_never_store_an_implausible_value(
    tmp_path: Path, topic: str, message: int, index: int, value: float, stamp_shift_s: float
) -> None:
    work = tmp_path / f"v{abs(hash((topic, message, index, value, stamp_shift_s)))}"
    index %= TOPIC_FIELDS[topic]

    def change(stamp, payload):
        payload.reshape(-1)[index] = value
        return stamp + int(stamp_shift_s * 1e9), payload

    path = _glove_session(work / "g.mcap", mutate=_at(topic, message, change))
    result = ingest_file(path, work / "lake")
    _assert_lake_holds_only_plausible_rows(work / "lake", result)
    shutil.rmtree(work)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_byte_mutations_of_a_real_recording_never_crash_and_leave_nothing_of_a_bad_file(
    replay_data: Path, tmp_path: Path, data: st.DataObject
) -> None:
    original = next((replay_data / "recordings").glob("pick_*_calib.mcap")).read_bytes()
    blob = bytearray(original)
    for _ in range(data.draw(st.integers(1, 4), label="mutations")):
        op = data.draw(st.sampled_from(["flip", "truncate", "insert", "delete"]), label="op")
        at = data.draw(st.integers(0, len(blob) - 1), label="at")
        if op == "flip":
            blob[at] ^= data.draw(st.integers(1, 255), label="mask")
        elif op == "truncate":
            del blob[at:]
        elif op == "insert":
            blob[at:at] = data.draw(st.binary(min_size=1, max_size=16), label="bytes")
        else:
            del blob[at : at + data.draw(st.integers(1, 64), label="length")]
        if not blob:
            break
    work = tmp_path / f"b{abs(hash(bytes(blob)))}"
    work.mkdir()
    (work / "c.mcap").write_bytes(bytes(blob))
    result = ingest_file(work / "c.mcap", work / "lake")
    assert result.status in ("ingested", "quarantined")
    if result.status == "quarantined":
        assert _ids_in_lake(work / "lake") == set()
        assert recording_rows(work / "lake").to_pylist()[0]["status"] == "quarantined"
    else:  # a mutation the CRCs let through (e.g. in padding) still yields only plausible readings
        values = np.stack(
            pq.read_table(work / "lake" / "twintac" / f"{result.recording_id}.parquet")["values"].to_numpy(
                zero_copy_only=False
            )
        )
        assert np.isfinite(values).all() and (values >= plaus.TACTILE_COUNTS.low).all()
        assert (values <= plaus.TACTILE_COUNTS.high).all()
    shutil.rmtree(work)


# --- a bit flip in the metadata --------------------------------------------------------------------------------


def _metadata_record(data: bytes) -> tuple[int, int]:
    """(start, end) of the first Metadata record in the data section (opcode 0x0C)."""
    pos = 8  # after the magic
    while pos < len(data):
        opcode, length = data[pos], struct.unpack_from("<Q", data, pos + 1)[0]
        if opcode == 0x0C:
            return pos, pos + 9 + length
        pos += 9 + length
    raise AssertionError("no metadata record")


def test_a_bit_flip_in_the_metadata_is_caught_by_the_data_crc(tmp_path: Path) -> None:
    """The subject 's09' flipped to 'r09' is a plausible name: only the data-section CRC can tell."""
    path = _glove_session(tmp_path / "g.mcap")
    data = bytearray(path.read_bytes())
    start, end = _metadata_record(bytes(data))
    at = data.index(b"s09", start, end)
    data[at] ^= ord("s") ^ ord("r")
    (tmp_path / "flipped.mcap").write_bytes(bytes(data))
    result = ingest_file(tmp_path / "flipped.mcap", tmp_path / "lake")
    assert result.status == "quarantined" and "crc validation failed in DataEnd" in result.reason, result.reason
