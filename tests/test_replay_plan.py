"""Which trajectories the replay stage executes (touch2robot.twin.plan): every method on the same
demonstrations, one hardware draw per demonstration whatever the method, and a method with nothing to
replay skipped with the reason."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from conftest import rollouts_following

from touch2robot import datasets
from touch2robot.settings import DataLayout
from touch2robot.twin.plan import ReplayConfig, plan_replays


@pytest.fixture(scope="module")
def layout(demo_lake: Path, tmp_path_factory: pytest.TempPathFactory) -> DataLayout:
    root = tmp_path_factory.mktemp("plan") / "data"
    shutil.copytree(demo_lake, root)
    layout = DataLayout(root)
    pick = next(g for g in datasets.glove_sessions(layout.lake) if g["task"] == "pick")
    for method, origin in (("contrack", "teacher"), ("dex-retargeting", "kinematic"), ("touch2robot", "student")):
        datasets.ROLLOUTS.write(
            layout.lake,
            datasets.rollouts_key(origin, "pick", 0),
            rollouts_following("pick", method, origin, pick["recording_id"]),
            method=method,
        )
    return layout


def test_every_method_replays_the_same_demonstration_on_the_same_hardware(layout: DataLayout) -> None:
    jobs, _ = plan_replays(layout.lake, layout.recordings, ReplayConfig(tasks=("pick",), demos_per_task=3), 0)
    assert {j.method for j in jobs} == {"contrack", "dex-retargeting", "touch2robot"}
    assert len({j.reference_id for j in jobs}) == 1
    assert len({j.twin_seed(0) for j in jobs}) == 1  # the draw is the demonstration's, not the method's
    by_method = {j.method: j for j in jobs}
    assert by_method["touch2robot"].origin == "student" and by_method["dex-retargeting"].origin == "kinematic"
    assert by_method["contrack"].trajectory == "teacher-contrack-pick-000"  # the first that follows it
    for job in jobs:
        # next to its glove session, where the ingest links a replay to its reference and calibration
        assert job.replay_path.parent == Path(job.folder) == layout.recordings.resolve()
        assert job.metadata("twin")["reference_recording"] == job.reference_recording
        assert job.metadata("twin")["calibration_recording"] == job.calibration_path.name


def test_a_method_without_trajectories_is_skipped_with_the_reason(layout: DataLayout) -> None:
    config = ReplayConfig(tasks=("pick", "wipe"), methods=("dexmachina", "contrack"))
    jobs, skipped = plan_replays(layout.lake, layout.recordings, config, 0)
    assert [(j.task, j.method) for j in jobs] == [("pick", "contrack")]
    reasons = {(s.task, s.method): s.reason for s in skipped}
    assert set(reasons) == {("pick", "dexmachina"), ("wipe", "dexmachina"), ("wipe", "contrack")}
    assert reasons[("pick", "dexmachina")] == "no teacher rollouts of dexmachina on pick (teacher-pick-seed0.parquet)"


def test_the_teacher_can_stand_for_touch2robot(layout: DataLayout) -> None:
    config = ReplayConfig(tasks=("pick",), methods=("touch2robot",), touch2robot_origin="teacher")
    jobs, skipped = plan_replays(layout.lake, layout.recordings, config, 0)
    assert not jobs and "no teacher rollouts of touch2robot on pick" in skipped[0].reason


def test_an_unknown_method_is_named() -> None:
    with pytest.raises(ValueError, match=r"replay\.methods: unknown method 'telepathy'"):
        plan_replays(Path("/nonexistent"), Path("/nonexistent"), ReplayConfig(methods=("telepathy",)), 0)
