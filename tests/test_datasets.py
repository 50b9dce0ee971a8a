"""The catalog of the data folder (touch2robot.datasets): every id format builds and parses back,
a mistyped id fails naming it, the ids are the lake's documented spellings, and the readiness
queries find what the stages need."""

from __future__ import annotations

import shutil
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from conftest import scripted_rollout_rows

from schemas.tables import SCHEMAS
from touch2robot import datasets as ds
from touch2robot.settings import DataLayout

ROUND_TRIPS = [
    (ds.RECORDING_ID, ds.RecordingKey("0123456789abcdef"), "0123456789abcdef"),
    (ds.ROLLOUTS_ID, ds.RolloutsKey("teacher", "pick", "0"), "teacher-pick-seed0"),
    (ds.ROLLOUTS_ID, ds.RolloutsKey("kinematic", "drawer", "12"), "kinematic-drawer-seed12"),
    (
        ds.ROLLOUT_CONTACTS_ID,
        ds.RolloutContactsKey("kinematic", "dex-retargeting", "0"),
        "kinematic-dex-retargeting-seed0",
    ),
    (ds.ROLLOUT_CONTACTS_ID, ds.RolloutContactsKey("student", "touch2robot", "3"), "student-touch2robot-seed3"),
    # a method whose name looks like a seed still reads back to itself
    (ds.ROLLOUT_CONTACTS_ID, ds.RolloutContactsKey("teacher", "a-seed1", "2"), "teacher-a-seed1-seed2"),
    (ds.TASK_ID, ds.TaskKey("wipe", "1"), "wipe-seed1"),
    (
        ds.METHOD_TASK_ID,
        ds.MethodTaskKey("dex-retargeting", "rotate", "0"),
        "dex-retargeting-rotate-seed0",
    ),
    (ds.TEACHER_RUN_ID, ds.TeacherRunKey("pick", "contrack", "0123456789ab"), "pick-contrack-0123456789ab"),
    (ds.STUDENT_RUN_ID, ds.StudentRunKey("no_tactile", "0123456789ab"), "no_tactile-0123456789ab"),
    (
        ds.POLICY_RUN_ID,
        ds.PolicyRunKey("dex-retargeting", "pick", "2", "0123456789ab"),
        "dex-retargeting-pick-seed2-0123456789ab",
    ),
]


@pytest.mark.parametrize(("fmt", "key", "file_id"), ROUND_TRIPS, ids=[r[2] for r in ROUND_TRIPS])
def test_every_id_format_builds_and_parses_back(fmt: ds.IdFormat, key: tuple, file_id: str) -> None:
    assert fmt.build(key) == file_id
    assert fmt.parse(file_id) == key
    assert type(fmt.parse(file_id)) is fmt.key


@pytest.mark.parametrize(
    ("fmt", "file_id", "message"),
    [
        (
            ds.ROLLOUTS_ID,
            "teacher_pick-seed0",
            r"'teacher_pick-seed0' is not a \{origin\}-\{task\}-seed\{seed\} id \(origin one of",
        ),
        (ds.ROLLOUTS_ID, "replay-pick-seed0", r"'replay-pick-seed0' is not a \{origin\}-\{task\}-seed\{seed\} id"),
        (ds.ROLLOUTS_ID, "teacher-pik-seed0", r"task one of \('pick', 'rotate', 'wipe', 'drawer'\)"),
        # a file from before the sweep seeds: named, with what it should be
        (ds.ROLLOUTS_ID, "teacher-pick", r"'teacher-pick' is not a .*seed a sweep seed"),
        (ds.ROLLOUTS_ID, "teacher-pick-seed01", r"seed a sweep seed \(a whole number >= 0\)"),
        (ds.METHOD_TASK_ID, "touch2robot-seed0", r"'touch2robot-seed0' is not a \{method\}-\{task\}-seed\{seed\} id"),
        (ds.TASK_ID, "Pick-seed0", r"'Pick-seed0' is not a \{task\}-seed\{seed\} id"),
        (ds.TEACHER_RUN_ID, "pick-contrack-xyz", r"config 12 hex digits"),
        (ds.RECORDING_ID, ".hidden", r"'.hidden' is not a \{recording_id\} id"),
        (ds.RECORDING_ID, "a/b", r"'a/b' is not a \{recording_id\} id"),
    ],
)
def test_a_mistyped_id_fails_naming_it(fmt: ds.IdFormat, file_id: str, message: str) -> None:
    with pytest.raises(ds.DatasetIdError, match=message):
        fmt.parse(file_id)


def test_a_mistyped_key_fails_naming_the_table_and_the_field(tmp_path: Path) -> None:
    with pytest.raises(
        ds.DatasetIdError, match=r"lake table 'rollouts': \{origin\}-\{task\}-seed\{seed\}: task 'pik' is not one of"
    ):
        ds.ROLLOUTS.path(tmp_path, ds.rollouts_key("teacher", "pik", 0), method="touch2robot")
    with pytest.raises(ds.DatasetIdError, match=r"origin 'teachers' is not one of"):
        ds.ROLLOUTS_ID.build(ds.rollouts_key("teachers", "pick", 0))
    with pytest.raises(ds.DatasetIdError, match=r"seed '-1' is not a sweep seed"):
        ds.ROLLOUTS_ID.build(ds.rollouts_key("teacher", "pick", -1))
    with pytest.raises(ds.DatasetIdError, match=r"method 'a/b' is not a name"):
        ds.METHOD_TASK_ID.build(ds.MethodTaskKey("a/b", "pick", "0"))
    with pytest.raises(ValueError, match=r"partitioned by \('method',\)"):
        ds.ROLLOUTS.path(tmp_path, ds.rollouts_key("teacher", "pick", 0))


def test_evaluation_ids_join_their_key_columns() -> None:
    fmt = ds.EVALUATION_IDS["contact_metrics"]
    assert fmt.build(("real", "touch2robot")) == "real__touch2robot"
    assert fmt.parse("real__touch2robot") == ("real", "touch2robot")
    unsafe = fmt.build(("sim", "a/b"))
    assert unsafe.startswith("sim__a-b-") and "/" not in unsafe
    with pytest.raises(ds.DatasetIdError, match=r"'real' is not a source__method id"):
        fmt.parse("real")
    with pytest.raises(ds.DatasetIdError, match="has not 2 parts"):
        fmt.build(("real",))
    assert ds.EVALUATION_IDS["user_study"].parse("ratings_SYNTHETIC.csv") == ("ratings_SYNTHETIC.csv",)


def test_every_lake_table_is_in_the_catalog_with_its_schema() -> None:
    assert set(ds.LAKE) == set(SCHEMAS)
    assert all(t.schema is SCHEMAS[name] and t.name == name for name, t in ds.LAKE.items())
    assert ds.CONTACTS.partition_keys == ("source", "task") and ds.ROLLOUTS.partition_keys == ("method",)


def test_lake_paths_are_the_documented_ones(tmp_path: Path) -> None:
    """The spellings schemas/tables.py documents (a refactor must not move a file): every file of a stochastic
    stage names its sweep seed."""
    lake = tmp_path / "lake"
    rollouts = ds.teacher_rollouts(lake, "touch2robot", "pick", 0)
    assert rollouts == lake / "rollouts/method=touch2robot/teacher-pick-seed0.parquet"
    sim = ds.CONTACTS.path(lake, ds.RolloutContactsKey("teacher", "contrack", "1"), task="wipe", source="sim")
    assert sim == lake / "contacts/source=sim/task=wipe/teacher-contrack-seed1.parquet"
    human = ds.human_contacts(lake, {"recording_id": "0123456789abcdef", "task": "pick"})
    assert human == lake / "contacts/source=human/task=pick/0123456789abcdef.parquet"
    key = ds.MethodTaskKey("contrack", "pick", "0")
    assert ds.POLICY_EVAL.path(lake, key) == lake / "policy_eval/contrack-pick-seed0.parquet"
    assert ds.STUDENT_DATASET.path(lake, ds.TaskKey("pick", "2")) == lake / "student_dataset/pick-seed2.parquet"
    layout = DataLayout(tmp_path)
    assert ds.policy_dataset(layout, "contrack", "pick", 1) == tmp_path / "datasets/contrack-pick-seed1"
    assert ds.lerobot_repo_id("contrack", "pick", 1) == "touch2robot/contrack-pick-seed1"
    key = "0123456789abcdef0123"
    assert (
        ds.teacher_checkpoints(layout, "pick", "contrack", key)
        == tmp_path / "checkpoints/teachers/pick-contrack-0123456789ab"
    )
    assert ds.student_checkpoints(layout, "full", key) == tmp_path / "checkpoints/student/full-0123456789ab"
    training = ds.policy_training(layout, "contrack", "pick", 0, key[:12])
    assert training == tmp_path / "policies/contrack-pick-seed0-0123456789ab"


def test_entries_parse_every_file_and_name_a_stray_one(tmp_path: Path) -> None:
    lake = tmp_path / "lake"
    rows = pa.table({"x": [1]})
    for origin, task, method in (("teacher", "pick", "contrack"), ("kinematic", "drawer", "dex-retargeting")):
        path = ds.ROLLOUTS.path(lake, ds.rollouts_key(origin, task, 0), method=method)
        path.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(rows, path)
    found = [(key, partition) for key, partition, _ in ds.ROLLOUTS.entries(lake)]
    assert found == [
        (ds.RolloutsKey("teacher", "pick", "0"), {"method": "contrack"}),
        (ds.RolloutsKey("kinematic", "drawer", "0"), {"method": "dex-retargeting"}),
    ]
    stray = lake / "rollouts" / "method=contrack" / "teacher_pick-seed0.parquet"
    pq.write_table(rows, stray)
    with pytest.raises(
        ds.DatasetIdError,
        match=r"teacher_pick-seed0.parquet: 'teacher_pick-seed0' is not a \{origin\}-\{task\}-seed\{seed\} id",
    ):
        list(ds.ROLLOUTS.entries(lake))
    stray.unlink()
    unpartitioned = lake / "rollouts" / "teacher-pick-seed0.parquet"
    pq.write_table(rows, unpartitioned)
    with pytest.raises(ds.DatasetIdError, match=r"expected lake/rollouts/method=<method>/<id>.parquet"):
        list(ds.ROLLOUTS.entries(lake))


def test_folder_digest_follows_content_not_timestamps(tmp_path: Path) -> None:
    lake = tmp_path / "lake"
    table = ds.LAKE["time_map"]
    rows = pa.table({"recording_id": ["r1"], "t": [0.0], "t_ref": [0.0]})
    path = table.write(lake, ds.RecordingKey("r1"), rows)
    before = ds.folder_digest([table.folder(lake)])
    table.write(lake, ds.RecordingKey("r1"), rows)  # the same rows again: a new file, a new mtime
    assert ds.folder_digest([table.folder(lake)]) == before
    table.write(lake, ds.RecordingKey("r1"), rows.set_column(1, "t", pa.array([1.0])))
    assert ds.folder_digest([table.folder(lake)]) != before
    assert path.is_file()


def test_readiness_finds_the_retargeted_and_taught_demonstrations(demo_lake: Path, tmp_path: Path) -> None:
    root = tmp_path / "data"
    shutil.copytree(demo_lake, root)
    lake = DataLayout(root).lake
    gloves = ds.glove_sessions(lake)
    assert [r["file_name"] for r in gloves] == sorted(r["file_name"] for r in gloves) and gloves
    demos = ds.retargeted_demonstrations(lake)
    assert [d["recording_id"] for d in demos] == [r["recording_id"] for r in gloves]
    assert set(demos[0]) == {"recording_id", "task", "subject"}
    first = demos[0]
    assert ds.retargeted_demonstrations(lake, [first["task"]]) == [first]
    ds.RETARGETED.path(lake, ds.RecordingKey(first["recording_id"])).unlink()
    assert first not in ds.retargeted_demonstrations(lake)
    assert ds.taught_demonstrations(lake, "touch2robot", 0) == []
    second = demos[1]
    ds.ROLLOUTS.write(
        lake,
        ds.rollouts_key("teacher", second["task"], 0),
        scripted_rollout_rows(second["task"], "touch2robot", 1, 3),
        method="touch2robot",
    )
    assert ds.taught_demonstrations(lake, "touch2robot", 0) == [second]
    assert ds.taught_demonstrations(lake, "touch2robot", 1) == []  # another seed's teacher has not run
    assert ds.taught_demonstrations(lake, "contrack", 0) == []


def test_a_file_from_before_the_seeds_is_named_before_a_stage_reads_it_twice(tmp_path: Path) -> None:
    """A contacts file named as before the sweep seeds would be read beside its seed-0 successor: the check the
    evaluation makes first names it and the spelling it should have."""
    lake = tmp_path / "lake"
    rows = pa.table({"x": [1]})
    for name in ("teacher-contrack-seed0", "teacher-contrack"):
        path = lake / "contacts" / "source=sim" / "task=pick" / f"{name}.parquet"
        path.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(rows, path)
    with pytest.raises(ds.DatasetIdError, match=r"teacher-contrack.parquet: .*\{origin\}-\{method\}-seed\{seed\}"):
        ds.check_ids(lake, ("contacts", "rollouts"))
    (lake / "contacts" / "source=sim" / "task=pick" / "teacher-contrack.parquet").unlink()
    ds.check_ids(lake, ("contacts", "rollouts"))
