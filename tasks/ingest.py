"""Tasks of ingestion and contact extraction."""

from __future__ import annotations

import json
import tempfile
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
from prefect import get_run_logger, task
from prefect.artifacts import create_markdown_artifact, create_table_artifact

from schemas.tables import ROBOT_REGIONS
from schemas.vocabulary import RecordingStatus, Source
from tasks import tracking
from tasks.common import ALWAYS_RUN, cache_policy
from touch2robot import catalog, datasets
from touch2robot import lake as lake_io
from touch2robot.contacts import ContactsConfig
from touch2robot.contacts.extract import human_contacts, replay_contacts
from touch2robot.ingest import ingest_file, recording_rows, superseded_ids
from touch2robot.ingest.rigs import rigs_from
from touch2robot.settings import DataLayout


@task(
    cache_policy=cache_policy("touch2robot.ingest", "touch2robot.recording", "touch2robot.lake"),
    persist_result=True,
    retries=1,
    task_run_name="ingest-{content_sha:.12}",
)
def ingest_recording(
    path: str, content_sha: str, lake: str, session: dict[str, str] | None = None, rigs: dict[str, dict] | None = None
) -> dict:
    """Ingest one recording (keyed by its content hash, sidecar included, the command line's session
    fields and the rigs' definitions) into the lake."""
    result = ingest_file(Path(path), Path(lake), session, rigs_from(rigs) if rigs else None)
    if result.status == RecordingStatus.QUARANTINED:
        get_run_logger().warning("quarantined %s: %s", path, result.reason)
    return asdict(result)


@task(**ALWAYS_RUN)
def remove_superseded(lake: str, current: dict[str, str]) -> list[str]:
    """Drop the rows of earlier versions of files whose content changed."""
    stale = superseded_ids(Path(lake), current)
    for rid in stale:
        lake_io.remove_id(Path(lake), rid)
    return stale


@task(
    cache_policy=cache_policy("touch2robot.contacts", "touch2robot.lake", "touch2robot.datasets"),
    persist_result=True,
    task_run_name="human-contacts-{recording[recording_id]}",
)
def extract_human_contacts(recording: dict, config: ContactsConfig, lake: str) -> dict:
    """Human contacts + glove thresholds of one glove session."""
    rows, thresholds = human_contacts(Path(lake), recording, config)
    rid = recording["recording_id"]
    datasets.CONTACTS.write(Path(lake), datasets.RecordingKey(rid), rows, source=Source.HUMAN, task=recording["task"])
    datasets.LAKE["thresholds"].write(Path(lake), datasets.RecordingKey(rid), thresholds)
    return {"recording_id": rid, "rows": rows.num_rows, "thresholds": thresholds.to_pylist()}


@task(
    cache_policy=cache_policy("touch2robot.contacts", "touch2robot.lake", "touch2robot.datasets"),
    persist_result=True,
    task_run_name="real-contacts-{replay[recording_id]}",
)
def extract_real_contacts(
    replay: dict, calibration_id: str, reference: dict | None, config: ContactsConfig, lake: str
) -> dict:
    """Real-robot contacts + TwinTac/FSR thresholds of one replay."""
    rows, thresholds = replay_contacts(Path(lake), replay, calibration_id, reference, config)
    rid = replay["recording_id"]
    rows = datasets.with_seed(rows, replay.get("seed"))
    datasets.CONTACTS.write(Path(lake), datasets.RecordingKey(rid), rows, source=Source.REAL, task=replay["task"])
    datasets.LAKE["thresholds"].write(Path(lake), datasets.RecordingKey(rid), thresholds)
    return {"recording_id": rid, "rows": rows.num_rows}


@task(**ALWAYS_RUN, retries=2, retry_delay_seconds=2)
def refresh_catalog(data: str) -> list[str]:
    """Recreate the DuckDB views over the lake (waits for the single-writer lock)."""
    return catalog.refresh(DataLayout.from_env(data))


def _timeline_png(lake: Path, recording: dict, out: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = pq.read_table(datasets.human_contacts(lake, recording)).to_pandas()
    fig, ax = plt.subplots(figsize=(9, 3.2))
    for k, region in enumerate(ROBOT_REGIONS):
        r = rows[rows.region == region]
        ax.fill_between(r.t, k + 0.1, k + 0.1 + 0.8 * r.contact.astype(float), step="mid", color=f"C{k}")
    ax.set_yticks(np.arange(len(ROBOT_REGIONS)) + 0.5, ROBOT_REGIONS)
    ax.set_xlabel("time (s)")
    ax.set_title(f"human contacts — {Path(recording['path']).name}")
    fig.tight_layout()
    path = out / f"contact_timeline_{Path(recording['path']).stem}.png"
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


@task(cache_policy=cache_policy("tasks.tracking"), persist_result=True)
def report_ingest(data: str, profile: str, results: list[dict], contact_summaries: list[dict]) -> str:
    """MLflow run (counts, quarantined files, thresholds, contact timelines) and a Prefect
    artefact summarising the ingest flow run. Cached on what it reports: a re-run whose every file and
    contact task was a cache hit reports the same figures, and adds no second MLflow run of them."""
    layout = DataLayout.from_env(data)
    recordings = {r["recording_id"]: r for r in recording_rows(layout.lake).to_pylist()}
    statuses = [r["status"] for r in results]
    quarantined = [r for r in results if r["status"] == RecordingStatus.QUARANTINED]
    with tracking.stage_run(layout, "ingest", f"ingest-{profile}", {"profile": profile}) as run:
        import mlflow

        mlflow.log_metrics(
            {
                "files": len(results),
                "ingested": statuses.count(RecordingStatus.INGESTED),
                "unchanged": statuses.count(RecordingStatus.UNCHANGED),
                "quarantined": len(quarantined),
                "rows": sum(r["rows"] for r in results),
                "contact_rows": sum(c["rows"] for c in contact_summaries),
            }
        )
        mlflow.log_dict(
            {"quarantined": [{"path": q["path"], "reason": q["reason"]} for q in quarantined]}, "quarantined.json"
        )
        thresholds = {c["recording_id"]: c["thresholds"] for c in contact_summaries if "thresholds" in c}
        mlflow.log_dict(thresholds, "glove_thresholds.json")
        for rid, rows in thresholds.items():
            for row in rows:
                mlflow.log_metric(f"threshold_{row['applies_to']}_{rid}", row["threshold"])
        with tempfile.TemporaryDirectory() as tmp:
            for rid in thresholds:
                if rid in recordings:
                    mlflow.log_artifact(
                        str(_timeline_png(layout.lake, recordings[rid], Path(tmp))), "contact_timelines"
                    )
        run_id = run.info.run_id
    create_table_artifact(
        key="ingest-files",
        table=[
            {
                "file": Path(r["path"]).name,
                "status": r["status"],
                "kind": r["kind"],
                "rows": r["rows"],
                "reason": r["reason"],
            }
            for r in results
        ],
        description="Files seen by the ingest flow run",
    )
    create_markdown_artifact(
        key="ingest-summary",
        markdown=(
            f"# Ingest ({profile})\n\n| files | ingested | unchanged | quarantined |\n|---|---|---|---|\n"
            f"| {len(results)} | {statuses.count('ingested')} | {statuses.count('unchanged')} | "
            f"{len(quarantined)} |\n\n"
            + "".join(f"- quarantined `{Path(q['path']).name}`: {q['reason']}\n" for q in quarantined)
            + f"\nMLflow run `{run_id}`; catalog `{layout.catalog}`\n"
        ),
    )
    return json.dumps({"run_id": run_id, "quarantined": len(quarantined)})
