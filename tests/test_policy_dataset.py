"""Robot demonstrations as LeRobot datasets: the best origin per task x method, replay of real
MuJoCo rollouts reproducing their states, the dataset round-tripping through LeRobot's loader and
LeRobot's own training command, clear errors for bad rollouts files, the Wilson interval."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
import torch
from conftest import lerobot_frame, scripted_rollout_rows

from schemas.tables import ROBOT_REGIONS
from touch2robot import lake as lake_io
from touch2robot import scenes
from touch2robot.config import load_profile
from touch2robot.policy.config import VIDEO_BACKEND
from touch2robot.policy.dataset import (
    ACTION_NAMES,
    STATE_NAMES,
    TACTILE_KEY,
    RolloutError,
    build_dataset,
    common_demonstrations,
    read_rollouts,
    sources,
)
from touch2robot.policy.reader import column_views
from touch2robot.policy.train import lerobot_train_args, pipeline_config
from touch2robot.sim.config import SimConfig
from touch2robot.sim.scene import build_scene

CONFIG = load_profile("smoke").policy


@pytest.fixture(scope="module")
def lake(tmp_path_factory: pytest.TempPathFactory) -> Path:
    lake = tmp_path_factory.mktemp("policy") / "lake"
    lake_io.write_rows(
        lake,
        "rollouts",
        "teacher-pick-seed0",
        scripted_rollout_rows("pick", "contrack", 3, 30),
        partition={"method": "contrack"},
    )
    kinematic = scripted_rollout_rows("pick", "contrack", 1, 10, origin="kinematic", seed=1)
    lake_io.write_rows(lake, "rollouts", "kinematic-pick-seed0", kinematic, partition={"method": "contrack"})
    lake_io.write_rows(
        lake,
        "rollouts",
        "kinematic-drawer-seed0",
        scripted_rollout_rows("drawer", "dex-retargeting", 2, 12, origin="kinematic"),
        partition={"method": "dex-retargeting"},
    )
    return lake


@pytest.fixture(scope="module")
def dataset(lake: Path, tmp_path_factory: pytest.TempPathFactory):
    src = next(s for s in sources(lake) if s.task == "pick")
    sim = SimConfig(threads=1)
    rollouts = read_rollouts(src.path)
    root = tmp_path_factory.mktemp("datasets") / "contrack-pick"
    return build_dataset(root, "pick", "contrack", rollouts, build_scene("pick", sim), sim, CONFIG), rollouts


def test_sources_take_the_best_origin_per_task_and_method(lake: Path) -> None:
    found = [(s.task, s.method, s.origin) for s in sources(lake)]
    assert found == [("pick", "contrack", "teacher"), ("drawer", "dex-retargeting", "kinematic")]


def test_origins_narrow_and_order_the_choice(lake: Path) -> None:
    assert [(s.task, s.method) for s in sources(lake, ("teacher",))] == [("pick", "contrack")]
    only_kinematic = {(s.task, s.method, s.origin) for s in sources(lake, ("kinematic",))}
    assert ("drawer", "dex-retargeting", "kinematic") in only_kinematic
    assert all(origin == "kinematic" for _, _, origin in only_kinematic)
    with pytest.raises(ValueError, match=r"policy\.origins.*'replay'"):
        sources(lake, ("teacher", "replay"))


def test_one_episode_per_demonstration_and_the_same_demonstrations_for_every_method(lake: Path, tmp_path: Path) -> None:
    teacher = lake_io.file_path(lake, "rollouts", "teacher-pick-seed0", {"method": "contrack"})
    kinematic = lake_io.file_path(lake, "rollouts", "kinematic-pick-seed0", {"method": "contrack"})
    assert common_demonstrations([teacher, kinematic]) == ["scripted-000"]
    assert [r.rollout_id[-3:] for r in read_rollouts(teacher, references=["scripted-002", "scripted-000"])] == [
        "002",
        "000",
    ]
    # a deterministic teacher's repeats of one demonstration are one episode: the first rollout
    table = pq.read_table(teacher)
    repeats = tmp_path / "method=contrack" / "teacher-pick.parquet"
    repeats.parent.mkdir()
    pq.write_table(
        table.set_column(
            table.schema.get_field_index("reference_id"), "reference_id", pa.array(["scripted-000"] * len(table))
        ),
        repeats,
    )
    assert [r.rollout_id for r in read_rollouts(repeats, references=["scripted-000"])] == ["teacher-contrack-pick-000"]
    with pytest.raises(
        RolloutError, match=r"teacher-pick-seed0.parquet: no rollout follows demonstration\(s\) \['nobody'\]"
    ):
        read_rollouts(teacher, references=["nobody"])


def test_policy_sources_share_their_demonstrations_per_task(tmp_path: Path) -> None:
    from tasks.policy import rollout_sources
    from touch2robot.settings import DataLayout

    layout = DataLayout(tmp_path / "data")
    lake_io.write_rows(
        layout.lake,
        "rollouts",
        "teacher-pick-seed0",
        scripted_rollout_rows("pick", "contrack", 3, 4),
        partition={"method": "contrack"},
    )
    lake_io.write_rows(
        layout.lake,
        "rollouts",
        "kinematic-pick-seed0",
        scripted_rollout_rows("pick", "dex-retargeting", 2, 4, origin="kinematic"),
        partition={"method": "dex-retargeting"},
    )
    found = {s["method"]: s["references"] for s in rollout_sources(str(layout.root), CONFIG)}
    assert found == {"contrack": ["scripted-000", "scripted-001"], "dex-retargeting": ["scripted-000", "scripted-001"]}
    alone = rollout_sources(str(layout.root), CONFIG, methods=["contrack"])
    assert [s["references"] for s in alone] == [["scripted-000", "scripted-001", "scripted-002"]]
    every = rollout_sources(str(layout.root), CONFIG.model_copy(update={"same_demonstrations": False}))
    assert all(s["references"] is None for s in every)


def test_dataset_round_trips_through_lerobots_loader(dataset) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    summary, rollouts = dataset
    assert summary.episodes == 3 and summary.frames == 90
    # replay in the same scene reproduces the recorded physics
    assert summary.replay_max_joint_error_rad < 1e-5
    assert summary.render_frames == 2 * 90 and summary.render_fps > 0
    ds = LeRobotDataset(summary.repo_id, root=summary.root, video_backend=VIDEO_BACKEND)
    assert ds.num_episodes == 3 and len(ds) == 90 and ds.fps == 20
    assert ds.meta.features["observation.state"]["names"] == list(STATE_NAMES)
    assert ds.meta.features["action"]["names"] == list(ACTION_NAMES)
    frame = lerobot_frame(ds, 31)  # episode 1, step 1
    assert frame["episode_index"] == 1 and frame["frame_index"] == 1
    assert frame["task"] == scenes.task("pick").instruction
    assert frame["observation.images.cam_left"].shape == (3, CONFIG.image_size, CONFIG.image_size)
    assert frame["observation.images.cam_right"].std() > 0.01  # a rendered scene, not a blank
    r = rollouts[1]
    np.testing.assert_allclose(frame["observation.state"][:16].numpy(), r.joint_position[1], atol=1e-5)
    np.testing.assert_allclose(frame["action"].numpy(), np.concatenate([r.joint_target[1], r.wrist_pose[1]]), atol=1e-6)
    assert frame["observation.environment_state"].shape == (8,)
    forces = torch.stack([lerobot_frame(ds, i)["observation.environment_state"] for i in range(60, 90)])
    assert forces.max() > 0.5  # the scripted grasp touches the box: tactile forces are recorded
    # the named tactile feature, alongside what the policy reads (LeRobot 0.6.1 has no tactile convention)
    assert ds.meta.features[TACTILE_KEY]["names"] == [f"force_{r}" for r in ROBOT_REGIONS]
    tactile = torch.stack([lerobot_frame(ds, i)[TACTILE_KEY] for i in range(60, 90)])
    assert torch.equal(tactile, forces)


def test_column_views_give_lerobots_samples_decoding_only_the_window_images(
    dataset, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import pickle

    import datasets.features.image as hf_image
    from lerobot.datasets.factory import make_dataset
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    summary, _ = dataset
    pipeline = pipeline_config(Path(summary.root), summary.repo_id, CONFIG, tmp_path / "out")
    plain, viewed = make_dataset(pipeline), make_dataset(pipeline)
    assert isinstance(plain, LeRobotDataset) and isinstance(viewed, LeRobotDataset)
    column_views(viewed)
    decodes = []
    real_decode = hf_image.Image.decode_example
    monkeypatch.setattr(
        hf_image.Image, "decode_example", lambda self, *a, **k: decodes.append(1) or real_decode(self, *a, **k)
    )
    counts = {}
    for name, ds in (("plain", plain), ("viewed", viewed)):
        decodes.clear()
        ds[45]
        counts[name] = len(decodes)
    cams = len(CONFIG.cameras)
    assert counts["viewed"] == cams * (1 + CONFIG.n_obs_steps)  # the frame's row, then each camera's window
    assert counts["plain"] > 5 * counts["viewed"]  # LeRobot 0.6.1 decodes both images of every window row
    # identical samples, episode edges (padding) included
    for i in (0, 29, 30, 45, 89):
        a, b = lerobot_frame(plain, i), lerobot_frame(viewed, i)
        assert a.keys() == b.keys()
        for key, value in a.items():
            assert torch.equal(value, b[key]) if isinstance(value, torch.Tensor) else value == b[key], (i, key)
    # DataLoader workers under spawn receive the reader by pickling
    clone = pickle.loads(pickle.dumps(viewed))
    assert type(clone.reader) is type(viewed.reader) and torch.equal(
        lerobot_frame(clone, 45)["action"], lerobot_frame(plain, 45)["action"]
    )


def test_bad_rollouts_file_is_named(tmp_path: Path, lake: Path) -> None:
    src = sources(lake)[0]
    bad = tmp_path / "method=contrack" / "teacher-pick.parquet"
    bad.parent.mkdir()
    table = pq.read_table(src.path)
    pq.write_table(table.drop_columns(["joint_target"]), bad)
    with pytest.raises(RolloutError, match=r"teacher-pick.parquet: missing columns \['joint_target'\]"):
        read_rollouts(bad)
    gap = table.filter(pc.not_equal(table.column("step"), 3))  # pyright: ignore[reportAttributeAccessIssue]
    pq.write_table(gap, bad)
    with pytest.raises(RolloutError, match="expected 0, 1, 2"):
        read_rollouts(bad)


def lerobot_command(name: str, *args: str, cwd: Path) -> subprocess.CompletedProcess:
    """One of LeRobot's console scripts from this venv, offline, its output captured."""
    env = {
        **os.environ,
        "HF_HUB_OFFLINE": "1",
        "HF_DATASETS_OFFLINE": "1",
        "WANDB_MODE": "disabled",
        "OMP_NUM_THREADS": "1",
    }
    cli = Path(sys.executable).with_name(name)
    return subprocess.run([str(cli), *args], env=env, cwd=cwd, capture_output=True, text=True, timeout=300)


@pytest.mark.slow
def test_lerobots_own_training_command_loads_the_dataset(dataset, tmp_path: Path) -> None:
    summary, _ = dataset
    cfg = CONFIG.model_copy(update={"batch_size": 4, "log_freq": 1})
    args = lerobot_train_args(Path(summary.root), summary.repo_id, cfg, tmp_path / "out", steps=2, save=False)
    done = lerobot_command("lerobot-train", *args, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    log = done.stdout + done.stderr
    assert "dataset.num_frames=90" in log and "step:2" in log.replace(" ", "")


def test_lerobots_viewer_saves_an_episode_and_lerobot_info_finds_ffmpeg(dataset, tmp_path: Path) -> None:
    import rerun as rr

    summary, _ = dataset
    viewer = lerobot_command(
        "lerobot-dataset-viz",
        f"--repo-id={summary.repo_id}",
        f"--root={summary.root}",
        "--episode-index=1",
        "--mode=local",
        "--save=1",
        f"--output-dir={tmp_path / 'viz'}",
        "--num-workers=0",
        cwd=tmp_path,
    )
    assert viewer.returncode == 0, viewer.stderr[-3000:]
    saved = list((tmp_path / "viz").glob("*.rrd"))
    assert len(saved) == 1, viewer.stdout[-2000:]
    rows: dict[str, int] = {}
    for chunk in rr.experimental.RrdReader(saved[0]).stream().to_chunks():
        rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    for entity in ("/observation.images.cam_left", "/observation.images.cam_right", "/action", "/state"):
        assert rows.get(entity) == 30, (entity, rows)  # episode 1's 30 frames
    info = lerobot_command("lerobot-info", cwd=tmp_path)
    assert info.returncode == 0, info.stderr[-3000:]
    # "- FFmpeg version: 5.1.9-…", not "N/A": .ci/run installs the system FFmpeg that torchcodec loads
    assert re.search(r"FFmpeg version: \d", info.stdout), info.stdout
