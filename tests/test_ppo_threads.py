"""The teacher training's per-phase torch thread counts: collection on one thread, the PPO update on
``update_threads`` (default: the physics' thread count), and a training's losses repeatable at fixed
counts."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
import torch
from rsl_rl.algorithms import PPO
from tensordict import TensorDict

from touch2robot.sim.config import SimConfig
from touch2robot.sim.rsl_env import JointTracking, make_vec_env
from touch2robot.teachers.config import PPOConfig, TeacherConfig
from touch2robot.teachers.train import WALL_CLOCK_SUFFIX, torch_threads, train, update_threads

# wide enough layers and minibatches (32 x 8 / 2 = 128 rows) that torch splits their work over threads
TINY = TeacherConfig(
    sim=SimConfig(n_envs=32, threads=2),
    ppo=PPOConfig(
        num_steps_per_env=8, max_iterations=2, num_mini_batches=2, num_learning_epochs=2, hidden_dims=(256, 256)
    ),
)


def _with_update_threads(threads: int | None) -> TeacherConfig:
    return TINY.model_copy(update={"ppo": TINY.ppo.model_copy(update={"update_threads": threads})})


def _losses(config: TeacherConfig, run_dir: Path) -> list[dict[str, float]]:
    """Every iteration's logged scalars but the timings, of a fresh training of ``config``."""
    vec_env = make_vec_env("pick", JointTracking(), config.sim, max_episode_length=16)
    logged: list[dict[str, float]] = []
    try:
        train(vec_env, config, run_dir, on_log=lambda step, metrics: logged.append(metrics))
    finally:
        vec_env.env.close()
    untimed = (
        {k: v for k, v in m.items() if not (k.startswith("Perf/") or k.endswith(WALL_CLOCK_SUFFIX))} for m in logged
    )
    return [m for m in untimed if m]


@pytest.fixture
def restore_torch_threads() -> Iterator[None]:
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


def test_torch_threads_sets_and_restores(restore_torch_threads: None) -> None:
    torch.set_num_threads(1)
    with torch_threads(2):
        assert torch.get_num_threads() == 2
    assert torch.get_num_threads() == 1
    with pytest.raises(RuntimeError), torch_threads(2):
        raise RuntimeError
    assert torch.get_num_threads() == 1


def test_update_threads_default_to_the_physics_threads() -> None:
    assert update_threads(TINY) == 2
    assert update_threads(TINY.model_copy(update={"sim": SimConfig(threads=3)})) == 3
    assert update_threads(_with_update_threads(1)) == 1


def test_collection_runs_on_one_thread_and_the_update_on_update_threads(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, restore_torch_threads: None
) -> None:
    seen: dict[str, set[int]] = {"act": set(), "update": set()}
    act, update = PPO.act, PPO.update

    def counted_act(self: PPO, obs: TensorDict) -> torch.Tensor:
        seen["act"].add(torch.get_num_threads())
        return act(self, obs)

    def counted_update(self: PPO) -> dict[str, float]:
        seen["update"].add(torch.get_num_threads())
        return update(self)

    monkeypatch.setattr(PPO, "act", counted_act)
    monkeypatch.setattr(PPO, "update", counted_update)
    torch.set_num_threads(3)
    _losses(_with_update_threads(2), tmp_path)
    assert seen == {"act": {1}, "update": {2}}
    assert torch.get_num_threads() == 3  # the caller's count, back


@pytest.mark.parametrize("threads", [1, 2])
def test_a_training_is_repeatable_at_fixed_thread_counts(
    tmp_path: Path, restore_torch_threads: None, threads: int
) -> None:
    """Two trainings with the same seed and thread counts log identical losses, bit for bit, whatever
    the caller's own thread count."""
    config = _with_update_threads(threads)
    torch.set_num_threads(1)
    first = _losses(config, tmp_path / "first")
    torch.set_num_threads(2)
    second = _losses(config, tmp_path / "second")
    assert len(first) == TINY.ppo.max_iterations
    assert first == second
