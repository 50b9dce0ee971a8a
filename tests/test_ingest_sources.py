"""Recordings a lab's own recorder makes: rosbag2 folders (MCAP and sqlite3 storage) written with the plain
rosbags writer, session metadata from custom_data, a sidecar or the command line, and messages stored out of
log-time order. Each must land as the demonstrator's own file does."""

from __future__ import annotations

import random
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import yaml
from mcap.reader import make_reader
from mcap.writer import Writer

from schemas.messages import METADATA_NAME, MSG_DEFINITIONS
from schemas.rig import DEFAULT_RIG
from touch2robot import lake as lake_io
from touch2robot.ingest import ingest_file, link_replays, read_recording, recording_rows
from touch2robot.ingest.scan import find_recordings
from touch2robot.ingest.sources import sidecar_path

CUSTOM_TYPES = ("touch2robot_msgs/msg/TactileArray", "touch2robot_msgs/msg/ReferenceTime")


def _messages(path: Path) -> tuple[dict[str, dict[str, str]], list[tuple[str, str, int, int, bytes]]]:
    """The project record and every message (topic, type, log time, publish time, payload) of an MCAP file."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        record = next(m.metadata for m in reader.iter_metadata() if m.name == METADATA_NAME)
        messages = [
            (channel.topic, schema.name if schema else "", m.log_time, m.publish_time, m.data)
            for schema, channel, m in reader.iter_messages(log_time_order=False)
        ]
    return {METADATA_NAME: dict(record)}, messages


def _typestore():
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    for name in CUSTOM_TYPES:
        body = MSG_DEFINITIONS[name].split("=" * 80)[0]  # the type's own fields; its dependencies are standard
        store.register(get_types_from_msg(body, name))
    return store


def write_bag(source: Path, bag: Path, storage: str, custom_data: dict[str, str] | None = None) -> dict[str, str]:
    """Write ``source``'s messages as a rosbag2 folder with the plain rosbags writer (no project record), as
    a lab's recorder would; ``custom_data`` goes into its metadata.yaml. Returns the source's session fields."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    record, messages = _messages(source)
    plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
    store = _typestore()
    with Writer(bag, version=9, storage_plugin=plugin) as writer:
        connections = {}
        for topic, msgtype, *_ in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
        for topic, _, log_time, _, data in messages:
            writer.write(connections[topic], log_time, data)
        for key, value in (custom_data or {}).items():
            writer.set_custom_data(key, value)
    return {k: v for k, v in record[METADATA_NAME].items() if k != "schema_version"}


def _stream_tables(lake: Path, recording_id: str, kind: str) -> dict[str, pa.Table]:
    tables = {}
    for topic in DEFAULT_RIG.topics(kind):
        table = pq.read_table(lake_io.file_path(lake, topic.table, recording_id))
        tables[topic.table] = table.drop_columns([c for c in table.column_names if c == "recording_id"])
    return tables


def _same_landing(lake: Path, original: str, other: str, kind: str) -> None:
    mine, theirs = _stream_tables(lake, original, kind), _stream_tables(lake, other, kind)
    assert mine.keys() == theirs.keys()
    for name, table in mine.items():
        assert table.equals(theirs[name]), name
    rows = {r["recording_id"]: r for r in recording_rows(lake).to_pylist()}
    for column in ("kind", "task", "subject", "method", "start_time_s", "end_time_s", "message_counts", "seed"):
        assert rows[original][column] == rows[other][column], column


def _replay_trio(replay_data: Path) -> tuple[Path, Path, Path]:
    recordings = replay_data / "recordings"
    replay = sorted(recordings.glob("pick_*_replay.mcap"))[0]
    meta = read_recording(replay).metadata
    return recordings / meta["reference_recording"], replay, recordings / meta["calibration_recording"]


def test_rosbags_written_sessions_with_sidecars_land_as_the_demonstrators_own(
    replay_data: Path, tmp_path: Path
) -> None:
    """A glove session, a robot replay and its calibration, each rewritten as a rosbag2 MCAP folder by the
    rosbags writer and described by a sidecar, ingest with the same stream tables as the originals, and the
    replay links to its calibration and glove session by their folder names."""
    glove, replay, calibration = _replay_trio(replay_data)
    lake, bags = tmp_path / "lake", tmp_path / "lab"
    bags.mkdir()
    names = {glove: "glove_bag", replay: "replay_bag", calibration: "calib_bag"}
    for source, name in names.items():
        fields = write_bag(source, bags / name, "mcap")
        if fields["kind"] == "robot_replay":
            fields |= {"reference_recording": "glove_bag", "calibration_recording": "calib_bag"}
        sidecar_path(bags / name).write_text(yaml.safe_dump(fields))
    assert find_recordings(bags).recordings == [bags / n for n in sorted(names.values())]
    for source, name in names.items():
        original, bag = ingest_file(source, lake), ingest_file(bags / name, lake)
        assert bag.status == "ingested", bag.reason
        _same_landing(lake, original.recording_id, bag.recording_id, original.kind)
    rows = [r for r in recording_rows(lake).to_pylist() if Path(r["path"]).parent == bags]
    _, links, problems = link_replays(rows)
    assert not problems and len(links) == 1
    assert links[0].reference is not None and links[0].reference["file_name"] == "glove_bag"


def test_a_rosbag2_sqlite3_folder_imports_with_its_session_in_custom_data(smoke_data: Path, tmp_path: Path) -> None:
    glove = sorted((smoke_data / "recordings").glob("rotate_*_glove.mcap"))[0]
    lake = tmp_path / "lake"
    fields = write_bag(glove, tmp_path / "bag", "sqlite3", custom_data={"kind": "glove_session"})
    assert sorted(p.suffix for p in (tmp_path / "bag").iterdir()) == [".db3", ".yaml"]
    # the rest of the session on the command line
    session = {k: v for k, v in fields.items() if k != "kind"}
    original, bag = ingest_file(glove, lake), ingest_file(tmp_path / "bag", lake, session)
    assert bag.status == "ingested", bag.reason
    _same_landing(lake, original.recording_id, bag.recording_id, "glove_session")


def test_a_file_stored_out_of_log_time_order_ingests_as_its_ordered_original(smoke_data: Path, tmp_path: Path) -> None:
    glove = sorted((smoke_data / "recordings").glob("wipe_*_glove.mcap"))[0]
    record, messages = _messages(glove)
    random.Random(0).shuffle(messages)
    shuffled = tmp_path / "shuffled.mcap"
    with open(shuffled, "wb") as f:
        writer = Writer(f)
        writer.start("ros2", "touch2robot-test")
        channels: dict[str, int] = {}
        for topic, msgtype, *_ in messages:
            if topic not in channels:
                schema = writer.register_schema(msgtype, "ros2msg", MSG_DEFINITIONS[msgtype].encode())
                channels[topic] = writer.register_channel(topic, "cdr", schema)
        for topic, _, log_time, publish_time, data in messages:
            writer.add_message(channels[topic], log_time, data, publish_time)
        writer.add_metadata(METADATA_NAME, record[METADATA_NAME])
        writer.finish()
    lake = tmp_path / "lake"
    original, other = ingest_file(glove, lake), ingest_file(shuffled, lake)
    assert other.status == "ingested", other.reason
    _same_landing(lake, original.recording_id, other.recording_id, "glove_session")


def test_a_missing_session_field_is_named_with_where_to_give_it(smoke_data: Path, tmp_path: Path) -> None:
    glove = sorted((smoke_data / "recordings").glob("pick_*_glove.mcap"))[0]
    write_bag(glove, tmp_path / "bag", "mcap")
    result = ingest_file(tmp_path / "bag", tmp_path / "lake")
    assert result.status == "quarantined"
    assert "no session metadata 'kind'" in result.reason and "bag.session.yaml" in result.reason
    assert "custom_data in its metadata.yaml" in result.reason and "--session" in result.reason
    sidecar_path(tmp_path / "bag").write_text("kind: glove_session\ntask: pick\n")
    result = ingest_file(tmp_path / "bag", tmp_path / "lake")
    assert result.status == "quarantined" and result.reason.startswith("metadata lacks subject")
    sidecar_path(tmp_path / "bag").write_text("kind: glove_session\ntask: pick\nsubjekt: s01\n")
    result = ingest_file(tmp_path / "bag", tmp_path / "lake")
    assert "sidecar bag.session.yaml: unknown session field 'subjekt'" in result.reason
    # a bad value is refused by the same checks as a record's
    sidecar_path(tmp_path / "bag").write_text("kind: glove_session\ntask: pick\nsubject: ../s01\n")
    assert "metadata 'subject' is '../s01'" in ingest_file(tmp_path / "bag", tmp_path / "lake").reason


def test_a_changed_sidecar_makes_a_new_recording(smoke_data: Path, tmp_path: Path) -> None:
    glove = sorted((smoke_data / "recordings").glob("drawer_*_glove.mcap"))[0]
    fields = write_bag(glove, tmp_path / "bag", "mcap")
    sidecar_path(tmp_path / "bag").write_text(yaml.safe_dump(fields))
    lake = tmp_path / "lake"
    first = ingest_file(tmp_path / "bag", lake)
    assert ingest_file(tmp_path / "bag", lake).status == "unchanged"
    sidecar_path(tmp_path / "bag").write_text(yaml.safe_dump(fields | {"subject": "s42"}))
    second = ingest_file(tmp_path / "bag", lake)
    assert second.status == "ingested" and second.recording_id != first.recording_id
    assert {r["recording_id"]: r["subject"] for r in recording_rows(lake).to_pylist()}[second.recording_id] == "s42"


def test_a_damaged_bag_is_quarantined_and_the_rest_ingested(smoke_data: Path, tmp_path: Path) -> None:
    gloves = sorted((smoke_data / "recordings").glob("*_glove.mcap"))[:2]
    for k, glove in enumerate(gloves):
        fields = write_bag(glove, tmp_path / f"bag{k}", "mcap")
        sidecar_path(tmp_path / f"bag{k}").write_text(yaml.safe_dump(fields))
    (storage,) = (tmp_path / "bag0").glob("*.mcap")
    storage.write_bytes(storage.read_bytes()[: storage.stat().st_size // 2])
    results = [ingest_file(p, tmp_path / "lake") for p in find_recordings(tmp_path).recordings]
    assert [r.status for r in results] == ["quarantined", "ingested"]
    assert "rosbag2 folder cannot be read" in results[0].reason


@pytest.mark.parametrize("pair", ["task", "=pick", "colour=red"])
def test_a_bad_session_option_is_refused_before_any_compute(pair: str, tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from app.cli import app

    data = tmp_path / "data"
    result = CliRunner().invoke(app, ["ingest", "--data", str(data), "--session", pair])
    assert result.exit_code == 2, result.output
    assert "--session" in result.output
    assert not data.exists()


@pytest.mark.slow
def test_the_ingest_flow_takes_a_labs_bags_with_the_command_lines_session_fields(
    replay_data: Path, tmp_path: Path
) -> None:
    """The ingest flow over a folder of rosbag2 recordings: the subject given once for all (the command's
    ``--session``), the rest in sidecars; the replay's measured contacts are extracted against its calibration."""
    from conftest import run_script_for_result

    glove, replay, calibration = _replay_trio(replay_data)
    bags = tmp_path / "lab"
    bags.mkdir()
    for source, name in {glove: "glove_bag", replay: "replay_bag", calibration: "calib_bag"}.items():
        fields = write_bag(source, bags / name, "mcap")
        fields.pop("subject", None)
        if fields["kind"] == "robot_replay":
            fields |= {"reference_recording": "glove_bag", "calibration_recording": "calib_bag"}
        sidecar_path(bags / name).write_text(yaml.safe_dump(fields))
    subject = read_recording(glove).metadata["subject"]
    data = tmp_path / "data"
    script = (
        "from flows.ingest import ingest; import json; "
        f"print('RESULT', json.dumps(ingest(profile='smoke', data={str(data)!r}, folder={str(bags)!r}, "
        f"session={{'subject': {subject!r}}})))"
    )
    result, output = run_script_for_result(["-c", script], data)
    assert (result["ingested"], result["quarantined"]) == (3, 0), output[-3000:]
    from touch2robot import catalog
    from touch2robot.settings import DataLayout

    rows = catalog.query(
        DataLayout(data), "SELECT source, count(*) AS n FROM contacts GROUP BY source ORDER BY source"
    ).to_pylist()
    assert [r["source"] for r in rows] == ["human", "real"] and all(r["n"] > 0 for r in rows)
