"""Flow `ingest`: MCAP recordings -> Parquet lake -> contacts -> DuckDB catalog."""

from __future__ import annotations

from pathlib import Path

from prefect import flow, get_run_logger, unmapped

from schemas.vocabulary import RecordingStatus
from tasks.common import stored
from tasks.ingest import (
    extract_human_contacts,
    extract_real_contacts,
    ingest_recording,
    refresh_catalog,
    remove_superseded,
    report_ingest,
)
from tasks.runners import ProfileTaskRunner
from touch2robot import datasets
from touch2robot.config import load_profile
from touch2robot.ingest import link_replays, recording_digest, recording_rows
from touch2robot.ingest.rigs import checked_rigs
from touch2robot.ingest.scan import folder_state
from touch2robot.settings import DataLayout


@flow(name="ingest", task_runner=ProfileTaskRunner(), log_prints=True)
def ingest(
    profile: str = "smoke",
    data: str | None = None,
    folder: str | None = None,
    session: dict[str, str] | None = None,
    rig_files: list[str] | None = None,
) -> dict:
    """Ingest every recording under ``folder`` (default ``<data>/recordings``): MCAP files and rosbag2
    folders; ``session`` gives the session fields a recording's own sources lack; each recording is read
    with the rig it names (``*.rig.yaml`` in the folder, or ``rig_files``), every rig checked before any
    file is ingested. Bad files are quarantined with a reason; contacts and thresholds are extracted; the
    catalog is refreshed."""
    layout = DataLayout.from_env(data)
    config = load_profile(profile).contacts
    lake = str(layout.lake)
    recordings = Path(folder or layout.recordings)
    rigs = checked_rigs(recordings, rig_files or [], session or {}).definitions()
    state = folder_state(recordings)  # before the reading: a file changed during it moves the state
    scan = datasets.recording_files(recordings)
    for entry, why in scan.skipped:
        get_run_logger().warning("skipped %s: %s", entry, why)
    paths = [str(p) for p in scan.recordings]
    digests = [recording_digest(Path(p)) for p in paths]
    results = [
        f.result()
        for f in stored(ingest_recording, layout.results).map(
            paths, digests, unmapped(lake), unmapped(session or {}), unmapped(rigs)
        )
    ]
    current = {r["path"]: r["recording_id"] for r in results if r["status"] != RecordingStatus.QUARANTINED}
    remove_superseded(lake, current)
    gloves, links, problems = link_replays(recording_rows(layout.lake).to_pylist())
    for line in problems:
        get_run_logger().warning(line)
    human = stored(extract_human_contacts, layout.results).map(gloves, unmapped(config), unmapped(lake))
    real = stored(extract_real_contacts, layout.results).map(
        [link.replay for link in links],
        [link.calibration_id for link in links],
        [link.reference for link in links],
        unmapped(config),
        unmapped(lake),
    )
    summaries = [f.result() for f in human] + [f.result() for f in real]
    refresh_catalog(str(layout.root))
    report = report_ingest(str(layout.root), profile, results, summaries)
    counts = {status.value: sum(r["status"] == status for r in results) for status in RecordingStatus}
    print(f"ingest: {counts} -> {layout.catalog}")
    # what was ingested: the folder in this state, as is (no session fields or rig files given)
    as_found = state if not (session or rig_files) else None
    return {**counts, "skipped": len(scan.skipped), "files": len(results), "report": report, "folder_state": as_found}
