"""Teachers: demonstration references, the shared objective and its method variants, rsl-rl
training that learns and resumes, and rollouts that replay exactly."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch
from mlflow.tracking import MlflowClient

from schemas.tables import unseeded
from tasks import tracking
from touch2robot import lake as lake_io
from touch2robot.ingest import recording_rows
from touch2robot.settings import DataLayout
from touch2robot.sim.config import SimConfig
from touch2robot.sim.env import BatchEnv
from touch2robot.sim.scene import build_scene
from touch2robot.teachers import rollouts as ro
from touch2robot.teachers.config import AssistanceConfig, MethodConfig, PPOConfig, TeacherConfig
from touch2robot.teachers.objective import NUM_ACTIONS, DemoTracking, References, stack_references
from touch2robot.teachers.reference import ReferenceError, load_reference
from touch2robot.teachers.train import (
    WALL_CLOCK_SUFFIX,
    checkpoints,
    load_latest,
    make_teacher_env,
    runner_config,
    torch_threads,
    train,
)

SMALL = TeacherConfig(
    sim=SimConfig(n_envs=16),
    ppo=PPOConfig(num_steps_per_env=32, max_iterations=4, hidden_dims=(64, 64), save_interval=2),
)


def _recordings(root: Path) -> dict[str, dict]:
    return {r["task"]: r for r in recording_rows(DataLayout(root).lake).to_pylist()}


@pytest.fixture(scope="module")
def refs(demo_lake: Path) -> dict[str, References]:
    lake = DataLayout(demo_lake).lake
    return {task: stack_references([load_reference(lake, r)]) for task, r in _recordings(demo_lake).items()}


@pytest.fixture
def one_torch_thread() -> Iterator[None]:
    with torch_threads(1):
        yield


# ---------------------------------------------------------------- references
def test_reference_is_on_the_control_grid(refs: dict[str, References]) -> None:
    for task, r in refs.items():
        t = r.t_ref[0, : r.length[0]]
        np.testing.assert_allclose(np.diff(t), 0.05, atol=1e-9, err_msg=task)
        assert np.isfinite(r.joints).all() and np.isfinite(r.object_pos).all()
        np.testing.assert_allclose(np.linalg.norm(r.object_quat, axis=-1), 1.0, atol=1e-9)
    assert refs["drawer"].opening.max() > 0.05  # the demonstrator opens the drawer
    assert refs["pick"].object_pos[0, :, 2].max() > 0.08  # and lifts the box


@pytest.mark.parametrize("task", ["pick", "rotate", "wipe", "drawer"])
def test_geometric_contacts_agree_with_the_glove(refs: dict[str, References], task: str) -> None:
    """ConTrack's geometry-only contact references find the contacts the glove reports, and their
    points lie on the surface. They are a proxy: near the object is not pressing on it (the
    thenar segment passes within 5 mm of the box in pick and rotate, and in drawer the thumb and
    middle fingertips hover within 5 mm of the bar they hook round, where the glove reads nothing),
    which is the gap tactile references close; so they find the glove's contacts but add some."""
    r = refs[task]
    geo, pref = r.geo_contact[0], r.preference[0]
    assert pref.sum() > 0
    assert np.sum(geo & pref) / np.sum(pref) > 0.9
    from touch2robot import scenes
    from touch2robot.geometry import body_sdf

    points = r.geo_point[0][geo]
    assert np.abs(body_sdf(scenes.get(task).object.geoms, points)).max() < 1e-3


def test_missing_retargeting_is_named(demo_lake: Path, tmp_path: Path) -> None:
    root = tmp_path / "data"
    shutil.copytree(demo_lake, root)
    rec = _recordings(root)["pick"]
    lake_io.file_path(DataLayout(root).lake, "retargeted", rec["recording_id"]).unlink()
    with pytest.raises(ReferenceError, match=f"{rec['recording_id']}.*retargeted"):
        load_reference(DataLayout(root).lake, rec)


# ---------------------------------------------------------------- objective
def _env(task: str, n: int = 4) -> BatchEnv:
    return BatchEnv(build_scene(task, SMALL.sim), SMALL.sim, n)


def test_methods_share_observations_and_differ_in_their_contact_term(refs: dict[str, References]) -> None:
    seen = {}
    for method in ("touch2robot", "contrack", "dexmachina"):
        env = _env("rotate")
        objective = DemoTracking(refs["rotate"], SMALL, method)
        objective.reset(env, np.arange(env.n), np.random.default_rng(0))
        env.step(*objective.command(env, np.zeros((env.n, NUM_ACTIONS))))
        _, terms = objective.reward(env, np.zeros((env.n, NUM_ACTIONS)))
        seen[method] = (set(terms), objective.observe(env)["actor"].shape)
        env.close()
    assert "tactile" in seen["touch2robot"][0] and "contact" not in seen["touch2robot"][0]
    assert "contact" in seen["contrack"][0] and "tactile" not in seen["contrack"][0]
    assert "contact" in seen["dexmachina"][0]
    assert len({shape for _, shape in seen.values()}) == 1


def _tracking_error(refs: References, config: TeacherConfig, method: str, gain: float) -> float:
    env = _env("pick", 1)
    objective = DemoTracking(refs, config, method)
    objective.assist_gain = gain
    objective.reset(env, np.arange(1), np.random.default_rng(0))
    errors = []
    for _ in range(int(refs.length[0]) - 1):
        env.step(*objective.command(env, np.zeros((1, NUM_ACTIONS))))
        errors.append(np.linalg.norm(env.object_pos - objective._ref("object_pos", env), axis=1)[0])
    env.close()
    return float(np.mean(errors))


def test_virtual_object_assistance_pulls_the_object_along_its_reference(refs: dict[str, References]) -> None:
    """With the kinematic hand alone the box is dropped; DexMachina's assistance at full gain keeps
    it on the reference trajectory."""
    unassisted = _tracking_error(refs["pick"], SMALL, "dexmachina", 0.0)
    assisted = _tracking_error(refs["pick"], SMALL, "dexmachina", 1.0)
    assert assisted < 0.5 * unassisted, (assisted, unassisted)
    assert assisted < 0.015


def test_assistance_gain_decays_with_task_reward_until_off(refs: dict[str, References]) -> None:
    config = SMALL.model_copy(
        update={
            "variants": {
                **SMALL.variants,
                "dexmachina": MethodConfig(
                    assistance=AssistanceConfig(enabled=True, window_episodes=4, decay=0.5, min_gain=0.2)
                ),
            }
        }
    )
    env = _env("pick", 4)
    objective = DemoTracking(refs["pick"], config, "dexmachina")
    objective.reset(env, np.arange(4), np.random.default_rng(0))
    env.time_step[:] = refs["pick"].length[0] - 1
    objective.task_return[:] = 0.1 * env.time_step  # poor tracking: the help stays
    objective.episode_end(env, np.arange(4))
    assert objective.assist_gain == 1.0
    gains = []
    for _ in range(3):
        objective.task_return[:] = 0.9 * env.time_step  # good tracking: the help decays
        gains.append(objective.episode_end(env, np.arange(4))["dexmachina/assist_gain"])
    assert gains == [0.5, 0.25, 0.0]
    env.close()


def test_contrack_dual_variable_follows_the_task_constraint(refs: dict[str, References]) -> None:
    env = _env("rotate", 1)
    objective = DemoTracking(refs["rotate"], SMALL, "contrack")
    objective.reset(env, np.arange(1), np.random.default_rng(0))
    env.time_step[:] = refs["rotate"].length[0] - 1
    start = objective.dual[0]
    objective.task_return[:] = 0.8 * env.time_step  # sets the best return: constraint met
    objective.episode_end(env, np.arange(1))
    met = objective.dual[0]
    objective.task_return[:] = 0.3 * env.time_step  # far below alpha x best: weight the task more
    objective.episode_end(env, np.arange(1))
    assert met < start < objective.dual[0]
    env.close()


# ---------------------------------------------------------------- rollouts
@pytest.mark.parametrize("task", ["pick", "drawer"])
def test_rollouts_replay_exactly_from_their_first_rows(refs: dict[str, References], task: str) -> None:
    """The rollouts contract: reset to row 0, replay the recorded commands, get the recorded states."""
    env = _env(task, 2)
    rows, contacts = ro.record(
        env, DemoTracking(refs[task], SMALL, "touch2robot"), ro.zero_residual, "dex-retargeting", "kinematic"
    )
    env.close()
    assert rows.schema.equals(unseeded("rollouts"))  # the stage that stores them adds the sweep seed
    assert contacts.num_rows == 8 * rows.num_rows
    first = rows.filter(np.asarray(rows["step"]) == 0)
    replay = _env(task, 2)
    ro.reset_to_rows(replay, np.arange(2), first)
    ids = rows["rollout_id"].to_numpy(zero_copy_only=False)
    targets, wrist, positions = (
        ro.column(rows, "joint_target"),
        ro.column(rows, "wrist_pose"),
        ro.column(rows, "joint_position"),
    )
    per_copy = [np.flatnonzero(ids == rid) for rid in np.unique(ids)]
    for k in range(min(len(p) for p in per_copy)):
        idx = [p[k] for p in per_copy]
        np.testing.assert_allclose(replay.hand_qpos, positions[idx], atol=1e-9)
        replay.step(targets[idx], wrist[idx, :3], wrist[idx, 3:])
    replay.close()


# ---------------------------------------------------------------- training
def _mean_return(vec_env, runner, episodes_steps: int) -> float:
    env, objective = vec_env.env, vec_env.objective
    objective.reset(env, np.arange(env.n), vec_env.rng)
    vec_env.episode_length_buf[:] = 0
    obs, total, done_mask = vec_env.get_observations(), torch.zeros(env.n), torch.zeros(env.n, dtype=torch.bool)
    with torch.inference_mode():
        for _ in range(episodes_steps):
            obs, reward, dones, _ = vec_env.step(runner.alg.act(obs))
            total += reward * ~done_mask
            done_mask |= dones.bool()
    return float(total.mean())


@pytest.mark.usefixtures("one_torch_thread")
def test_teacher_return_rises_with_training(refs: dict[str, References]) -> None:
    """Smoke-sized PPO (Table VII's algorithm and learning rate, small sizes) on the Touch2Robot
    objective for Wipe: the mean first-episode return of the training policy rises (measured
    158.7 -> 189.6 -> 230.5 -> 238.6 after 0/10/20/30 iterations: the residuals learn to keep the
    sponge on its path under the exploration noise)."""
    from rsl_rl.runners import OnPolicyRunner

    torch.manual_seed(0)
    config = SMALL.model_copy(update={"sim": SimConfig(n_envs=32)})
    vec_env = make_teacher_env("wipe", refs["wipe"], config, "touch2robot")
    runner = OnPolicyRunner(vec_env, runner_config(config.ppo), log_dir=None, device="cpu")
    steps = int(refs["wipe"].length[0])
    curve = [_mean_return(vec_env, runner, steps)]
    for _ in range(3):
        runner.learn(10)
        curve.append(_mean_return(vec_env, runner, steps))
    vec_env.env.close()
    print(f"teacher mean episode return after 0/10/20/30 PPO iterations: {[round(c, 1) for c in curve]}")
    assert curve[-1] > 1.2 * curve[0]


def _into(run_id: str, uri: str) -> dict:
    """A training's hooks streaming into the MLflow run ``run_id``."""
    writer = tracking.RunWriter(run_id, uri)
    return {"on_log": writer.log, "on_checkpoint": writer.checkpoint}


@pytest.fixture
def teacher_run(refs: dict[str, References], tmp_path: Path, one_torch_thread: None):
    """A Wipe teacher's env, an MLflow run for it and its checkpoint folder."""
    layout = DataLayout(tmp_path / "data")
    with tracking.stage_run(layout, "teachers", "resume-test") as run:
        run_id = run.info.run_id
    vec_env = make_teacher_env("wipe", refs["wipe"], SMALL, "touch2robot")
    yield vec_env, run_id, tracking.tracking_uri(layout), tmp_path / "teacher"
    vec_env.env.close()


def test_training_resumes_from_its_newest_readable_checkpoint(teacher_run) -> None:
    vec_env, run_id, uri, folder = teacher_run
    first = train(vec_env, SMALL, folder, **_into(run_id, uri))
    assert (first.resumed_from, first.iterations) == (0, 4)
    (folder / "model_9.pt").write_bytes(b"torn by a kill during torch.save")  # newest, unreadable
    longer = SMALL.model_copy(update={"ppo": SMALL.ppo.model_copy(update={"max_iterations": 6})})
    second = train(vec_env, longer, folder, **_into(run_id, uri))
    assert (second.resumed_from, second.iterations) == (4, 6)
    steps = [m.step for m in MlflowClient(uri).get_metric_history(run_id, "Loss/learning_rate")]
    assert steps == list(range(6))  # one continuous curve, no iteration trained twice
    artefacts = {a.path for a in MlflowClient(uri).list_artifacts(run_id, "checkpoints")}
    assert "checkpoints/model_5.pt" in artefacts
    assert [it for it, _ in checkpoints(folder)][:2] == [9, 5]


def test_a_training_stopped_midway_checkpoints_there_and_resumes(teacher_run) -> None:
    """``should_stop`` true after the second of four iterations (no periodic save there: every
    2nd from 0): the call saves that iteration and returns; the next continues at the third."""
    vec_env, run_id, uri, folder = teacher_run
    asked = iter(range(1, 5))
    stopped = train(vec_env, SMALL, folder, **_into(run_id, uri), should_stop=lambda: next(asked) == 2)
    assert (stopped.resumed_from, stopped.iterations, stopped.checkpoint.name) == (0, 2, "model_1.pt")
    assert [it for it, _ in checkpoints(folder)] == [1, 0]
    history = lambda: [m.step for m in MlflowClient(uri).get_metric_history(run_id, "Loss/learning_rate")]  # noqa: E731
    assert history() == [0, 1]
    resumed = train(vec_env, SMALL, folder, **_into(run_id, uri))
    assert (resumed.resumed_from, resumed.iterations) == (2, 4)
    assert history() == [0, 1, 2, 3]
    assert "checkpoints/model_1.pt" in {a.path for a in MlflowClient(uri).list_artifacts(run_id, "checkpoints")}


def test_a_teacher_training_calls_on_log_per_iteration_with_its_metrics(
    refs: dict[str, References], tmp_path: Path, one_torch_thread: None, capsys: pytest.CaptureFixture[str]
) -> None:
    """The library's one training hook: ``on_log(iteration, metrics)`` after every iteration with
    rsl-rl's scalars of it, checkpoints to ``on_checkpoint``; rsl-rl's dump is printed nowhere."""
    vec_env = make_teacher_env("wipe", refs["wipe"], SMALL, "touch2robot")
    calls: list[tuple[int, dict[str, float]]] = []
    saved: list[str] = []
    try:
        train(
            vec_env,
            SMALL,
            tmp_path / "teacher",
            on_log=lambda step, m: calls.append((step, m)),
            on_checkpoint=saved.append,
        )
    finally:
        vec_env.env.close()
    iterations = [(step, m) for step, m in calls if not all(k.endswith(WALL_CLOCK_SUFFIX) for k in m)]
    assert [step for step, _ in iterations] == list(range(SMALL.ppo.max_iterations))
    for _, metrics in iterations:
        assert {"Loss/learning_rate", "Loss/value", "Perf/total_fps", "Policy/mean_std"} <= metrics.keys()
        assert all(isinstance(v, float) and v == v for v in metrics.values())
    assert any("Train/mean_reward" in m for _, m in iterations)  # once episodes have ended
    assert [Path(p).name for p in saved] == ["model_0.pt", "model_2.pt", "model_3.pt"]
    assert "Learning iteration" not in capsys.readouterr().out


def test_load_latest_without_checkpoints(refs: dict[str, References], tmp_path: Path) -> None:
    from rsl_rl.runners import OnPolicyRunner

    vec_env = make_teacher_env("wipe", refs["wipe"], SMALL, "touch2robot", n_envs=2)
    runner = OnPolicyRunner(vec_env, runner_config(SMALL.ppo), log_dir=None, device="cpu")
    assert load_latest(runner, tmp_path) is None
    vec_env.env.close()
