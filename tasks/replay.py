"""Tasks of the replay stage: execute one method's robot trajectory on the hardware twin (writing the
robot replay and its calibration as the rig would), record what was replayed or skipped, report."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
from prefect import get_run_logger, task
from prefect.artifacts import create_markdown_artifact, create_table_artifact

from schemas.tables import SCHEMAS
from tasks.common import ALWAYS_RUN, cache_policy
from touch2robot.datasets import EVALUATION_IDS
from touch2robot.evaluate import replace_table
from touch2robot.sim.config import SimConfig
from touch2robot.twin.config import TwinConfig
from touch2robot.twin.plan import ReplayJob, Skipped

TWIN = "twin"  # what executed a replay (the replays table's rig column); its recordings name the rig file RIG
REPLAY_MODULES = (
    "touch2robot.twin",
    "touch2robot.sim",
    "touch2robot.scenes",
    "touch2robot.leap",
    "touch2robot.recording",
    "touch2robot.geometry",
)
REPLAYED, SKIPPED, FAILED = "replayed", "skipped", "failed"


@task(
    cache_policy=cache_policy(*REPLAY_MODULES),
    persist_result=True,
    retries=1,  # lost physics is a row, not an error: what is retried is the rest (a full disk, say)
    task_run_name="replay-{jobs[0].task}-{jobs[0].method}-seed{jobs[0].seed}",
)
def replay_on_twin(
    jobs: list[ReplayJob], rollouts_digest: str, sim: SimConfig, twin: TwinConfig, seed: int
) -> list[dict]:
    """Execute the trajectories of one rollouts file (one task x method x sweep seed) open loop on the twin, one
    after another, each one's physics overlapping the writing of the one before; write each robot replay and
    calibration MCAP next to the glove session it follows. ``rollouts_digest`` (the file's content) keys the
    cache on the trajectories; ``seed`` is the sweep seed's ``replay.seed`` (the rest of that section chose the
    jobs). A replay that loses physics, or whose rows are not a rollout, is a ``failed`` row with the reason;
    the others go on."""
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    from touch2robot.sim.guard import LostPhysicsError
    from touch2robot.twin.replay import RIG, ReplayOutcome, ReplayRequest, replay_rollouts

    table = pq.read_table(jobs[0].rollouts_file)
    requests = (
        ReplayRequest(
            table.filter(pc.field("rollout_id") == job.trajectory).sort_by("step"),
            job.twin_seed(seed),
            job.replay_path,
            job.calibration_path,
            job.metadata(RIG.name),
        )
        for job in jobs
    )
    rows = []
    for job, outcome in zip(jobs, replay_rollouts(requests, sim, twin), strict=True):
        row = _job_row(job)
        if not isinstance(outcome, ReplayOutcome):
            what = "lost physics" if isinstance(outcome, LostPhysicsError) else "bad rollout"
            get_run_logger().warning("replay %s of %s on %s failed: %s", job.trajectory, job.method, job.task, outcome)
            rows.append(
                row | {"status": FAILED, "reason": f"{what}: {outcome}", "replay_file": None, "calibration_file": None}
            )
            continue
        rows.append(
            row
            | {
                "duration_s": outcome.duration_s,
                "peak_force": list(outcome.peak_region_force),
                "contact_fraction": list(outcome.contact_fraction),
                "perturbation": json.dumps(outcome.perturbation, sort_keys=True),
            }
        )
    return rows


def _row(task_name: str, method: str, seed: int, status: str, reason: str, **values: object) -> dict:
    """A ``replays`` row: the given columns, NULL elsewhere."""
    return dict.fromkeys(SCHEMAS["replays"].names) | {
        "task": task_name,
        "method": method,
        "seed": seed,
        "status": status,
        "reason": reason,
        "rig": TWIN,
        **values,
    }


def _job_row(job: ReplayJob) -> dict:
    return _row(
        job.task,
        job.method,
        job.seed,
        REPLAYED,
        "",
        origin=job.origin,
        trajectory=job.trajectory,
        reference_id=job.reference_id,
        replay_file=job.replay_path.name,
        calibration_file=job.calibration_path.name,
    )


def skipped_rows(skipped: list[Skipped], seed: int) -> list[dict]:
    """``replays`` rows of what sweep seed ``seed`` had nothing to replay."""
    return [_row(s.task, s.method, seed, SKIPPED, s.reason) for s in skipped]


@task(**ALWAYS_RUN)
def store_replays(lake: str, rows: list[dict]) -> list[str]:
    """Make ``rows`` the whole ``replays`` table (one file per task x method x seed). Runs every time, like the
    evaluation tables: the table says what this run's replays are."""
    frame = pd.DataFrame(rows, columns=SCHEMAS["replays"].names)
    return replace_table(Path(lake), "replays", frame, EVALUATION_IDS["replays"].columns)


@task(**ALWAYS_RUN)
def report_replays(profile: str, rows: list[dict]) -> list[dict]:
    """A Prefect table per task x method x seed (replayed, skipped, failed, the reasons) and the log's summary."""
    logger = get_run_logger()
    summary: dict[tuple[str, str, int], dict] = {}
    for r in rows:
        s = summary.setdefault(
            (r["task"], r["method"], r["seed"]),
            {
                "task": r["task"],
                "method": r["method"],
                "seed": r["seed"],
                REPLAYED: 0,
                SKIPPED: 0,
                FAILED: 0,
                "reasons": [],
            },
        )
        s[r["status"]] += 1
        if r["reason"] and r["reason"] not in s["reasons"]:
            s["reasons"].append(r["reason"])
    table = [s | {"reasons": "; ".join(s["reasons"])} for s in summary.values()]
    for s in table:
        if s[SKIPPED] or s[FAILED]:
            logger.warning(
                "replay %s/%s seed %d: %d skipped, %d failed: %s",
                *(s["task"], s["method"], s["seed"], s[SKIPPED], s[FAILED], s["reasons"]),
            )
    create_table_artifact(
        key="replays", table=table, description=f"Robot replays on the hardware twin per task x method ({profile})"
    )
    lines = [
        f"| {s['task']} | {s['method']} | {s['seed']} | {s[REPLAYED]} | {s[SKIPPED]} | {s[FAILED]} | {s['reasons']} |"
        for s in table
    ]
    create_markdown_artifact(
        key="replays-summary",
        markdown=f"# Replays on the hardware twin ({profile})\n\n"
        "| task | method | seed | replayed | skipped | failed | why |\n|---|---|---|---|---|---|---|\n"
        + "\n".join(lines)
        + "\n",
    )
    return table
