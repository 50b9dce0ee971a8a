"""Flow `replay` (real Prefect, MuJoCo and ingest on tiny data): each method's trajectory executed on the
hardware twin, written and ingested as the rig's recordings; a method with nothing to replay is a row
with the reason, in the table, the artefact and the log; a re-run is served from the cache."""

from __future__ import annotations

import shutil
from pathlib import Path

import duckdb
import pytest
from conftest import rollouts_following

from touch2robot import datasets
from touch2robot.settings import DataLayout


@pytest.fixture(scope="module")
def replayed(demo_lake: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[DataLayout, dict]:
    from flows.replay import replay

    root = tmp_path_factory.mktemp("replay-flow") / "data"
    shutil.copytree(demo_lake, root)
    layout = DataLayout(root)
    pick = next(g for g in datasets.glove_sessions(layout.lake) if g["task"] == "pick")
    for method, origin in (("contrack", "teacher"), ("dex-retargeting", "kinematic"), ("touch2robot", "student")):
        rows = rollouts_following("pick", method, origin, pick["recording_id"])
        datasets.ROLLOUTS.write(layout.lake, datasets.rollouts_key(origin, "pick", 0), rows, method=method)
    return layout, replay(profile="smoke", data=str(root), tasks=["pick", "wipe"])


def _sql(layout: DataLayout, query: str) -> list[tuple]:
    con = duckdb.connect(str(layout.catalog), read_only=True)
    try:
        return con.execute(query).fetchall()
    finally:
        con.close()


def test_each_method_is_replayed_and_ingested_as_the_rigs_recordings(replayed: tuple[DataLayout, dict]) -> None:
    layout, result = replayed
    assert result["replayed"] == 3 and result["failed"] == 0
    for method in ("contrack", "dex-retargeting", "touch2robot"):
        assert (layout.recordings / f"pick_s01_d01_{method}_seed0_replay.mcap").is_file()
        assert (layout.recordings / f"pick_s01_d01_{method}_seed0_calib.mcap").is_file()
    rows = _sql(
        layout,
        "SELECT method, trajectory FROM recordings WHERE kind = 'robot_replay' AND status = 'ingested' ORDER BY 1",
    )
    assert rows == [
        ("contrack", "teacher-contrack-pick-000"),
        ("dex-retargeting", "kinematic-dex-retargeting-pick-000"),
        ("touch2robot", "student-touch2robot-pick-000"),
    ]
    (real,) = _sql(layout, "SELECT count(DISTINCT sequence_id) FROM contacts WHERE source = 'real'")[0]
    assert real == 3
    # the sweep seed travels from the replay's metadata to its recording row and its measured contacts
    assert _sql(layout, "SELECT DISTINCT seed FROM recordings WHERE kind = 'robot_replay'") == [(0,)]
    assert _sql(layout, "SELECT DISTINCT seed FROM contacts WHERE source = 'real'") == [(0,)]
    assert _sql(layout, "SELECT count(*) FROM contacts WHERE source = 'human' AND seed IS NOT NULL") == [(0,)]


def test_what_has_no_trajectory_is_skipped_with_the_reason(replayed: tuple[DataLayout, dict]) -> None:
    layout, result = replayed
    rows = _sql(layout, "SELECT task, method, status, reason FROM replays WHERE status <> 'replayed' ORDER BY 1, 2")
    assert [(t, m, s) for t, m, s, _ in rows] == [
        ("pick", "dexmachina", "skipped"),
        ("wipe", "contrack", "skipped"),
        ("wipe", "dex-retargeting", "skipped"),
        ("wipe", "dexmachina", "skipped"),
        ("wipe", "touch2robot", "skipped"),
    ]
    assert rows[0][3] == "no teacher rollouts of dexmachina on pick (teacher-pick-seed0.parquet)"
    by = {(s["task"], s["method"]): s for s in result["by_task_method"]}
    assert by[("pick", "dexmachina")]["reasons"] == rows[0][3] and by[("pick", "contrack")]["replayed"] == 1
    replayed_rows = _sql(layout, "SELECT peak_force, perturbation FROM replays WHERE status = 'replayed'")
    assert len(replayed_rows) == 3 and all(len(p) == 8 and perturbation for p, perturbation in replayed_rows)


def test_a_rerun_is_served_from_the_cache(replayed: tuple[DataLayout, dict]) -> None:
    from flows.replay import replay

    layout, first = replayed
    files = sorted([*layout.recordings.glob("*_replay.mcap"), *(layout.lake / "recordings").glob("*.parquet")])
    stamps = [p.stat().st_mtime_ns for p in files]
    again = replay(profile="smoke", data=str(layout.root), tasks=["pick", "wipe"])
    assert [p.stat().st_mtime_ns for p in files] == stamps  # nothing re-executed, rewritten or re-ingested
    assert again["by_task_method"] == first["by_task_method"]


def test_recordings_unchanged_since_the_runs_ingest_are_not_ingested_again(replayed: tuple[DataLayout, dict]) -> None:
    """The pipeline hands the replay stage the folder state its ingest found: a replay that wrote nothing (all
    cached) leaves the folder so, and the stage's ingest is skipped; a folder changed since is ingested."""
    from flows.replay import replay
    from touch2robot.ingest.scan import folder_state

    layout, first = replayed
    state = folder_state(layout.recordings)
    again = replay(profile="smoke", data=str(layout.root), tasks=["pick", "wipe"], ingested_state=state)
    assert again["ingest"] == [] and again["by_task_method"] == first["by_task_method"]
    assert _sql(layout, "SELECT count(*) FROM replays WHERE status = 'replayed'") == [(3,)]
    other = replay(profile="smoke", data=str(layout.root), tasks=["pick", "wipe"], ingested_state="0" * 64)
    assert [r["files"] for r in other["ingest"]] == [len(list(layout.recordings.glob("*.mcap")))]


def test_a_second_seed_adds_its_own_replays_and_leaves_the_first_seeds_cached(
    replayed: tuple[DataLayout, dict],
) -> None:
    """Seed 1 has no rollouts yet: every one of its cells is skipped with the reason, while seed 0's replays are
    served from the cache, untouched; the replays table holds both seeds."""
    from flows.replay import replay

    layout, first = replayed
    files = sorted(layout.recordings.glob("*_replay.mcap"))
    stamps = [p.stat().st_mtime_ns for p in files]
    swept = replay(profile="smoke", data=str(layout.root), tasks=["pick", "wipe"], seeds=[0, 1])
    assert [p.stat().st_mtime_ns for p in files] == stamps and sorted(layout.recordings.glob("*_replay.mcap")) == files
    assert swept["replayed"] == first["replayed"]
    rows = _sql(layout, "SELECT seed, status, count(*) FROM replays GROUP BY ALL ORDER BY ALL")
    assert rows == [(0, "replayed", 3), (0, "skipped", 5), (1, "skipped", 8)]
    (reason,) = _sql(layout, "SELECT reason FROM replays WHERE seed = 1 AND task = 'pick' AND method = 'contrack'")[0]
    assert reason == "no teacher rollouts of contrack on pick (teacher-pick-seed1.parquet)"


def test_replays_of_a_session_from_another_folder_are_written_and_ingested_there(
    replay_data: Path, tmp_path: Path
) -> None:
    """A glove session ingested with `ingest --folder` gets its replays beside it, and they are ingested."""
    from flows.ingest import ingest
    from flows.replay import replay

    elsewhere, layout = tmp_path / "rig-sessions", DataLayout(tmp_path / "data")
    elsewhere.mkdir()
    shutil.copy(next((replay_data / "recordings").glob("pick_*_glove.mcap")), elsewhere)
    ingest(profile="smoke", data=str(layout.root), folder=str(elsewhere))
    (glove,) = datasets.glove_sessions(layout.lake)
    rows = rollouts_following("pick", "contrack", "teacher", glove["recording_id"], n=1)
    datasets.ROLLOUTS.write(layout.lake, datasets.rollouts_key("teacher", "pick", 0), rows, method="contrack")
    result = replay(profile="smoke", data=str(layout.root), tasks=["pick"], methods=["contrack"])
    assert result["replayed"] == 1
    (path,) = _sql(layout, "SELECT path FROM recordings WHERE kind = 'robot_replay'")[0]
    assert Path(path).parent == elsewhere.resolve()
    assert _sql(layout, "SELECT count(*) FROM contacts WHERE source = 'real'")[0][0] > 0


def test_a_replay_that_loses_physics_is_a_failed_row_and_the_stage_goes_on(demo_lake: Path, tmp_path: Path) -> None:
    """Commands that turn NaN from the third step lose the twin's physics: that replay is a ``failed`` row with
    the reason (table and result), leaves no files, and the other methods' replays of the task are written."""
    import numpy as np
    import pyarrow as pa

    from flows.replay import replay

    root = tmp_path / "data"
    shutil.copytree(demo_lake, root)
    layout = DataLayout(root)
    pick = next(g for g in datasets.glove_sessions(layout.lake) if g["task"] == "pick")
    for method in ("contrack", "dexmachina"):
        rows = rollouts_following("pick", method, "teacher", pick["recording_id"])
        if method == "contrack":
            targets = np.array(rows["joint_target"].to_pylist())
            targets[2:] = np.nan
            column = rows.schema.get_field_index("joint_target")
            rows = rows.set_column(
                column, rows.schema.field(column), pa.array(targets.tolist(), rows["joint_target"].type)
            )
        datasets.ROLLOUTS.write(layout.lake, datasets.rollouts_key("teacher", "pick", 0), rows, method=method)
    result = replay(profile="smoke", data=str(root), tasks=["pick"], methods=["contrack", "dexmachina"])
    assert (result["replayed"], result["failed"]) == (1, 1)
    (status, reason, replay_file) = _sql(
        layout, "SELECT status, reason, replay_file FROM replays WHERE method = 'contrack'"
    )[0]
    assert status == "failed" and reason.startswith("lost physics: pick: env 0 at t = ") and replay_file is None
    assert not list(layout.recordings.glob("*_contrack_*.mcap"))
    assert (layout.recordings / "pick_s01_d01_dexmachina_seed0_replay.mcap").is_file()
