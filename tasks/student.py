"""Tasks of the student stage: the augmented dataset (lake ``student_dataset`` + an MLflow
manifest), one distillation per variant (the full model and each ablation: its own MLflow run
of stage "student" with curves, checkpoints and the model) resuming from its last checkpoint,
and the reconstruction of the held-out demonstrations (full model: ``rollouts`` origin student,
``contacts`` source reconstructed, ``student_predictions``)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pandas as pd
import pyarrow as pa
from prefect import get_run_logger, task
from prefect.artifacts import create_markdown_artifact, create_table_artifact

from schemas.vocabulary import Origin, Source
from tasks import tracking
from tasks.common import ALWAYS_RUN, cache_policy, checkpoint_on_stop, one_torch_thread
from tasks.logs import TrainingProgress, both
from touch2robot import datasets
from touch2robot.evaluate import heldout_demonstration_sums
from touch2robot.settings import DataLayout
from touch2robot.student.config import StudentConfig
from touch2robot.teachers.config import TeacherConfig

STUDENT_MODULES = (
    "touch2robot.geometry",
    "touch2robot.student",
    "touch2robot.teachers",
    "touch2robot.sim",
    "touch2robot.scenes",
    "touch2robot.lake",
    "touch2robot.datasets",
    "touch2robot.metrics",
)


def _sha(payload: object) -> str:
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()


def _references(layout: DataLayout, recordings: list[dict], teacher: TeacherConfig) -> dict:
    from touch2robot.teachers.reference import load_reference

    return {
        r["recording_id"]: load_reference(layout.lake, r, teacher.sim.control_hz, teacher.contact_margin_m)
        for r in recordings
    }


def _split_tags(split: dict) -> dict[str, str]:
    held = (
        "in-sample (no task had a demonstration to hold out: every demonstration is trained on and reconstructed)"
        if split["in_sample"]
        else "held-out demonstrations"
    )
    return {
        "held_out": held,
        **{f"demos_{role}": str(sum(len(v) for v in split[role].values())) for role in ("train", "val", "held_out")},
    }


@task(
    cache_policy=cache_policy(*STUDENT_MODULES),
    persist_result=True,
    retries=1,
    task_run_name="student-dataset-seed{seed}",
)
def augment_dataset(
    seed: int,
    config: StudentConfig,
    teacher: TeacherConfig,
    split: dict,
    recordings: list[dict],
    digest: str,
    data: str,
    profile: str,
) -> dict:
    """Pair the teacher rollouts of the training and validation demonstrations with their
    demonstrations, augment the training ones to ``config.augmented_rollouts`` (balanced over
    the tasks) and write ``student_dataset`` (one file per task); the manifest goes to MLflow. ``seed``: the
    sweep seed, whose teacher rollouts it reads (``config`` is the profile's for that seed)."""
    import mlflow
    import pyarrow.parquet as pq

    from touch2robot.student.augment import augment, paired_sequences, per_task_counts

    layout = DataLayout.from_env(data)
    trainable = [
        r
        for r in recordings
        if any(r["recording_id"] in ids for role in ("train", "val") for ids in split[role].values())
    ]
    refs = _references(layout, trainable, teacher)
    tasks = sorted({t for role in ("train", "val") for t, ids in split[role].items() if ids})
    counts = per_task_counts(config.augmented_rollouts, [t for t in tasks if split["train"].get(t)])
    manifest: dict = {
        "profile": profile,
        "total_rollouts": config.augmented_rollouts,
        "joint_noise_std": config.joint_noise_std,
        "seed": config.seed,
        "sweep_seed": seed,
        "teacher_method": config.teacher_method,
        "in_sample": split["in_sample"],
        "tasks": {},
    }
    paths = {}
    for task_name in tasks:
        source = datasets.teacher_rollouts(layout.lake, config.teacher_method, task_name, seed)
        if not source.is_file():
            raise FileNotFoundError(
                f"student: no teacher rollouts of {config.teacher_method}/{task_name} at {source}: run the "
                "teachers flow first"
            )
        seqs = paired_sequences(pq.read_table(source), refs, teacher.sim.contact_threshold_n)
        train = [s for s in seqs if s.reference_id in split["train"].get(task_name, [])]
        val = [s for s in seqs if s.reference_id in split["val"].get(task_name, [])]
        count = counts.get(task_name, 0)
        table = augment(train, count, config.joint_noise_std, config.seed, val)
        key = datasets.TaskKey(task_name, str(seed))
        path = datasets.STUDENT_DATASET.write(layout.lake, key, datasets.with_seed(table, seed))
        paths[task_name] = str(path)
        manifest["tasks"][task_name] = {
            "train_demos": split["train"].get(task_name, []),
            "val_demos": split["val"].get(task_name, []),
            "held_out_demos": split["held_out"].get(task_name, []),
            "teacher_rollouts_train": len(train),
            "teacher_rollouts_val": len(val),
            "augmented_rollouts": count,
            "noisy_copies": max(count - len(train), 0),
            "rows": table.num_rows,
            "file": path.name,
            "sha256": datasets.file_digest(path),
        }
    tags = {"profile": profile, "seed": str(seed), **_split_tags(split)}
    with tracking.stage_run(layout, "student", f"dataset-seed{seed}", tags) as run:
        mlflow.log_params(
            {
                "augmented_rollouts": config.augmented_rollouts,
                "joint_noise_std": config.joint_noise_std,
                "seed": config.seed,
            }
        )
        mlflow.log_dict(manifest, "manifest.json")
    get_run_logger().info("student dataset: %s", {t: m["rows"] for t, m in manifest["tasks"].items()})
    return {
        "seed": seed,
        "paths": paths,
        "tasks": tasks,
        "digest": _sha([manifest["tasks"][t]["sha256"] for t in tasks]),
        "mlflow_run": run.info.run_id,
        "split": split,
    }


def _clouds(tasks: list[str], teacher: TeacherConfig):
    import numpy as np
    import torch

    from touch2robot.sim.scene import build_scene

    return torch.as_tensor(np.stack([build_scene(t, teacher.sim).point_cloud for t in tasks]), dtype=torch.float32)


@task(
    cache_policy=cache_policy(*STUDENT_MODULES),
    persist_result=True,
    retries=1,
    task_run_name="student-train-{variant}-seed{dataset[seed]}",
)
def train_student(
    variant: str, config: StudentConfig, teacher: TeacherConfig, dataset: dict, data: str, profile: str
) -> dict:
    """Distil one variant on the dataset; curves and checkpoints to its MLflow run, then the
    model (``mlflow.pytorch``, single-tensor serving form with a signature). A killed run
    resumes from the last checkpoint in its training folder (keyed by config and dataset); a
    stopped one (SIGTERM, Ctrl-C) checkpoints at its current update first, then stops."""
    import mlflow
    import mlflow.pytorch as mlflow_pytorch
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.parquet as pq
    import torch
    from mlflow.models import infer_signature

    from touch2robot.student.model import ServingStudent
    from touch2robot.student.train import CHECKPOINT, train, windows_from_table

    one_torch_thread()
    layout = DataLayout.from_env(data)
    cfg = config.variant(variant)
    dump = cfg.model_dump(mode="json", exclude={"ablations"})
    folder = datasets.student_checkpoints(layout, variant, _sha([dump, dataset["digest"]]))
    seed = dataset["seed"]
    tags = {
        "profile": profile,
        "variant": variant,
        "seed": str(seed),
        "checkpoints": str(folder),
        "dataset_run": dataset["mlflow_run"],
        **_split_tags(dataset["split"]),
    }
    run_id = tracking.resumable_run(
        layout, "student", folder, f"student-{variant}-seed{seed}", tags, {**dump, "variant": variant}
    )
    tasks = dataset["tasks"]
    table = pa.concat_tables([pq.read_table(dataset["paths"][t]) for t in tasks])
    # pyarrow.compute makes its kernels (pc.equal) at import: no source or stub names them
    split = lambda name: windows_from_table(table.filter(pc.equal(table["split"], name)), tasks, cfg.history)  # noqa: E731  # pyright: ignore[reportAttributeAccessIssue]
    clouds = _clouds(tasks, teacher)
    tracking.experiment(layout, "student")
    progress = TrainingProgress(f"student {variant}", "update", cfg.steps, _student_loss)
    with mlflow.start_run(run_id=run_id):
        with checkpoint_on_stop() as stop_requested:
            result = train(
                split("train"),
                split("val"),
                clouds,
                cfg,
                folder,
                on_log=both(tracking.step_logger(run_id), progress),
                should_stop=stop_requested,
            )
        mlflow.log_artifact(str(folder / CHECKPOINT), "checkpoints")
        serving = ServingStudent(result.net, clouds.shape[1]).eval()
        window = split("val") if len(split("val")) else split("train")
        example = torch.cat(
            [
                window.batch(torch.arange(1))["inputs"].reshape(1, -1),
                clouds[window.cloud[window.starts[:1] + cfg.history - 1]].reshape(1, -1),
            ],
            dim=1,
        )
        with torch.inference_mode():
            signature = infer_signature(example.numpy(), serving(example).numpy())
        # pickled module: torch.export (MLflow's default) is not thread-safe and variants train side by side
        mlflow_pytorch.log_model(
            serving, name="model", signature=signature, input_example=example.numpy(), serialization_format="pickle"
        )
        mlflow.log_metrics({"val/initial_loss": result.initial_val["loss"], "val/final_loss": result.final_val["loss"]})
    if result.resumed_from:
        get_run_logger().info("student %s resumed at update %d of %d", variant, result.resumed_from, result.steps)
    return {
        "variant": variant,
        "seed": seed,
        "folder": str(folder),
        "mlflow_run": run_id,
        "steps": result.steps,
        "resumed_from": result.resumed_from,
        "initial_val_loss": result.initial_val["loss"],
        "final_val_loss": result.final_val["loss"],
    }


def _student_loss(metrics: dict[str, float]) -> str:
    """The progress line's figure: the training loss, the validation loss at the first call."""
    name = "train/loss" if "train/loss" in metrics else "val/loss"
    return f"{name.split('/')[0]} loss {metrics[name]:.4f}" if name in metrics else ""


@task(
    cache_policy=cache_policy(*STUDENT_MODULES, "touch2robot.evaluate", "touch2robot.comparison"),
    persist_result=True,
    task_run_name="student-reconstruct-{trained[variant]}-seed{trained[seed]}",
)
def reconstruct(
    trained: dict,
    config: StudentConfig,
    teacher: TeacherConfig,
    split: dict,
    recordings: list[dict],
    digest: str,
    data: str,
) -> list[dict]:
    """Reconstruct every held-out demonstration with one trained variant: executed in MuJoCo,
    figures per task to the variant's MLflow run. The full model's reconstructions are the
    lake's: ``contacts`` (source reconstructed) and ``student_predictions`` of the held-out
    demonstrations, and ``rollouts`` (origin student) of every demonstration of the task, the
    trained-on ones too: those are Touch2Robot's robot demonstrations for the policy stage, made
    from the same human demonstrations as every other method's (whose teachers trained on all of
    them). The ablations are compared in MLflow only."""
    import mlflow
    import pyarrow.parquet as pq

    from touch2robot.student.execute import reconstruct_task
    from touch2robot.student.train import load_net

    one_torch_thread()
    layout = DataLayout.from_env(data)
    variant, method, seed = trained["variant"], config.teacher_method, trained["seed"]
    net = load_net(Path(trained["folder"]), config.variant(variant))
    by_id = {r["recording_id"]: r for r in recordings}
    rows = []
    sums = []  # per held-out demonstration, vs the human's contacts: the comparison's clusters of this variant
    tracking.experiment(layout, "student")
    for task_name, ids in sorted(split["held_out"].items()):
        if not ids:
            continue
        trained_on = [i for role in ("train", "val") for i in split[role].get(task_name, []) if i not in ids]
        reconstructed = ids + trained_on if variant == "full" else ids
        refs = list(_references(layout, [by_id[i] for i in reconstructed], teacher).values())
        source = datasets.teacher_rollouts(layout.lake, method, task_name, seed)
        result = reconstruct_task(
            net,
            task_name,
            refs,
            teacher,
            method,
            variant,
            pq.read_table(source) if source.is_file() else None,
            evaluated=ids,
        )
        if variant == "full":
            lake = layout.lake
            key = datasets.rollouts_key(Origin.STUDENT, task_name, seed)
            datasets.ROLLOUTS.write(lake, key, datasets.with_seed(result.rollouts, seed), method=method)
            datasets.CONTACTS.write(
                lake,
                datasets.RolloutContactsKey(Origin.STUDENT, method, str(seed)),
                datasets.with_seed(result.contacts, seed),
                source=Source.RECONSTRUCTED,
                task=task_name,
            )
            predictions = datasets.with_seed(result.predictions, seed)
            key = datasets.MethodTaskKey(method, task_name, str(seed))
            datasets.STUDENT_PREDICTIONS.write(lake, key, predictions)
        with mlflow.start_run(run_id=trained["mlflow_run"]):
            mlflow.log_metrics({f"heldout/{task_name}/{k}": v for k, v in result.figures.items() if v == v})
        rows.append({"variant": variant, "seed": seed, "task": task_name, "demos": len(refs), **result.figures})
        sums.append(heldout_demonstration_sums(layout.lake, task_name, ids, result.contacts.to_pandas()))
    if sums:
        table = pd.concat(sums, ignore_index=True).assign(method=method, variant=variant, seed=seed)
        rows_arrow = pa.Table.from_pandas(table, schema=datasets.STUDENT_VARIANTS.schema, preserve_index=False)
        datasets.STUDENT_VARIANTS.write(layout.lake, (method, variant, str(seed)), rows_arrow)
    return rows


@task(**ALWAYS_RUN)
def report_student(profile: str, trained: list[dict], rows: list[dict]) -> list[dict]:
    """A Prefect table of the held-out figures per variant x task and a summary of the losses."""
    keys = (
        "variant",
        "seed",
        "task",
        "demos",
        "joint_error_student",
        "joint_error_kinematic",
        "contact_f1",
        "predicted_contact_f1",
        "success_rate",
    )
    table = [{k: (round(r[k], 4) if isinstance(r[k], float) else r[k]) for k in keys} for r in rows]
    create_table_artifact(
        key="student-heldout",
        table=table,
        description=f"Student reconstructions of held-out demonstrations ({profile})",
    )
    lines = [
        f"| {t['variant']} | {t['seed']} | {t['steps']} | {t['initial_val_loss']:.4f} | {t['final_val_loss']:.4f} |"
        for t in trained
    ]
    create_markdown_artifact(
        key="student-summary",
        markdown=f"# Student ({profile})\n\n| variant | seed | updates | val loss at init | val loss final |\n"
        "|---|---|---|---|---|\n" + "\n".join(lines) + "\n",
    )
    return table
