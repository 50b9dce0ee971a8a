"""Flow `replay`: each method's robot trajectories executed open loop on the hardware twin -> robot replay
and calibration MCAPs in the recordings folder (as the rig writes them) -> the normal ingest -> real
contacts; the ``replays`` table says what was replayed or skipped and why."""

from __future__ import annotations

from pathlib import Path

from prefect import flow

from flows.ingest import ingest
from tasks.common import stored
from tasks.ingest import refresh_catalog
from tasks.replay import FAILED, REPLAYED, SKIPPED, replay_on_twin, report_replays, skipped_rows, store_replays
from tasks.runners import ProfileTaskRunner
from touch2robot.config import load_profile
from touch2robot.datasets import file_digest
from touch2robot.ingest.scan import folder_state
from touch2robot.settings import DataLayout
from touch2robot.twin.plan import ReplayJob, plan_replays


@flow(name="replay", task_runner=ProfileTaskRunner(), log_prints=True)
def replay(
    profile: str = "smoke",
    data: str | None = None,
    tasks: list[str] | None = None,
    methods: list[str] | None = None,
    seeds: list[int] | None = None,
    ingested_state: str | None = None,
) -> dict:
    """Replay the profile's ``replay`` section (``tasks`` x ``methods``, default all) of every sweep seed
    (``seeds``, default the profile's) on the twin of its ``twin`` section, then ingest the recordings so
    that their measured contacts reach the lake. ``ingested_state``: the ``folder_state`` an ingest of this
    run returned for ``<data>/recordings`` (the pipeline's); a folder still in it is not ingested again."""
    layout = DataLayout.from_env(data)
    settings = load_profile(profile)
    run = stored(replay_on_twin, layout.results)
    jobs, futures, rows = [], [], []
    for seed in settings.sweep(seeds):
        config = settings.for_seed(seed).replay
        config = config.model_copy(
            update={"tasks": tuple(tasks or config.tasks), "methods": tuple(methods or config.methods)}
        )
        seed_jobs, skipped = plan_replays(layout.lake, layout.recordings, config, seed)
        # one task run per rollouts file (task x method): its replays run back to back, physics overlapping writing
        batches: dict[str, list[ReplayJob]] = {}
        for job in seed_jobs:
            batches.setdefault(job.rollouts_file, []).append(job)
        futures += [
            run.submit(batch, file_digest(path), settings.teacher.sim, settings.twin, config.seed)
            for path, batch in batches.items()
        ]
        jobs += seed_jobs
        rows += skipped_rows(skipped, seed)
    rows = [row for f in futures for row in f.result()] + rows
    store_replays(str(layout.lake), rows)
    table = report_replays(profile, rows)
    for s in table:
        why = f" ({s['reasons']})" if s["reasons"] else ""
        print(
            f"replay: {s['task']:7s} {s['method']:16s} seed {s['seed']} {s[REPLAYED]} replayed, {s[SKIPPED]} skipped, "
            f"{s[FAILED]} failed{why}"
        )
    # the data folder's recordings, and any other folder a glove session was ingested from (`ingest --folder`):
    # its replays were written beside it
    recordings = layout.recordings.resolve()
    elsewhere = sorted({j.folder for j in jobs if not Path(j.folder).is_relative_to(recordings)})
    unchanged = ingested_state is not None and folder_state(recordings) == ingested_state
    if unchanged:  # no replay wrote a file (all were cached): ingesting again would find what the last ingest did
        print(f"replay: {recordings} unchanged since this run's ingest, not ingested again")
        refresh_catalog(str(layout.root))  # the replays table's view
    folders = ([None] if recordings.is_dir() and not unchanged else []) + elsewhere
    ingested = [ingest(profile=profile, data=data, folder=folder) for folder in folders]
    return {
        REPLAYED: sum(r["status"] == REPLAYED for r in rows),
        SKIPPED: sum(r["status"] == SKIPPED for r in rows),
        FAILED: sum(r["status"] == FAILED for r in rows),
        "by_task_method": table,
        "ingest": ingested,  # one result per folder ingested
    }
