"""rsl-rl PPO (OnPolicyRunner, tiny networks, few copies) learns on the batched MuJoCo env:
the mean episode return of a joint-trajectory tracking objective rises with training."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
import torch
from rsl_rl.runners import OnPolicyRunner

from touch2robot.sim.config import SimConfig
from touch2robot.sim.rsl_env import JointTracking, RslVecEnv, make_vec_env

EPISODE = 40  # control steps (2 s at 20 Hz)
TRAIN_CFG = {
    "num_steps_per_env": 20,
    "save_interval": 10_000,
    "obs_groups": {"actor": ["actor"], "critic": ["critic"]},
    "actor": {
        "class_name": "MLPModel",
        "hidden_dims": [32, 32],
        "activation": "elu",
        "obs_normalization": True,
        "distribution_cfg": {"class_name": "GaussianDistribution", "init_std": 0.8},
    },
    "critic": {"class_name": "MLPModel", "hidden_dims": [32, 32], "activation": "elu", "obs_normalization": True},
    "algorithm": {
        "class_name": "PPO",
        "num_learning_epochs": 5,
        "num_mini_batches": 4,
        "learning_rate": 1e-3,
        "clip_param": 0.2,
        "max_grad_norm": 1.0,
        "gamma": 0.96,
        "lam": 0.95,
        "desired_kl": 0.016,
        "entropy_coef": 0.0,
        "schedule": "adaptive",
    },
}


def _mean_episode_return(runner: OnPolicyRunner, env: RslVecEnv) -> float:
    """Mean return over one full episode of every copy with the training (stochastic) policy.
    (``alg.act`` only fills the pending transition; nothing reaches the rollout storage.)"""
    env.objective.reset(env.env, np.arange(env.num_envs), env.rng)
    env.episode_length_buf[:] = 0
    obs, total = env.get_observations(), torch.zeros(env.num_envs)
    with torch.inference_mode():
        for _ in range(EPISODE):
            obs, reward, _, _ = env.step(runner.alg.act(obs))
            total += reward
    return float(total.mean())


@pytest.fixture
def one_torch_thread() -> Iterator[None]:
    """One intra-op thread for the test: the networks are tiny, and two OpenMP threads contending
    with the rollout threads and other processes on 2 cores made PPO updates 5-10x slower."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.mark.usefixtures("one_torch_thread")
def test_ppo_mean_return_rises_on_joint_tracking() -> None:
    torch.manual_seed(0)
    env = make_vec_env("pick", JointTracking(), SimConfig(n_envs=32, seed=0), max_episode_length=EPISODE)
    runner = OnPolicyRunner(env, {**TRAIN_CFG}, log_dir=None, device="cpu")
    curve = [_mean_episode_return(runner, env)]
    for _ in range(3):
        runner.learn(8)
        curve.append(_mean_episode_return(runner, env))
    print(f"mean episode return after 0/8/16/24 PPO iterations: {[round(c, 2) for c in curve]}")
    assert curve[-1] > curve[0] + 1.0
