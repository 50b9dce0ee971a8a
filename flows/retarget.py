"""Flow `retarget`: every ingested glove recording's hand motion -> LEAP joint trajectories
(``retargeted`` table), MLflow runs (stage "retarget"), a comparison drawing per task."""

from __future__ import annotations

from prefect import flow, unmapped

from tasks.common import stored
from tasks.ingest import refresh_catalog
from tasks.retarget import report_retarget, retarget_recording
from tasks.runners import ProfileTaskRunner
from touch2robot.config import load_profile
from touch2robot.datasets import RETARGETED, glove_sessions
from touch2robot.settings import DataLayout


@flow(name="retarget", task_runner=ProfileTaskRunner(), log_prints=True)
def retarget(profile: str = "smoke", data: str | None = None) -> dict:
    """Retarget every ingested glove recording of the data folder with the profile's
    ``retarget`` section; draw the first recording of each task."""
    layout = DataLayout.from_env(data)
    config = load_profile(profile).retarget
    gloves = glove_sessions(layout.lake)
    first = {}
    for r in gloves:
        first.setdefault(r["task"], r["recording_id"])
    render = [first[r["task"]] == r["recording_id"] for r in gloves]
    futures = stored(retarget_recording, layout.results).map(
        gloves, unmapped(config), unmapped(str(layout.root)), unmapped(profile), render
    )
    results = [f.result() for f in futures]
    refresh_catalog(str(layout.root))
    summary = report_retarget(profile, results)
    print(
        f"retarget: {summary['recordings']} recordings, {summary['frames']} frames, {summary['failed_frames']} failed, "
        f"mean fingertip residual {summary['residual_mean_mm']:.2f} mm "
        f"-> {RETARGETED.folder(layout.lake)}"
    )
    return summary
