"""rsl-rl PPO on the batched MuJoCo environment: the return of a joint-tracking objective rises."""

from __future__ import annotations

import numpy as np
import torch
from rsl_rl.runners import OnPolicyRunner

from touch2robot.sim.config import SimConfig
from touch2robot.sim.env import BatchEnv
from touch2robot.sim.rsl_env import JointTracking, RslVecEnv
from touch2robot.sim.scene import build_scene

TRAIN_CFG = {
    "num_steps_per_env": 24,
    "save_interval": 1000,
    "obs_groups": {"actor": ["actor"], "critic": ["critic"]},
    "actor": {"class_name": "MLPModel", "hidden_dims": [64, 64], "activation": "elu", "obs_normalization": True,
              "distribution_cfg": {"class_name": "GaussianDistribution", "init_std": 0.8}},
    "critic": {"class_name": "MLPModel", "hidden_dims": [64, 64], "activation": "elu", "obs_normalization": True},
    "algorithm": {"class_name": "PPO", "num_learning_epochs": 5, "num_mini_batches": 4, "learning_rate": 3e-4, "clip_param": 0.2,
                  "max_grad_norm": 1.0, "gamma": 0.96, "lam": 0.95, "desired_kl": 0.016, "entropy_coef": 0.0, "schedule": "adaptive"},
}  # fmt: skip


def _episode_return(runner: OnPolicyRunner, env: RslVecEnv, steps: int) -> tuple[float, float]:
    """Mean return of the stochastic policy (as in training) and mean tracking term of the deterministic one."""
    obs, total = env.get_observations(), np.zeros(env.num_envs)
    for _ in range(steps):
        with torch.inference_mode():
            obs, r, _, _ = env.step(runner.alg.act(obs))
        total += r.numpy()
    policy = runner.get_inference_policy()
    obs, tracking = env.get_observations(), []
    for _ in range(steps):
        with torch.inference_mode():
            obs, _, _, extras = env.step(policy(obs))
        tracking.append(extras["log"]["reward/tracking"])
    runner.alg.train_mode()
    return float(total.mean()), float(np.mean(tracking))


def test_ppo_return_rises_on_joint_tracking() -> None:
    torch.manual_seed(0)
    cfg = SimConfig(n_envs=48, seed=0)
    env = RslVecEnv(BatchEnv(build_scene("pick", cfg), cfg), JointTracking(), max_episode_length=40)
    runner = OnPolicyRunner(env, {**TRAIN_CFG}, log_dir=None, device="cpu")
    before, tracking_before = _episode_return(runner, env, 40)
    runner.learn(25)
    after, tracking_after = _episode_return(runner, env, 40)
    print(f"return {before:.2f} -> {after:.2f}; deterministic tracking {tracking_before:.3f} -> {tracking_after:.3f}")
    assert after > before + 0.5
    assert tracking_after > tracking_before
