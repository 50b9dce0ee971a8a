"""The lost-physics guard of the batched environment: a scene whose contacts outgrow its arena, a
full constraint buffer, a NaN velocity and MuJoCo's own arena error each stop stepping with an error
naming the task, the copy and its time; a normal grasp raises nothing."""

from __future__ import annotations

import dataclasses
import pickle
import re

import mujoco
import numpy as np
import pytest

from touch2robot.sim import guard
from touch2robot.sim.config import SimConfig
from touch2robot.sim.env import BatchEnv
from touch2robot.sim.guard import LostPhysicsError
from touch2robot.sim.scene import build_scene

CLOSE = np.array([1.0, 0.0, 1.0, 0.8] * 3 + [1.0, 1.0, 0.6, 0.4])


@pytest.fixture(autouse=True)
def _log_in_tmp(tmp_path, monkeypatch) -> None:
    """MuJoCo appends its warnings to MUJOCO_LOG.TXT in the working directory."""
    monkeypatch.chdir(tmp_path)


def _env(n: int, threads: int = 2, memory: str | None = None) -> BatchEnv:
    """A Pick scene, its arena (contacts, constraints and stack of each copy) sized by ``memory``."""
    cfg = SimConfig(n_envs=n, threads=threads)
    scene = build_scene("pick", cfg)
    if memory is not None:
        xml = scene.xml.replace("<option ", f'<size memory="{memory}" />\n  <option ', 1)
        scene = dataclasses.replace(scene, xml=xml, model=mujoco.MjModel.from_xml_string(xml))
    return BatchEnv(scene, cfg)


def _grasp_one(env: BatchEnv, copy: int, steps: int) -> None:
    """Copy ``copy`` lowers onto the box and closes the hand (contacts from about step 10); the others hover."""
    home = env.home_state[env.layout.qpos][env.scene.hand_qpos]
    targets, wrist = np.tile(home, (env.n, 1)), np.tile(env.scene.home_wrist_pos, (env.n, 1))
    for k in range(steps):
        targets[copy] = home + min(max(k - 5, 0) / 10, 1.0) * CLOSE
        wrist[copy] = env.scene.home_wrist_pos - [0.0, 0.0, 0.004 * min(k, 12)]
        env.step(targets, wrist)


def _time_in(error: pytest.ExceptionInfo[LostPhysicsError]) -> float:
    match = re.search(r"at t = ([0-9.]+) s", str(error.value))
    assert match, str(error.value)
    return float(match.group(1))


def test_contacts_outgrowing_the_arena_raise_naming_the_copy() -> None:
    # 100 KiB: the hovering hands use ~42% of it, the grasping one ~75% once it touches the box
    env = _env(n=3, memory="100K")
    with pytest.raises(LostPhysicsError, match=r"pick: env 1 at t = .*arena use .* raise <size memory>") as error:
        _grasp_one(env, copy=1, steps=30)
    assert error.value.env == 1 and error.value.task == "pick" and env.lost_physics == 1
    assert error.value.time_s is not None and _time_in(error) == pytest.approx(error.value.time_s, abs=0.005)
    assert 0.3 < error.value.time_s <= 1.5
    # the failed step was not kept: every copy's clock still reads its last good step
    np.testing.assert_allclose(env.state[:, 0], env.time_step * env.cfg.control_dt)
    assert env.time_step[1] * env.cfg.control_dt < error.value.time_s
    env.close()


def test_a_full_constraint_buffer_raises_with_the_warning() -> None:
    env = _env(n=2, memory="10K")  # too small for the constraints of any step
    with pytest.raises(
        LostPhysicsError, match=r"pick: env 0 at t = 0.01 s: constraint buffer full \(mjWARN_CNSTRFULL\)"
    ):
        env.step(env.joint_targets)
    env.close()


def test_a_nan_velocity_raises_naming_its_copy() -> None:
    env = _env(n=5)
    for _ in range(3):
        env.step(env.joint_targets)
    env.state[3, env.layout.qvel.start + 2] = np.nan
    with pytest.raises(LostPhysicsError, match=r"pick: env 3 at t = 0.16 s: .*velocity .*mjWARN_BADQVEL"):
        env.step(env.joint_targets)
    env.close()


def test_mujoco_arena_error_on_one_thread_raises_naming_the_copy(monkeypatch) -> None:
    # without the budget, 64 KiB overflows MuJoCo's stack when the hand touches: on one thread a
    # FatalError (in a worker thread MuJoCo would exit the process, which is what the budget prevents)
    monkeypatch.setattr(guard, "ARENA_BUDGET", 1.0)
    env = _env(n=3, threads=1, memory="64K")
    with pytest.raises(LostPhysicsError, match=r"pick: env 2 at t = .*MuJoCo error 'mj_stackAlloc: out of memory"):
        _grasp_one(env, copy=2, steps=30)
    env.close()


def test_a_normal_grasp_raises_nothing() -> None:
    env = _env(n=4)
    _grasp_one(env, copy=0, steps=25)
    assert env.region_contact[0].any() and env.lost_physics == 0
    env.close()


def test_the_error_survives_pickling() -> None:
    error = pickle.loads(pickle.dumps(LostPhysicsError("wipe", 17, 2.35, "contact buffer full")))
    assert str(error) == "wipe: env 17 at t = 2.35 s: contact buffer full"
    assert (error.task, error.env, error.time_s) == ("wipe", 17, 2.35)


def test_the_teacher_task_does_not_retry_lost_physics() -> None:
    from prefect.states import Failed

    from tasks.common import retry_unless_lost_physics

    lost = Failed(data=LostPhysicsError("pick", 0, 0.05, "contact buffer full"))
    assert not retry_unless_lost_physics(None, None, lost)
    assert retry_unless_lost_physics(None, None, Failed(data=OSError("disk full")))
