"""MLflow tracking of resumable trainings: a training resumed from its last checkpoint re-does the
updates after it; their figures are in the run already, so each step is drawn once."""

from __future__ import annotations

import shutil
from pathlib import Path

import mlflow
from mlflow.artifacts import load_text
from mlflow.tracking import MlflowClient

from tasks import tracking
from touch2robot.settings import DataLayout


def _steps(uri: str, run_id: str, key: str) -> list[int]:
    return sorted(m.step for m in MlflowClient(uri).get_metric_history(run_id, key))


def test_a_resumed_training_logs_each_step_once(tmp_path: Path) -> None:
    layout = DataLayout(tmp_path / "data")
    with tracking.stage_run(layout, "policy", "resume") as run:
        run_id = run.info.run_id
    uri = tracking.tracking_uri(layout)
    first = tracking.step_logger(run_id, "train/")
    for step in range(10, 70, 10):  # crashed after step 60; its last checkpoint was at 40
        first(step, {"loss": 1.0, "lr": 0.1})
    resumed = tracking.step_logger(run_id, "train/")  # a new process
    for step in range(50, 110, 10):
        resumed(step, {"loss": 0.5, "lr": 0.1, "grad_norm": 2.0})
    assert _steps(uri, run_id, "train/loss") == list(range(10, 110, 10))
    assert [m.value for m in sorted(MlflowClient(uri).get_metric_history(run_id, "train/loss"), key=lambda m: m.step)][
        -4:
    ] == [0.5] * 4
    assert _steps(uri, run_id, "train/grad_norm") == list(
        range(50, 110, 10)
    )  # a new metric starts where it is first logged
    assert mlflow.active_run() is None


def test_the_teachers_run_writer_skips_iterations_the_run_holds(tmp_path: Path) -> None:
    layout = DataLayout(tmp_path / "data")
    with tracking.stage_run(layout, "teachers", "resume") as run:
        run_id = run.info.run_id
    uri = tracking.tracking_uri(layout)
    before = tracking.RunWriter(run_id, uri)
    for it in range(4):  # killed after iteration 3, checkpoint at 1
        before.log(it, {"Loss/value": 1.0, "Train/mean_reward": float(it)})
    after = tracking.RunWriter(run_id, uri)  # a new process
    for it in range(2, 6):
        after.log(it, {"Loss/value": 0.5, "Train/mean_reward": float(it)})
    assert _steps(uri, run_id, "Loss/value") == list(range(6))
    assert _steps(uri, run_id, "Train/mean_reward") == list(range(6))


def test_a_copied_data_folder_finds_its_artefacts_in_the_copy(tmp_path: Path) -> None:
    """MLflow stores artefact locations as absolute file URIs; the copy's store is pointed at the copy."""
    original = DataLayout(tmp_path / "original")
    with tracking.stage_run(original, "ingest", "probe") as run:
        mlflow.log_text("hello", "note.txt")
        run_id = run.info.run_id
    shutil.copytree(original.root, tmp_path / "copy")
    shutil.rmtree(original.root)  # the original is gone: only the copy can answer
    copy = DataLayout(tmp_path / "copy")
    assert tracking.relocate_store(copy) > 0
    tracking.experiment(copy, "ingest")
    client = MlflowClient(tracking.local_uri(copy))
    artifact_uri = client.get_run(run_id).info.artifact_uri
    assert artifact_uri is not None and artifact_uri.startswith(copy.mlartifacts.as_uri())
    assert load_text(f"runs:/{run_id}/note.txt") == "hello"
