"""The batched environment: the same state gives the same next state whatever N, seeded
determinism, per-copy resets, region forces every step, success wiring, and rsl-rl's VecEnv contract."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from touch2robot.sim.config import SimConfig
from touch2robot.sim.env import BatchEnv
from touch2robot.sim.rsl_env import JointTracking, episode_steps, make_vec_env
from touch2robot.sim.scene import build_scene

CLOSE = np.array([1.0, 0.0, 1.0, 0.8] * 3 + [1.0, 1.0, 0.6, 0.4])


def _env(task: str = "pick", n: int = 4, threads: int = 2) -> BatchEnv:
    cfg = SimConfig(n_envs=n, threads=threads)
    return BatchEnv(build_scene(task, cfg), cfg)


def _grasp(env: BatchEnv, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Hand closing while the wrist lowers onto the object (contacts from about step 10)."""
    home = env.home_state[env.layout.qpos][env.scene.hand_qpos]
    targets = home + min(max(k - 5, 0) / 10, 1.0) * CLOSE
    wrist = env.scene.home_wrist_pos - [0.0, 0.0, 0.004 * min(k, 12)]
    return np.tile(targets, (env.n, 1)), np.tile(wrist, (env.n, 1))


def test_same_state_same_next_state_whatever_n_and_threads() -> None:
    rng = np.random.default_rng(7)
    small, large = _env(n=2, threads=1), _env(n=9, threads=2)
    for k in range(20):
        t_small, w_small = _grasp(small, k)
        t_large, w_large = _grasp(large, k)
        t_large += rng.normal(0.0, 0.3, t_large.shape) * (np.arange(9) != 6)[:, None]  # other copies differ
        t_large[6], w_large[6] = t_small[1], w_small[1]
        small.step(t_small, w_small)
        large.step(t_large, w_large)
        if k == 10:  # a reset elsewhere in the batch does not disturb copy 6
            large.reset(np.array([0, 8]))
    np.testing.assert_array_equal(small.state[1], large.state[6])
    np.testing.assert_array_equal(small.sensordata[1], large.sensordata[6])
    assert small.region_contact[1].any()  # the comparison covered contact dynamics


def test_vec_env_is_deterministic_given_a_seed() -> None:
    def run(seed: int) -> np.ndarray:
        venv = make_vec_env("rotate", JointTracking(), SimConfig(n_envs=3, seed=seed), max_episode_length=6)
        gen = torch.Generator().manual_seed(0)
        obs = []
        for _ in range(10):  # spans a reset (episode of 6 steps)
            o, *_ = venv.step(torch.rand(3, 16, generator=gen) * 2 - 1)
            obs.append(o["actor"].numpy())
        return np.stack(obs)

    a, b, c = run(1), run(1), run(2)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_reset_touches_only_the_given_copies_and_restores_sensors() -> None:
    env = _env(n=4)
    for k in range(20):
        env.step(*_grasp(env, k))
    assert env.region_contact.any()
    before, sensors_before = env.state.copy(), env.sensordata.copy()
    env.reset(np.array([1, 3]))
    np.testing.assert_array_equal(env.state[[0, 2]], before[[0, 2]])
    np.testing.assert_array_equal(env.sensordata[[0, 2]], sensors_before[[0, 2]])
    np.testing.assert_array_equal(env.state[[1, 3]], np.tile(env.home_state, (2, 1)))
    assert not env.region_contact[[1, 3]].any()
    np.testing.assert_allclose(env.fingertip_pos[1], env.fingertip_pos[3])
    assert list(env.time_step) == [20, 0, 20, 0]


def test_region_forces_every_control_step_while_grasping() -> None:
    env = _env(n=3)
    seen = np.zeros((3, 8), dtype=bool)
    for k in range(25):
        env.step(*_grasp(env, k))
        force, contact = env.region_force, env.region_contact
        assert force.shape == (3, 8) and contact.dtype == bool
        assert (force >= 0).all()
        np.testing.assert_array_equal(contact, force > env.cfg.contact_threshold_n)
        seen |= contact
    assert seen[:, :4].any(axis=1).all()  # fingertips touched the box in every copy
    tips = env.fingertip_pos
    assert tips.shape == (3, 4, 3)
    assert np.linalg.norm(tips - env.object_pos[:, None, :], axis=2).min() < 0.06


def test_drawer_success_through_the_env() -> None:
    env = _env("drawer", n=2)
    qpos = np.tile(env.home_state[env.layout.qpos], (2, 1))
    qpos[:, env.scene.object_qpos] = [0.15, 0.05]
    env.reset(np.arange(2), qpos=qpos)
    env.step(env.joint_targets)
    assert env.success.tolist() == [True, False]
    np.testing.assert_allclose(env.object_pos[0] - env.scene.spec.object.init_pos, [-0.15, 0.0, 0.0], atol=2e-3)
    assert env.object_points().shape == (2, env.scene.point_cloud.shape[0], 3)


def test_rsl_vec_env_contract() -> None:
    cfg = SimConfig(n_envs=5, episode_s=0.25)
    venv = make_vec_env("wipe", JointTracking(), cfg)
    assert venv.num_envs == 5 and venv.num_actions == 16 and venv.device == "cpu"
    assert venv.max_episode_length == episode_steps(venv.env) == 5
    assert isinstance(venv.cfg, dict) and venv.cfg["task"] == "wipe"
    obs = venv.get_observations()
    assert isinstance(obs, TensorDict) and set(obs.keys()) == {"actor", "critic"}
    assert obs["actor"].shape == (5, 64) and obs["actor"].dtype == torch.float32
    for _ in range(5):
        obs, rew, dones, extras = venv.step(torch.zeros(5, 16))
        assert rew.shape == (5,) and dones.shape == (5,)
        assert set(extras) == {"time_outs", "log"}
        assert "reward/tracking" in extras["log"] and not any(key.startswith("/") for key in extras["log"])
    assert dones.all() and extras["time_outs"].all()  # fifth step = episode length: truncated
    assert "task/success" in extras["log"]
    assert (venv.episode_length_buf == 0).all() and (venv.env.time_step == 0).all()


def test_config_rejects_inconsistent_rates_and_unknown_fields() -> None:
    with pytest.raises(ValueError, match="control_hz"):
        SimConfig(control_hz=25.0)
    with pytest.raises(ValueError):
        SimConfig(n_env=3)  # type: ignore[call-arg]
    assert SimConfig(control_hz=25.0, substeps=4).control_dt == pytest.approx(0.04)


def test_reset_to_a_given_pose_reads_its_sensors() -> None:
    env = _env(n=2)
    wrist = env.scene.home_wrist_pos - [0.0, 0.0, 0.06]  # low enough that the thumb tip sits in the box
    qpos = np.tile(env.home_state[env.layout.qpos], (1, 1))
    env.reset(np.array([1]), qpos=qpos, wrist_pos=wrist[None])
    np.testing.assert_allclose(env.wrist_pose[1, :3], wrist)
    np.testing.assert_array_equal(env.sensordata[0], env.home_sensordata)
    assert env.region_contact[1, 0] and not env.region_contact[0].any()


def test_wrist_follows_a_world_pose_trajectory() -> None:
    from touch2robot.geometry import quat_from_axis_angle, quat_mul, twist_angle

    env = _env("pick", n=1)
    start, quat0 = env.scene.home_wrist_pos, env.scene.home_wrist_quat
    errors, angle_errors = [], []
    for k in range(40):  # a 4 cm circle in 2 s while turning 60 degrees about the vertical
        t = (k + 1) * env.cfg.control_dt
        pos = start + 0.04 * np.array([np.cos(np.pi * t) - 1.0, np.sin(np.pi * t), 0.0]) + [0.0, 0.0, 0.02]
        yaw = np.pi / 3 * t / 2.0
        quat = quat_mul(quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), yaw), quat0)
        env.step(env.joint_targets, pos[None], quat[None])
        errors.append(np.linalg.norm(env.wrist_pose[0, :3] - pos))
        angle_errors.append(abs(twist_angle(env.wrist_pose[0, 3:], quat0, np.array([0.0, 0.0, 1.0])) - yaw))
    print(
        f"wrist tracking error while moving: {max(errors[5:]) * 1e3:.1f} mm, {np.degrees(max(angle_errors[5:])):.2f} "
        "deg"
    )
    assert max(errors[5:]) < 0.01 and max(angle_errors[5:]) < np.radians(3)  # within 1 cm / 3 deg while moving
