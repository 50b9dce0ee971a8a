"""MLflow tracking: a SQLite file under the data folder by default (or the server named
by MLFLOW_TRACKING_URI), one experiment per stage with its artefacts stored under the
data folder, never in the working directory; and the ``on_log`` hooks that stream a training's
figures into its run (the library trains without MLflow)."""

from __future__ import annotations

import fcntl
import json
import os
import sqlite3
from collections.abc import Callable, Iterator
from contextlib import closing, contextmanager, nullcontext
from pathlib import Path
from typing import TYPE_CHECKING

from touch2robot.datasets import file_digest
from touch2robot.provenance import code_version, git_commit
from touch2robot.settings import DataLayout

if TYPE_CHECKING:
    import mlflow

# MLflow is imported where it is used: importing it and opening its store take about 3 s on 2 cores, which a
# cached re-run that logs nothing should not pay


def local_uri(layout: DataLayout) -> str:
    return f"sqlite:///{layout.mlflow_db}"


# Local URIs this process pointed MLflow at (never mistaken for a server the user chose).
_LOCAL_URIS: set[str] = set()


def tracking_uri(layout: DataLayout) -> str:
    """The user's MLFLOW_TRACKING_URI (a server), else the data folder's SQLite file."""
    env = os.environ.get("MLFLOW_TRACKING_URI")
    if env and env not in _LOCAL_URIS:
        return env
    uri = local_uri(layout)
    _LOCAL_URIS.add(uri)
    return uri


def store_digest(layout: DataLayout) -> str | None:
    """The content digest of the data folder's SQLite store (with its journal, if any), or None when MLflow
    logs to a user's server: a cache keyed on it reads the store again only after something was logged."""
    if tracking_uri(layout) != local_uri(layout) or not layout.mlflow_db.exists():
        return None
    files = [layout.mlflow_db.with_name(layout.mlflow_db.name + suffix) for suffix in ("", "-wal", "-journal")]
    return "-".join(file_digest(f) for f in files if f.exists())


def experiment(layout: DataLayout, stage: str) -> str:
    """Point MLflow at the project's store and return the stage's experiment id."""
    import mlflow

    uri = tracking_uri(layout)
    mlflow.set_tracking_uri(uri)
    if uri in _LOCAL_URIS:
        # MLflow exports the URI for subprocesses to inherit; a child (a flow run, a test's
        # subprocess) working on another data folder must not mistake it for a user's server
        os.environ.pop("MLFLOW_TRACKING_URI", None)
    name = f"touch2robot/{stage}"
    with _store_lock(layout) if uri.startswith("sqlite:") else nullcontext():
        if uri == local_uri(layout):
            relocate_store(layout)
        return _get_or_create(layout, name, stage, uri)


# (table, column) of the local store that hold artefact locations
_LOCATION_COLUMNS = (
    ("experiments", "artifact_location"),
    ("runs", "artifact_uri"),
    ("logged_models", "artifact_location"),
    ("model_versions", "storage_location"),
    ("model_versions", "source"),
)
_RELOCATED: set[Path] = set()


def relocate_store(layout: DataLayout) -> int:
    """Point the local store's artefact locations at this data folder when the folder was copied or
    moved (they are absolute file URIs; users copy data folders to share them). Returns the rows changed."""
    if layout.mlflow_db in _RELOCATED or not layout.mlflow_db.exists():
        return 0
    new = (layout.mlartifacts).as_uri() + "/"
    changed = 0
    with closing(sqlite3.connect(layout.mlflow_db, timeout=60)) as con, con:
        tables = {row[0] for row in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        found = con.execute(
            "SELECT artifact_location FROM experiments WHERE artifact_location LIKE 'file://%/mlartifacts/%' LIMIT 1"
        ).fetchall()
        old = found[0][0].split("/mlartifacts/")[0] + "/mlartifacts/" if found else new
        if old != new:
            for table, column in _LOCATION_COLUMNS:
                if table in tables:
                    changed += con.execute(
                        f"UPDATE {table} SET {column} = ? || substr({column}, ?) WHERE substr({column}, 1, ?) = ?",
                        (new, len(old) + 1, len(old), old),
                    ).rowcount
    _RELOCATED.add(layout.mlflow_db)
    return changed


@contextmanager
def _store_lock(layout: DataLayout) -> Iterator[None]:
    """Two processes opening a fresh SQLite store both run its schema migrations and one
    fails; serialise the first touch of the store with a file lock."""
    layout.root.mkdir(parents=True, exist_ok=True)
    with open(layout.root / ".mlflow.db.lock", "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)  # released when the file closes
        yield


# What each stage's experiment holds (the MLflow UI shows it as the experiment's description).
EXPERIMENT_DESCRIPTIONS = {
    "ingest": "One run per ingest: recordings ingested, unchanged and quarantined, with the reasons.",
    "retarget": "Kinematic retargeting per glove recording: fingertip residuals and failed frames.",
    "teachers": "PPO teachers per method x task: reward and contact curves; the kinematic replays' figures.",
    "student": "The distilled student per variant (full model and ablations): losses and held-out reconstructions.",
    "evaluate": "Preference alignment and tactile fidelity per source x method x task (task 'all' pools the tasks); "
    "the user study; summary runs with the figures.",
    "policy": "LeRobot Diffusion Policy per method x task: training curves, closed-loop success, episode videos.",
    "report": "The run's report (report.html, report.md): the comparison with intervals and the paper's claims.",
}
# MLflow's own tag for a run's commit: the UI shows it on every run
GIT_COMMIT_TAG = "mlflow.source.git.commit"


def _get_or_create(layout: DataLayout, name: str, stage: str, uri: str) -> str:
    import mlflow
    from mlflow.exceptions import MlflowException

    found = mlflow.get_experiment_by_name(name)
    if found is not None:
        return found.experiment_id
    # a remote server keeps its own artefact store; the local default keeps them in the data folder
    location = (layout.mlartifacts / stage).as_uri() if uri == local_uri(layout) else None
    tags = {"mlflow.note.content": EXPERIMENT_DESCRIPTIONS[stage]} if stage in EXPERIMENT_DESCRIPTIONS else None
    try:
        return mlflow.create_experiment(name, artifact_location=location, tags=tags)
    except MlflowException:
        # another process created it between our lookup and create; if none did, the error stands
        created = mlflow.get_experiment_by_name(name)
        if created is None:
            raise
        return created.experiment_id


@contextmanager
def stage_run(
    layout: DataLayout, stage: str, run_name: str, tags: dict[str, str] | None = None, run_id: str | None = None
) -> Iterator[mlflow.ActiveRun]:
    """An MLflow run in the stage's experiment; ``run_id`` continues an earlier run (a resumed
    training keeps one run and one set of curves)."""
    import mlflow

    exp = experiment(layout, stage)
    if run_id is not None:
        with mlflow.start_run(run_id=run_id) as run:
            yield run
        return
    # a run of no single sweep seed (an ingest, a summary, the report) is tagged seed "all", so that
    # filtering MLflow's runs on the seed tag never drops one silently
    tags = {**provenance_tags(stage), "seed": "all", **(tags or {})}
    with mlflow.start_run(experiment_id=exp, run_name=run_name, tags=tags) as run:
        yield run


def provenance_tags(stage: str) -> dict[str, str]:
    """Tags of every run: its stage and the code that made it (the git commit where there is one)."""
    tags = {"stage": stage, "code": code_version()}
    if (commit := git_commit()) is not None:
        tags[GIT_COMMIT_TAG] = commit.removesuffix(" +changes")
    return tags


def resumable_run(
    layout: DataLayout, stage: str, folder: Path, run_name: str, tags: dict[str, str], params: dict
) -> str:
    """The run id of a training kept in ``folder``: the one recorded there (a resumed training
    continues its curves in the same run), else a new run with ``params``, recorded atomically."""
    import mlflow

    marker = folder / "mlflow_run.json"
    uri = tracking_uri(layout)
    if marker.is_file():
        saved = json.loads(marker.read_text())
        if saved.get("tracking_uri") == uri:
            return saved["run_id"]
    folder.mkdir(parents=True, exist_ok=True)
    with stage_run(layout, stage, run_name, tags) as run:
        mlflow.log_params(params)
    tmp = marker.with_suffix(".tmp")
    tmp.write_text(json.dumps({"run_id": run.info.run_id, "tracking_uri": uri}))
    tmp.replace(marker)
    return run.info.run_id


class UnloggedSteps:
    """Keeps, of each step's metrics, those the run does not hold yet at that step or later.

    A training resumed from its last checkpoint re-does the updates after it, and the run already
    holds their figures from before the crash. MLflow cannot replace logged values: logged again,
    each such step would be drawn twice and the curve would zigzag. The resumed curve continues
    from the last step the run holds."""

    def __init__(self, client: mlflow.MlflowClient, run_id: str) -> None:
        self.client, self.run_id = client, run_id
        self._last: dict[str, int] = {}

    def __call__(self, step: int, metrics: dict[str, float]) -> dict[str, float]:
        fresh = {}
        for name, value in metrics.items():
            if name not in self._last:
                self._last[name] = max((m.step for m in self.client.get_metric_history(self.run_id, name)), default=-1)
            if step > self._last[name]:
                fresh[name] = value
                self._last[name] = step
        return fresh


def step_logger(run_id: str, prefix: str = "") -> Callable[[int, dict[str, float]], None]:
    """``on_log(step, metrics)`` for a resumable training: logs ``prefix + name`` into ``run_id``
    (on the current tracking URI) for the steps the run does not hold yet (``UnloggedSteps``)."""
    import mlflow

    unlogged = UnloggedSteps(mlflow.MlflowClient(), run_id)

    def log(step: int, metrics: dict[str, float]) -> None:
        fresh = unlogged(step, {prefix + k: v for k, v in metrics.items()})
        if fresh:
            mlflow.log_metrics(fresh, step=step, run_id=run_id)

    return log


class RunWriter:
    """A teacher training's ``on_log`` (``log``) and ``on_checkpoint`` (``checkpoint``: an artefact
    under ``checkpoints/``) for one MLflow run, through an explicit client and run id, so trainings
    in parallel threads of one process never share MLflow's active-run state. Steps the run holds
    already are skipped (``UnloggedSteps``); a step's metrics go in one request (MLflow's batch
    limit is 1000)."""

    def __init__(self, run_id: str, tracking_uri: str) -> None:
        import mlflow

        self.run_id = run_id
        self.client = mlflow.MlflowClient(tracking_uri)
        self._unlogged = UnloggedSteps(self.client, run_id)

    def log(self, step: int, metrics: dict[str, float]) -> None:
        from mlflow.entities import Metric

        batch = [Metric(k, v, 0, step) for k, v in self._unlogged(step, metrics).items()]
        for i in range(0, len(batch), 1000):
            self.client.log_batch(self.run_id, metrics=batch[i : i + 1000])

    def checkpoint(self, path: str) -> None:
        self.client.log_artifact(self.run_id, path, "checkpoints")
