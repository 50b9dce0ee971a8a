"""Tasks of the policy stage, per task x method: the LeRobot dataset of its rollouts, LeRobot's
Diffusion Policy trained on it (one MLflow run of stage "policy": loss and learning-rate curves,
the final policy as an artefact) and its closed-loop evaluation (``policy_eval`` row, videos)."""

from __future__ import annotations

import hashlib
import json
import tempfile
from collections.abc import Sequence
from pathlib import Path

from prefect import get_run_logger, task
from prefect.artifacts import create_table_artifact

from tasks import tracking
from tasks.common import ALWAYS_RUN, cache_policy, checkpoint_on_stop, one_torch_thread
from tasks.logs import TrainingProgress, both
from touch2robot import datasets
from touch2robot.policy import PolicyConfig
from touch2robot.settings import DataLayout
from touch2robot.sim.config import SimConfig

POLICY_MODULES = (
    "touch2robot.geometry",
    "touch2robot.policy",
    "touch2robot.sim",
    "touch2robot.scenes",
    "touch2robot.leap",
    "touch2robot.lake",
    "touch2robot.datasets",
)
TAGS_NOTE = "none: ResNet-18 trained from scratch (pretrained_backbone_weights=None, no downloads)"


def _digest(payload: dict) -> str:
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()[:12]


@task(
    cache_policy=cache_policy(*POLICY_MODULES),
    persist_result=True,
    retries=1,
    task_run_name="dataset-{source[method]}-{source[task]}-seed{source[seed]}",
)
def build_policy_dataset(source: dict, config: PolicyConfig, sim: SimConfig, data: str) -> dict:
    """Replay one task x method's rollouts (with ``sim``, the physics they were recorded with) and
    write its LeRobot dataset under <data>/datasets (the source's ``digest``, the rollouts file's
    content hash, keys the cache)."""
    from touch2robot.policy.dataset import build_dataset, read_rollouts
    from touch2robot.sim.scene import build_scene

    layout = DataLayout.from_env(data)
    rollouts = read_rollouts(Path(source["path"]), config.max_rollouts, source["references"])
    root = datasets.policy_dataset(layout, source["method"], source["task"], source["seed"])
    summary = build_dataset(
        root,
        source["task"],
        source["method"],
        rollouts,
        build_scene(source["task"], sim),
        sim,
        config,
        source["seed"],
    )
    rendering = f"rendering {summary.render_fps:.0f} images/s" if summary.render_frames else "no cameras"
    get_run_logger().info(
        "%s: %d episodes, %d frames, %s, replay error max %.2e rad",
        root.name,
        summary.episodes,
        summary.frames,
        rendering,
        summary.replay_max_joint_error_rad,
    )
    return {**source, **summary.__dict__}


@task(
    cache_policy=cache_policy(*POLICY_MODULES),
    persist_result=True,
    task_run_name="train-{dataset[method]}-{dataset[task]}-seed{dataset[seed]}",
)
def train_policy(dataset: dict, config: PolicyConfig, data: str, profile: str) -> dict:
    """Train LeRobot's Diffusion Policy on one dataset with loss and learning rate streamed to
    the task x method's MLflow run. A crashed run resumes from its last LeRobot checkpoint and
    its MLflow run (the training folder is keyed by the dataset and the training settings); a
    stopped one (SIGTERM, Ctrl-C) first saves a checkpoint at the update it reached."""
    import mlflow

    from touch2robot.policy.train import train

    one_torch_thread()
    layout = DataLayout.from_env(data)
    # the dataset's own settings (observation, image_size, cameras, ...) stay in: a training folder holds one
    # dataset layout's checkpoints
    settings = config.model_dump(
        mode="json",
        exclude={
            "keep_checkpoints",
            "eval_episodes",
            "eval_batch",
            "eval_seed",
            "object_noise_m",
            "video_episodes",
        },
    )
    key = _digest(
        {"dataset": dataset["digest"], "references": dataset["references"], "frames": dataset["frames"], **settings}
    )
    out = datasets.policy_training(layout, dataset["method"], dataset["task"], dataset["seed"], key)
    out.mkdir(parents=True, exist_ok=True)
    run_file = out / "mlflow_run_id"
    tags = {
        "profile": profile,
        "task": dataset["task"],
        "method": dataset["method"],
        "seed": str(dataset["seed"]),
        "origin": dataset["origin"],
        "observation": config.observation,
        "pretrained_backbone": TAGS_NOTE if config.observation == "images" else "none: no cameras",
    }
    tracking.experiment(layout, "policy")
    if run_file.exists():
        run_ctx = mlflow.start_run(run_id=run_file.read_text().strip())
    else:
        name = f"{dataset['method']}-{dataset['task']}-seed{dataset['seed']}"
        run_ctx = tracking.stage_run(layout, "policy", name, tags)
    with run_ctx as run:
        run_file.write_text(run.info.run_id)
        mlflow.log_params(
            {
                **settings,
                "dataset_root": dataset["root"],
                "dataset_episodes": dataset["episodes"],
                "dataset_frames": dataset["frames"],
            }
        )
        rendered = {"dataset/render_fps": dataset["render_fps"]} if dataset["render_frames"] else {}
        mlflow.log_metrics({**rendered, "dataset/replay_max_joint_error_rad": dataset["replay_max_joint_error_rad"]})
        progress = TrainingProgress(
            f"policy {dataset['task']}/{dataset['method']}",
            "update",
            config.steps,
            lambda metrics: f"loss {metrics['loss']:.4f}",
        )
        with checkpoint_on_stop() as stop_requested:
            result = train(
                Path(dataset["root"]),
                dataset["repo_id"],
                config,
                out / "lerobot",
                on_log=both(tracking.step_logger(run.info.run_id, "train/"), progress),
                should_stop=stop_requested,
            )
        if result.steps > result.resumed_from:  # a finished folder resumes with no update to time
            mlflow.log_metrics({"train/samples_per_s_total": result.samples_per_s})
        mlflow.log_artifacts(result.policy_dir, "policy")
    return {**dataset, **result.__dict__, "mlflow_run": run.info.run_id}


@task(
    cache_policy=cache_policy(*POLICY_MODULES),
    persist_result=True,
    task_run_name="evaluate-{trained[method]}-{trained[task]}-seed{trained[seed]}",
)
def evaluate_policy(trained: dict, config: PolicyConfig, sim: SimConfig, data: str, profile: str) -> dict:
    """Closed-loop episodes of the trained policy; one ``policy_eval`` row (lake) and success
    metrics plus a few episode videos in the task x method's MLflow run."""
    import mlflow
    import pyarrow as pa

    from touch2robot.policy.dataset import read_rollouts
    from touch2robot.policy.evaluate import evaluate, write_video
    from touch2robot.sim.scene import build_scene

    one_torch_thread()
    layout = DataLayout.from_env(data)
    scene = build_scene(trained["task"], sim)
    rollouts = read_rollouts(Path(trained["path"]), config.max_rollouts, trained["references"])
    outcome = evaluate(
        Path(trained["policy_dir"]),
        Path(trained["root"]),
        trained["repo_id"],
        scene,
        sim,
        rollouts,
        config,
        config.video_episodes,
    )
    result, fit, replay = outcome.closed_loop, outcome.fit, outcome.replay
    low, high = result.wilson
    row = {
        "task": trained["task"],
        "method": trained["method"],
        "seed": trained["seed"],
        "origin": trained["origin"],
        "observation": config.observation,
        "profile": profile,
        "dataset_episodes": trained["episodes"],
        "dataset_frames": trained["frames"],
        "train_steps": trained["steps"],
        "final_loss": trained["last_loss"],
        "episodes": len(result.success),
        "successes": int(result.success.sum()),
        "success_rate": result.success_rate,
        "ci_low": low,
        "ci_high": high,
        "mean_progress": float(result.progress.mean()),
        "replay_successes": int(replay.success.sum()),
        "replay_success_rate": replay.success_rate,
        "fit_joint_err_rad": fit.joint_err_rad,
        "fit_wrist_err_mm": fit.wrist_err_mm,
        "hold_joint_err_rad": fit.hold_joint_err_rad,
        "hold_wrist_err_mm": fit.hold_wrist_err_mm,
        "episode_steps": result.steps,
        "replans": result.replans,
        "mlflow_run": trained["mlflow_run"],
    }
    key = datasets.MethodTaskKey(trained["method"], trained["task"], str(trained["seed"]))
    datasets.POLICY_EVAL.write(layout.lake, key, pa.Table.from_pylist([row]))
    tracking.experiment(layout, "policy")
    with mlflow.start_run(run_id=trained["mlflow_run"]):
        mlflow.log_metrics(
            {
                "eval/success_rate": row["success_rate"],
                "eval/ci_low": low,
                "eval/ci_high": high,
                "eval/mean_progress": row["mean_progress"],
                "eval/replay_success_rate": row["replay_success_rate"],
                **{f"fit/{k}": v for k, v in fit.__dict__.items() if k != "frames"},
            }
        )
        with tempfile.TemporaryDirectory() as tmp:
            for i, frames in enumerate(result.videos):
                mlflow.log_artifact(str(write_video(frames, Path(tmp) / f"episode_{i:02d}.mp4")), "videos")
    return row


@task(**ALWAYS_RUN)
def report_policy(profile: str, rows: list[dict]) -> list[dict]:
    """A Prefect table of the success rates per task x method."""
    create_table_artifact(
        key="policy-success",
        table=[
            {k: (round(v, 3) if isinstance(v, float) else v) for k, v in r.items() if k != "mlflow_run"} for r in rows
        ],
        description=f"Diffusion Policy closed-loop success per task x method x seed ({profile})",
    )
    return rows


def rollout_sources(
    data: str,
    config: PolicyConfig,
    tasks: Sequence[str] | None = None,
    methods: Sequence[str] | None = None,
    seed: int = 0,
) -> list[dict]:
    """The rollouts file of every task x method of sweep seed ``seed`` (most preferred of ``config.origins``,
    narrowed to ``tasks`` / ``methods``), with its content hash and, with ``config.same_demonstrations``, the
    demonstrations all of the task's methods follow (``references``; None = every rollout)."""
    from touch2robot.policy.dataset import chosen_sources

    layout = DataLayout.from_env(data)
    out = []
    for s, references in chosen_sources(layout.lake, config, tasks, methods, seed):
        if references == []:
            get_run_logger().warning(
                "policy: the methods of %s follow no demonstration in common; %s is skipped", s.task, s.method
            )
            continue
        out.append(
            {
                "task": s.task,
                "method": s.method,
                "seed": seed,
                "origin": s.origin,
                "path": str(s.path),
                "digest": datasets.file_digest(s.path),
                "references": references,
            }
        )
    return out
