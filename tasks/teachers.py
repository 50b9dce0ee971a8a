"""Tasks of the teachers stage: train one PPO teacher per task x method (resuming from its last
checkpoint), record its deterministic rollouts, replay the kinematic baseline, and report."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from prefect import get_run_logger, task
from prefect.artifacts import create_markdown_artifact, create_table_artifact

from schemas.vocabulary import Method, Origin, Source
from tasks import tracking
from tasks.common import ALWAYS_RUN, cache_policy, checkpoint_on_stop, one_torch_thread, retry_unless_lost_physics
from tasks.logs import TrainingProgress, both
from touch2robot import datasets
from touch2robot.settings import DataLayout
from touch2robot.teachers.config import TeacherConfig

TEACHER_MODULES = (
    "touch2robot.geometry",
    "touch2robot.teachers",
    "touch2robot.sim",
    "touch2robot.leap",
    "touch2robot.scenes",
    "touch2robot.contacts",
    "touch2robot.lake",
    "touch2robot.datasets",
)


def _references(layout: DataLayout, recordings: list[dict], config: TeacherConfig):
    from touch2robot.teachers.objective import load_references

    return load_references(layout.lake, recordings, config)


def _params(config: TeacherConfig, method: str) -> dict[str, object]:
    """Flat MLflow params: PPO, sim, objective scales and the method's variant."""
    flat: dict[str, object] = {}

    def walk(prefix: str, value: object) -> None:
        if isinstance(value, dict):
            for k, v in value.items():
                walk(f"{prefix}.{k}" if prefix else str(k), v)
        else:
            flat[prefix] = value

    dump = config.model_dump(mode="json", exclude={"variants", "tasks", "methods"})
    walk("", dump)
    walk("method", config.method(method).model_dump(mode="json"))
    return flat


def _run_folder(layout: DataLayout, task_name: str, method: str, config: TeacherConfig, digest: str) -> Path:
    """One folder per distinct training: checkpoints of another config or other demonstrations
    are never resumed into this one."""
    key = hashlib.sha256(
        json.dumps(
            [
                config.model_dump(mode="json", exclude={"tasks", "methods", "rollouts_per_task"}),
                method,
                task_name,
                digest,
            ],
            sort_keys=True,
        ).encode()
    )
    return datasets.teacher_checkpoints(layout, task_name, method, key.hexdigest())


@task(
    cache_policy=cache_policy(*TEACHER_MODULES),
    persist_result=True,
    retries=1,
    retry_condition_fn=retry_unless_lost_physics,
    task_run_name="teacher-{task_name}-{method}-seed{seed}",
)
def train_teacher(
    task_name: str,
    method: str,
    seed: int,
    config: TeacherConfig,
    recordings: list[dict],
    digest: str,
    data: str,
    profile: str,
) -> dict:
    """Train (or finish training) the teacher of one task and method; metrics stream to one MLflow
    run (stage "teachers"), checkpoints are its artefacts. A killed run resumes from the newest
    checkpoint: the retry, or the next flow run, continues instead of starting over. A stopped run
    (SIGTERM, Ctrl-C) first checkpoints the iteration it is in. ``seed`` is the sweep seed (``config`` is
    the profile's for that seed)."""
    from touch2robot.sim.guard import LostPhysicsError
    from touch2robot.teachers.train import WALL_CLOCK_SUFFIX, make_teacher_env, train

    one_torch_thread()
    layout = DataLayout.from_env(data)
    refs = _references(layout, recordings, config)
    folder = _run_folder(layout, task_name, method, config, digest)
    tags = {
        "profile": profile,
        "task": task_name,
        "method": method,
        "seed": str(seed),
        "demonstrations": str(len(recordings)),
        "checkpoints": str(folder),
    }
    run_id = tracking.resumable_run(
        layout, "teachers", folder, f"teacher-{task_name}-{method}-seed{seed}", tags, _params(config, method)
    )
    vec_env = make_teacher_env(task_name, refs, config, method)
    mlflow_run = tracking.RunWriter(run_id, tracking.tracking_uri(layout))

    def mean_return(metrics: dict[str, float]) -> str | None:
        if all(name.endswith(WALL_CLOCK_SUFFIX) for name in metrics):
            return None
        return f"mean return {metrics['Train/mean_reward']:.3g}" if "Train/mean_reward" in metrics else ""

    progress = TrainingProgress(
        f"teacher {task_name}/{method}",
        "iteration",
        config.ppo.max_iterations,
        mean_return,
        done=lambda iteration: iteration + 1,
    )
    iteration_in_progress = [0]  # the one after the last this attempt logged (0 until it logs one)

    def note_step(step: int, metrics: dict[str, float]) -> None:
        iteration_in_progress[0] = step + 1

    try:
        with checkpoint_on_stop() as stop_requested:
            result = train(
                vec_env,
                config,
                folder,
                on_log=both(mlflow_run.log, progress, note_step),
                on_checkpoint=mlflow_run.checkpoint,
                should_stop=stop_requested,
            )
    except LostPhysicsError:
        mlflow_run.client.log_metric(run_id, "sim/lost_physics", 1.0, step=iteration_in_progress[0])
        raise
    finally:
        vec_env.env.close()
    if result.resumed_from:
        get_run_logger().info(
            "teacher %s/%s resumed at iteration %d of %d", task_name, method, result.resumed_from, result.iterations
        )
    return {
        "task": task_name,
        "method": method,
        "seed": seed,
        "checkpoint": str(result.checkpoint),
        "iterations": result.iterations,
        "resumed_from": result.resumed_from,
        "mlflow_run": run_id,
    }


def _store_rollouts(
    layout: DataLayout, task_name: str, method: str, origin: str, seed: int, rollouts, contacts
) -> None:
    key = datasets.rollouts_key(origin, task_name, seed)
    datasets.ROLLOUTS.write(layout.lake, key, datasets.with_seed(rollouts, seed), method=method)
    datasets.CONTACTS.write(
        layout.lake,
        datasets.RolloutContactsKey(origin, method, str(seed)),
        datasets.with_seed(contacts, seed),
        source=Source.SIM,
        task=task_name,
    )


@task(
    cache_policy=cache_policy(*TEACHER_MODULES, "touch2robot.metrics"),
    persist_result=True,
    task_run_name="rollouts-{trained[task]}-{trained[method]}-seed{trained[seed]}",
)
def teacher_rollouts(trained: dict, config: TeacherConfig, recordings: list[dict], digest: str, data: str) -> dict:
    """``config.rollouts_per_task`` deterministic rollouts of a trained teacher -> ``rollouts`` and
    sim ``contacts``; success rate and contact F1 vs the human preference go to its MLflow run."""
    import numpy as np
    import torch
    from tensordict import TensorDict

    from touch2robot.teachers import rollouts as ro
    from touch2robot.teachers.train import load_policy, make_teacher_env

    one_torch_thread()
    layout = DataLayout.from_env(data)
    task_name, method = trained["task"], trained["method"]
    refs = _references(layout, recordings, config)
    vec_env = make_teacher_env(task_name, refs, config, method, n_envs=config.rollouts_per_task)
    policy = load_policy(vec_env, config, Path(trained["checkpoint"]))

    def act(obs: dict[str, np.ndarray]) -> np.ndarray:
        groups = TensorDict(
            {k: torch.as_tensor(v, dtype=torch.float32) for k, v in obs.items()}, batch_size=[vec_env.num_envs]
        )
        with torch.inference_mode():
            return policy(groups).numpy()

    try:
        rows, contacts = ro.record(vec_env.env, vec_env.objective, act, method, Origin.TEACHER, seed=config.seed)
    finally:
        vec_env.env.close()
    _store_rollouts(layout, task_name, method, Origin.TEACHER, trained["seed"], rows, contacts)
    figures = ro.summary(rows, refs, config.sim.contact_threshold_n)
    with tracking.stage_run(layout, "teachers", "", run_id=trained["mlflow_run"]):
        import mlflow

        mlflow.log_metrics({f"rollouts/{k}": v for k, v in figures.items() if v == v})
    return {
        "task": task_name,
        "method": method,
        "seed": trained["seed"],
        "origin": Origin.TEACHER,
        **figures,
        "iterations": trained["iterations"],
        "mlflow_run": trained["mlflow_run"],
    }


@task(
    cache_policy=cache_policy(*TEACHER_MODULES, "touch2robot.metrics"),
    persist_result=True,
    task_run_name="kinematic-{task_name}-seed{seed}",
)
def kinematic_rollouts(
    task_name: str, seed: int, config: TeacherConfig, recordings: list[dict], digest: str, data: str, profile: str
) -> dict:
    """Dex Retargeting's robot trajectories: the kinematic references replayed in MuJoCo with no
    residual (no teacher), one per demonstration, recorded like teacher rollouts. Deterministic, but
    stored per sweep seed like every method's, so that each seed's comparison is complete."""
    from touch2robot.sim.env import BatchEnv
    from touch2robot.sim.scene import build_scene
    from touch2robot.teachers import rollouts as ro
    from touch2robot.teachers.objective import DemoTracking

    layout = DataLayout.from_env(data)
    refs = _references(layout, recordings, config)
    env = BatchEnv(build_scene(task_name, config.sim), config.sim, len(refs.ids))
    try:
        rows, contacts = ro.record(
            env,
            DemoTracking(refs, config, Method.TOUCH2ROBOT),
            ro.zero_residual,
            Method.DEX_RETARGETING,
            Origin.KINEMATIC,
        )
    finally:
        env.close()
    _store_rollouts(layout, task_name, Method.DEX_RETARGETING, Origin.KINEMATIC, seed, rows, contacts)
    figures = ro.summary(rows, refs, config.sim.contact_threshold_n)
    tags = {
        "profile": profile,
        "task": task_name,
        "method": Method.DEX_RETARGETING,
        "origin": Origin.KINEMATIC,
        "seed": str(seed),
    }
    with tracking.stage_run(layout, "teachers", f"kinematic-{task_name}-seed{seed}", tags) as run:
        import mlflow

        mlflow.log_metrics({f"rollouts/{k}": v for k, v in figures.items() if v == v})
    return {
        "task": task_name,
        "method": Method.DEX_RETARGETING,
        "seed": seed,
        "origin": Origin.KINEMATIC,
        **figures,
        "iterations": 0,
        "mlflow_run": run.info.run_id,
    }


@task(**ALWAYS_RUN)
def report_teachers(profile: str, results: list[dict]) -> list[dict]:
    """A Prefect table of success rate and contact F1 per task x method, and a summary."""
    keys = (
        "task",
        "method",
        "seed",
        "origin",
        "iterations",
        "rollouts",
        "success_rate",
        "final_progress",
        "contact_precision",
        "contact_recall",
        "contact_f1",
        "mlflow_run",
    )
    table = [{k: (round(r[k], 3) if isinstance(r[k], float) else r[k]) for k in keys} for r in results]
    create_table_artifact(key="teacher-rollouts", table=table, description=f"Teacher rollouts ({profile})")
    lines = [
        f"| {r['task']} | {r['method']} | {r['seed']} | {r['success_rate']:.2f} | {r['contact_f1']:.3f} |"
        for r in table
    ]
    create_markdown_artifact(
        key="teachers-summary",
        markdown=f"# Teachers ({profile})\n\n| task | method | seed | success | contact F1 vs human |\n"
        "|---|---|---|---|---|\n" + "\n".join(lines) + "\n",
    )
    return table
