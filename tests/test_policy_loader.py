"""The fast policy loader (``touch2robot.policy.loader.FrameLoader``): LeRobot's own batches, in
LeRobot's order, from a frame cache that is never stale and never half-written; a training fed
by it ends where one fed by LeRobot's DataLoader ends."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import scripted_rollout_rows

from touch2robot import lake as lake_io
from touch2robot.config import load_profile
from touch2robot.policy.dataset import build_dataset, read_rollouts, sources
from touch2robot.policy.loader import CACHE_DIR, FrameLoader, dataset_digest
from touch2robot.policy.train import pipeline_config, train
from touch2robot.sim.config import SimConfig
from touch2robot.sim.scene import build_scene

# short episodes (10 frames) against the smoke profile's windows (2 observations, 24 actions):
# most samples' windows cross an episode's edge
CONFIG = load_profile("smoke").policy


def _build(base: Path, seed: int) -> tuple[Path, str]:
    lake = base / f"lake-{seed}"
    lake_io.write_rows(
        lake,
        "rollouts",
        "teacher-pick-seed0",
        scripted_rollout_rows("pick", "touch2robot", 3, 10, seed=seed),
        partition={"method": "touch2robot"},
    )
    sim = SimConfig(threads=1)
    rollouts = read_rollouts(sources(lake)[0].path)
    summary = build_dataset(base / f"ds-{seed}", "pick", "touch2robot", rollouts, build_scene("pick", sim), sim, CONFIG)
    return Path(summary.root), summary.repo_id


@pytest.fixture(scope="module")
def datasets(tmp_path_factory: pytest.TempPathFactory) -> list[tuple[Path, str]]:
    base = tmp_path_factory.mktemp("loader")
    return [_build(base, seed) for seed in (0, 1)]


def _lerobot(root: Path, repo_id: str, out: Path):
    from lerobot.datasets.factory import make_dataset

    return make_dataset(pipeline_config(root, repo_id, CONFIG, out))


def _sampler(dataset, seed: int = CONFIG.seed):
    from lerobot.datasets import EpisodeAwareSampler

    episodes = dataset.meta.episodes
    return EpisodeAwareSampler(
        episodes["dataset_from_index"],
        episodes["dataset_to_index"],
        drop_n_last_frames=CONFIG.horizon - CONFIG.n_action_steps - CONFIG.n_obs_steps + 1,
        shuffle=True,
        seed=seed,
    )


def _assert_same(ours: dict, theirs: dict) -> None:
    assert set(ours) == set(theirs)
    for key, expected in theirs.items():
        got = ours[key]
        if isinstance(expected, torch.Tensor):
            assert isinstance(got, torch.Tensor) and got.dtype == expected.dtype, key
            assert got.shape == expected.shape, key
            assert torch.equal(got, expected), key
        else:
            assert got == expected, key


def _lerobot_batch(dataset, indices) -> dict:
    return torch.utils.data.default_collate([dataset[i] for i in indices])


def test_the_loader_yields_lerobots_samples_at_every_index(datasets, tmp_path: Path) -> None:
    root, repo_id = datasets[0]
    dataset = _lerobot(root, repo_id, tmp_path)
    loader = FrameLoader(dataset, _sampler(dataset), CONFIG.batch_size)
    every = list(range(len(dataset)))  # episode starts and ends included: windows padded on both sides
    ours = loader.to_device(loader.host_batch(every))
    theirs = _lerobot_batch(dataset, every)
    _assert_same(ours, theirs)
    assert ours["action_is_pad"].any() and ours["observation.state_is_pad"].any()  # edges were crossed
    assert ours["observation.images.cam_left"].shape == (len(every), CONFIG.n_obs_steps, 3, 48, 48)


def test_the_loader_yields_lerobots_batches_in_lerobots_order(datasets, tmp_path: Path) -> None:
    root, repo_id = datasets[0]
    dataset = _lerobot(root, repo_id, tmp_path)
    ours = FrameLoader(dataset, _sampler(dataset), CONFIG.batch_size)
    theirs = torch.utils.data.DataLoader(dataset, batch_size=CONFIG.batch_size, sampler=_sampler(dataset))
    for _ in range(2):  # each epoch its own permutation
        mine, lerobots = list(ours), list(theirs)
        assert len(mine) == len(lerobots) == len(ours)
        for a, b in zip(mine, lerobots, strict=True):
            _assert_same(a, b)


def test_a_rebuilt_dataset_is_not_served_from_a_stale_frame_cache(datasets, tmp_path: Path) -> None:
    (first, first_id), (second, second_id) = datasets
    primed = _lerobot(first, first_id, tmp_path / "a")
    FrameLoader(primed, _sampler(primed), 4)
    assert dataset_digest(first) != dataset_digest(second)
    # the second dataset's folder holding the first one's cache (same episode and frame counts)
    shutil.rmtree(second / CACHE_DIR, ignore_errors=True)
    shutil.copytree(first / CACHE_DIR, second / CACHE_DIR)
    stale = next((second / CACHE_DIR).iterdir())
    shutil.move(stale, stale.with_name("0" * 16))  # even under another name
    dataset = _lerobot(second, second_id, tmp_path / "b")
    loader = FrameLoader(dataset, _sampler(dataset), 4)
    every = list(range(len(dataset)))
    _assert_same(loader.to_device(loader.host_batch(every)), _lerobot_batch(dataset, every))
    assert [p.name for p in (second / CACHE_DIR).iterdir()] == [dataset_digest(second)]


KILLED_WRITER = """
import sys, time
from pathlib import Path
import touch2robot.policy.loader as loader
decode = loader._decode_png
def slow(data):
    time.sleep(0.2)
    return decode(data)
loader._decode_png = slow
loader.frame_cache(Path(sys.argv[1]), ["observation.images.cam_left"], {"observation.images.cam_left": (3, 48, 48)}, 30)
"""


def test_a_half_written_frame_cache_is_never_used(datasets, tmp_path: Path) -> None:
    root, repo_id = datasets[0]
    shutil.rmtree(root / CACHE_DIR, ignore_errors=True)
    writer = subprocess.Popen([sys.executable, "-c", KILLED_WRITER, str(root)])
    deadline = time.monotonic() + 60
    while not list((root / CACHE_DIR).glob(".*.tmp/*.npy")) and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.3)  # some frames decoded, not all
    writer.send_signal(signal.SIGKILL)
    writer.wait()
    assert [p.name for p in (root / CACHE_DIR).iterdir() if not p.name.startswith(".")] == []
    dataset = _lerobot(root, repo_id, tmp_path)
    loader = FrameLoader(dataset, _sampler(dataset), 4)
    every = list(range(len(dataset)))
    _assert_same(loader.to_device(loader.host_batch(every)), _lerobot_batch(dataset, every))
    assert [p.name for p in (root / CACHE_DIR).iterdir()] == [dataset_digest(root)]  # the leftover removed


def test_a_training_fed_by_the_frame_loader_equals_one_fed_by_lerobots(datasets, tmp_path: Path) -> None:
    from safetensors.torch import load_file

    torch.set_num_threads(1)
    root, repo_id = datasets[0]
    weights = {}
    for name in ("lerobot", "frames"):
        cfg = CONFIG.model_copy(update={"loader": name, "save_freq": 1000})
        # 12 updates of 8 cross an epoch of 3 x (10 - 7) = 9 samples several times
        result = train(root, repo_id, cfg, tmp_path / name, steps=12)
        weights[name] = load_file(Path(result.policy_dir) / "model.safetensors")
    assert [k for k in weights["lerobot"] if not torch.equal(weights["lerobot"][k], weights["frames"][k])] == []
    assert np.isfinite(float(next(iter(weights["frames"].values())).float().sum()))
