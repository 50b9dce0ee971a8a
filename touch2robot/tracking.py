"""MLflow tracking: a SQLite file under the data folder by default (or the server named
by MLFLOW_TRACKING_URI), one experiment per stage with its artefacts stored under the
data folder, never in the working directory."""

from __future__ import annotations

import os
from contextlib import contextmanager
from collections.abc import Iterator

import mlflow

from touch2robot.settings import DataLayout


def tracking_uri(layout: DataLayout) -> str:
    return os.environ.get("MLFLOW_TRACKING_URI") or f"sqlite:///{layout.mlflow_db}"


def experiment(layout: DataLayout, stage: str) -> str:
    """Point MLflow at the project's store and return the stage's experiment id."""
    mlflow.set_tracking_uri(tracking_uri(layout))
    name = f"touch2robot/{stage}"
    found = mlflow.get_experiment_by_name(name)
    if found is not None:
        return found.experiment_id
    # a remote server keeps its own artefact store; the local default keeps them in the data folder
    location = None if os.environ.get("MLFLOW_TRACKING_URI") else (layout.mlartifacts / stage).as_uri()
    try:
        return mlflow.create_experiment(name, artifact_location=location)
    except mlflow.exceptions.MlflowException:
        # another process created it between our lookup and create
        return mlflow.get_experiment_by_name(name).experiment_id


@contextmanager
def stage_run(layout: DataLayout, stage: str, run_name: str, tags: dict[str, str] | None = None) -> Iterator[mlflow.ActiveRun]:
    """An MLflow run in the stage's experiment."""
    exp = experiment(layout, stage)
    with mlflow.start_run(experiment_id=exp, run_name=run_name, tags={"stage": stage, **(tags or {})}) as run:
        yield run
