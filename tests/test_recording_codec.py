"""The CDR codec and MCAP writer against independent readers (mcap_ros2, rosbags)."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zstandard
from mcap.reader import make_reader
from mcap.records import Chunk, DataEnd, Footer, MessageIndex
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory

from schemas.glove import GLOVE_JOINT_NAMES
from schemas.messages import LEAP_JOINT_NAMES
from touch2robot.recording import cdr
from touch2robot.recording.writer import RecordingWriter


def _messages(rng: np.random.Generator) -> dict[str, tuple[str, bytes]]:
    return {
        "tactile": (
            "touch2robot_msgs/msg/TactileArray",
            cdr.encode_tactile(123_456_789_012, "glove_right", rng.normal(size=256)),
        ),
        "joints": (
            "sensor_msgs/msg/JointState",
            cdr.encode_joint_state(
                5, "leap", LEAP_JOINT_NAMES, rng.normal(size=16), rng.normal(size=16), rng.normal(size=16)
            ),
        ),
        "pose": (
            "geometry_msgs/msg/PoseStamped",
            cdr.encode_pose_stamped(7, "world", rng.normal(size=3), np.array([0.5, 0.5, 0.5, 0.5])),
        ),
        "poses": ("geometry_msgs/msg/PoseArray", cdr.encode_pose_array(9, "world", rng.normal(size=(21, 3)))),
        "reftime": ("touch2robot_msgs/msg/ReferenceTime", cdr.encode_reference_time(11, "leap", 3.25)),
    }


def test_batch_decoding_equals_per_message_decoding() -> None:
    rng = np.random.default_rng(0)
    for msg_type, _ in _messages(rng).values():
        payloads = [
            m
            for t, m in (_messages(np.random.default_rng(s))[k] for s in range(5) for k in _messages(rng))
            if t == msg_type
        ]
        batch = cdr.decode_batch(msg_type, payloads)
        for i, p in enumerate(payloads):
            one = cdr.decode(msg_type, p)
            assert one["stamp_ns"] == batch.stamp_ns[i]
            for name, col in batch.fields.items():
                np.testing.assert_array_equal(np.atleast_1d(one[name]), col[i])


def test_slow_path_when_layouts_differ() -> None:
    a = cdr.encode_tactile(1, "a", np.arange(4))
    b = cdr.encode_tactile(2, "bbbb", np.arange(4) + 1)  # different frame id -> different layout
    batch = cdr.decode_batch("touch2robot_msgs/msg/TactileArray", [a, b])
    np.testing.assert_array_equal(batch.fields["values"], [[0, 1, 2, 3], [1, 2, 3, 4]])
    with pytest.raises(cdr.CdrError, match="length"):
        cdr.decode_batch("touch2robot_msgs/msg/TactileArray", [a, cdr.encode_tactile(2, "a", np.arange(5))])


def test_truncated_message_is_a_clear_error() -> None:
    data = cdr.encode_tactile(1, "glove", np.arange(256))
    with pytest.raises(cdr.CdrError, match="message 0"):
        cdr.decode_batch("touch2robot_msgs/msg/TactileArray", [data[:-10]])


def _write_replay(path: Path) -> None:
    meta = {
        "task": "pick",
        "subject": "s01",
        "method": "touch2robot",
        "reference_recording": "g.mcap",
        "calibration_recording": "c.mcap",
    }
    with RecordingWriter(path, "robot_replay", meta) as w:
        for i in range(3):
            s = 1_000_000_000 + i * 10_000_000
            w.write("/twintac/raw", s, cdr.encode_tactile(s, "twintac", np.arange(16) + i))
            w.write("/leap/joint_states", s, cdr.encode_joint_state(s, "leap", LEAP_JOINT_NAMES, np.full(16, 0.1 * i)))
            w.write("/replay/reference_time", s, cdr.encode_reference_time(s, "leap", 0.5 * i))


def test_mcap_ros2_decoder_reads_our_files(tmp_path: Path) -> None:
    path = tmp_path / "replay.mcap"
    _write_replay(path)
    with open(path, "rb") as f:
        decoded = [
            (c.topic, m) for _, c, _, m in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages()
        ]
    tactile = [m for t, m in decoded if t == "/twintac/raw"]
    assert [list(m.values)[:3] for m in tactile] == [[0, 1, 2], [1, 2, 3], [2, 3, 4]]
    states = [m for t, m in decoded if t == "/leap/joint_states"]
    assert tuple(states[0].name) == LEAP_JOINT_NAMES and states[2].position[0] == pytest.approx(0.2)
    assert [m.reference_time for t, m in decoded if t == "/replay/reference_time"] == [0.0, 0.5, 1.0]


def test_rosbags_reads_our_files(tmp_path: Path) -> None:
    from rosbags.highlevel import AnyReader

    path = tmp_path / "replay.mcap"
    _write_replay(path)
    with AnyReader([path]) as reader:
        conns = [c for c in reader.connections if c.topic == "/leap/joint_states"]
        msgs: list[Any] = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(connections=conns)]
    assert len(msgs) == 3
    assert list(msgs[1].name) == list(LEAP_JOINT_NAMES)
    np.testing.assert_allclose(msgs[1].position, np.full(16, 0.1))


def test_writer_leaves_no_file_on_error(tmp_path: Path) -> None:
    path = tmp_path / "g.mcap"
    with (
        pytest.raises(RuntimeError),
        RecordingWriter(path, "glove_session", {"task": "pick", "subject": "s01"}) as w,
    ):
        w.write("/glove/hand_joints", 1, cdr.encode_joint_state(1, "glove", GLOVE_JOINT_NAMES, np.zeros(20)))
        raise RuntimeError("recorder crashed")
    assert list(tmp_path.iterdir()) == []


def test_a_batch_reads_back_whole_through_every_index(tmp_path: Path) -> None:
    """``write_batch`` builds message records itself: mcap's readers (in file and in log-time order, CRCs
    checked), rosbags and the file's own message indexes and summary must all agree with what was written."""
    from rosbags.highlevel import AnyReader

    rng = np.random.default_rng(1)
    n = 700  # in batches of 100, several chunks at the small chunk size below
    stamps = 10**9 + np.sort(rng.integers(0, 10**9, n))
    tactile = rng.normal(size=(n, 16))
    rows = np.stack(
        [
            np.frombuffer(cdr.encode_tactile(int(s), "twintac", v), np.uint8)
            for s, v in zip(stamps, tactile, strict=True)
        ]
    )
    reference = np.frombuffer(cdr.encode_reference_time(10**9, "leap", 0.25), np.uint8)[None]
    path = tmp_path / "replay.mcap"
    meta = {"task": "pick", "subject": "s01", "method": "touch2robot"}
    meta |= {"reference_recording": "g.mcap", "calibration_recording": "c.mcap"}
    with RecordingWriter(path, "robot_replay", meta, chunk_size=4096) as w:
        w.write("/leap/joint_states", 5, cdr.encode_joint_state(5, "leap", LEAP_JOINT_NAMES, np.zeros(16)))
        for lo in range(0, n, 100):
            order = np.stack([np.zeros(100, int), np.arange(100)], 1)
            w.write_batch([("/twintac/raw", stamps[lo : lo + 100], rows[lo : lo + 100])], order)
        # a message earlier than those before it, after them in the file
        w.write_batch([("/replay/reference_time", np.array([10**9]), reference)], np.array([[0, 0]]))
    expected = [("/leap/joint_states", 5), *(("/twintac/raw", int(s)) for s in stamps)]
    expected.append(("/replay/reference_time", 10**9))

    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        in_file = [(c.topic, m.log_time) for _, c, m in reader.iter_messages(log_time_order=False)]
        by_time = [(c.topic, m.log_time) for _, c, m in reader.iter_messages(log_time_order=True)]
        summary = reader.get_summary()
    assert summary is not None and summary.statistics is not None
    statistics = summary.statistics
    assert in_file == expected
    assert by_time == sorted(expected, key=lambda e: e[1])
    assert statistics.message_count == n + 2 and statistics.chunk_count > 3
    assert (statistics.message_start_time, statistics.message_end_time) == (5, max(e[1] for e in expected))

    decoded: list[tuple[int, Any]] = []
    with AnyReader([path]) as bag:
        for connection, timestamp, raw in bag.messages():
            if connection.topic == "/twintac/raw":
                decoded.append((timestamp, bag.deserialize(raw, connection.msgtype)))
    assert [t for t, _ in decoded] == stamps.tolist()
    np.testing.assert_array_equal([m.values for _, m in decoded], tactile.astype(np.float32))

    # every message index entry points at a message of its channel with that log time; both CRCs hold
    with open(path, "rb") as f:
        records = list(StreamReader(f, emit_chunks=True, validate_crcs=True).records)
    assert next(r for r in records if isinstance(r, DataEnd)).data_section_crc
    indexed, data = 0, b""
    for record in records:
        if isinstance(record, Chunk):
            data = zstandard.ZstdDecompressor().decompress(record.data, max_output_size=record.uncompressed_size)
            assert zlib.crc32(data) == record.uncompressed_crc
        elif isinstance(record, MessageIndex):
            for log_time, offset in record.records:
                opcode, _, channel, _, stamp = struct.unpack_from("<BQHIQ", data, offset)
                assert (opcode, channel, stamp) == (0x05, record.channel_id, log_time)
                indexed += 1
    assert indexed == n + 2
    footer = next(r for r in records if isinstance(r, Footer))
    raw = path.read_bytes()
    footer_at = len(raw) - 8 - (1 + 8 + 20)  # magic after it; opcode, length, two offsets and the CRC
    assert zlib.crc32(raw[footer.summary_start : footer_at + 1 + 8 + 16]) == footer.summary_crc


def test_writers_on_several_threads_each_write_a_whole_file(tmp_path: Path) -> None:
    """The replay stage writes recordings on several threads at once: each file reads back whole (a compressor
    shared between writers corrupted chunks: "cannot compress: Src size is incorrect")."""
    from concurrent.futures import ThreadPoolExecutor

    rng = np.random.default_rng(2)
    rows = np.stack([np.frombuffer(cdr.encode_tactile(k, "twintac", rng.normal(size=16)), np.uint8) for k in range(50)])

    def write(k: int) -> Path:
        path = tmp_path / f"calib{k}.mcap"
        with RecordingWriter(path, "robot_calibration", {}, chunk_size=2048) as w:
            for batch in range(40):
                stamps = 10**9 * k + batch * 50 + np.arange(50)
                w.write_batch([("/twintac/raw", stamps, rows)], np.stack([np.zeros(50, int), np.arange(50)], 1))
        return path

    with ThreadPoolExecutor(4) as pool:
        paths = list(pool.map(write, range(8)))
    for path in paths:
        with open(path, "rb") as f:
            assert sum(1 for _ in make_reader(f, validate_crcs=True).iter_messages()) == 40 * 50
