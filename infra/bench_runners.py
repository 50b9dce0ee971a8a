"""Measure the ingest fan-out under each task runner kind on this machine.

    uv run python infra/bench_runners.py --recordings data/recordings [--profile local]

Each kind runs in a fresh process on a fresh copy of the recordings (so no cache hits),
after a warm-up flow has started Prefect's API, so the figure is the ingest flow run
itself: fan-out plus the runner's own start-up (a LocalCluster's is part of every run).
This is the measurement behind the default of ``RunnerConfig``; re-run it on a new
machine or cluster before changing a profile's ``runner`` section."""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

KINDS = {
    "serial": {"kind": "threads", "max_workers": 1},
    "threads": {"kind": "threads", "max_workers": 2},
    "processes": {"kind": "processes", "max_workers": 2},
    "dask": {"kind": "dask", "n_workers": 2, "threads_per_worker": 1},
}


def run_one(kind: str, profile: str, data: Path) -> dict:
    """Run the ingest flow once under one runner (in this process) and time it."""
    # flows first: importing it configures the environment before Prefect reads its settings
    from flows.ingest import ingest  # noqa: I001
    from prefect import flow
    from tasks.runners import ProfileTaskRunner
    from touch2robot.runner_config import RunnerConfig

    @flow
    def warm_up() -> None:
        """Starts the API (ephemeral server or client) outside the timed run."""

    warm_up()
    runner = ProfileTaskRunner(RunnerConfig(**KINDS[kind]))
    t0 = time.perf_counter()
    result = ingest.with_options(task_runner=runner)(profile=profile, data=str(data))
    return {"kind": kind, "seconds": round(time.perf_counter() - t0, 1), "files": result["files"], "ingested": result["ingested"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--recordings", type=Path, help="folder of MCAP recordings to ingest (copied per run)")
    parser.add_argument("--profile", default="local", help="profile whose contacts settings the ingest uses")
    parser.add_argument("--kinds", default=",".join(KINDS), help=f"comma-separated subset of {', '.join(KINDS)}")
    parser.add_argument("--repeat", type=int, default=1, help="rounds over the kinds (interleaved, so background load hits all alike)")
    parser.add_argument("--one", choices=KINDS, help=argparse.SUPPRESS)
    parser.add_argument("--data", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(run_one(args.one, args.profile, args.data)))
        return
    if args.recordings is None:
        parser.error("--recordings is required")
    rows = []
    for kind in [k for _ in range(args.repeat) for k in args.kinds.split(",")]:
        with tempfile.TemporaryDirectory(prefix=f"bench-{kind}-") as tmp:
            data = Path(tmp)
            shutil.copytree(args.recordings, data / "recordings")
            env = {
                **os.environ,
                "TOUCH2ROBOT_DATA": str(data),
                "PREFECT_HOME": str(data / "prefect"),
                "PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS": "120",
            }
            env.pop("PREFECT_API_URL", None)  # every kind against the same kind of API: the embedded one
            out = subprocess.run(
                [sys.executable, __file__, "--one", kind, "--profile", args.profile, "--data", str(data)],
                env=env, capture_output=True, text=True, check=True,
            )
            rows.append({**json.loads(out.stdout.strip().splitlines()[-1]), "load_1min": round(os.getloadavg()[0], 1)})
            print(json.dumps(rows[-1]), flush=True)
    print("\n| runner | ingest flow run (s), each round | files |\n|---|---|---|")
    for kind in args.kinds.split(","):
        seconds = [r["seconds"] for r in rows if r["kind"] == kind]
        print(f"| {kind} | {', '.join(map(str, seconds))} | {rows[0]['files']} |")


if __name__ == "__main__":
    main()
