"""What a cached re-run costs: the pipeline run twice on a fresh data folder, as a user runs it.

    uv run python bench/rerun.py [--profile smoke] [--data FOLDER]

Runs ``touch2robot run -p PROFILE --data FOLDER`` twice (FOLDER: a new temporary folder, removed
afterwards, unless given) and prints the first run's and the re-run's wall time, the re-run's
Prefect API start (from its log: "Prefect API answered ... after its start", app/local_server.py),
and (re-run - API start) / first run against the target of 0.05 (issue 34, item 13). Also the
re-run's task states and the process pools it started (a cached re-run should start none).

The commands run without PYTHONDONTWRITEBYTECODE: an installed environment caches its bytecode, and
without that cache every process compiles its imports again (about 10 s a run on 2 cores)."""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

TARGET = 0.05
API_READY = re.compile(r"Prefect API answered ([0-9.]+) s after its start")
TASK_STATE = re.compile(r"prefect\.task_runs: Finished in state (\w+)")


def run_pipeline(profile: str, data: Path, env: dict[str, str]) -> tuple[float, Path]:
    """Wall time of one ``touch2robot run``, and the log file it wrote."""
    logs = data / "logs"
    before = set(logs.glob("run-*.log")) if logs.exists() else set()
    started = time.perf_counter()
    proc = subprocess.run(
        [str(Path(sys.executable).with_name("touch2robot")), "run", "-p", profile, "--data", str(data)],
        env=env,
        capture_output=True,
        text=True,
    )
    elapsed = time.perf_counter() - started
    if proc.returncode != 0:
        raise SystemExit(f"touch2robot run failed ({proc.returncode}):\n{proc.stdout[-4000:]}\n{proc.stderr[-4000:]}")
    (log,) = set(logs.glob("run-*.log")) - before
    return elapsed, log


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--profile", default="smoke")
    parser.add_argument("--data", type=Path, help="an empty or new data folder, kept afterwards")
    args = parser.parse_args()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONDONTWRITEBYTECODE", "PREFECT_API_URL")}
    data = args.data or Path(tempfile.mkdtemp(prefix="touch2robot-rerun-"))
    try:
        first, _ = run_pipeline(args.profile, data, env)
        print(f"first run   {first:6.1f} s", flush=True)
        rerun, log = run_pipeline(args.profile, data, env)
        text = log.read_text()
        ready = API_READY.search(text)
        api = float(ready.group(1)) if ready else 0.0
        states = Counter(TASK_STATE.findall(text))
        pools = text.count("fan-out on ProcessPoolTaskRunner") + text.count("fan-out on DaskTaskRunner")
        ratio = (rerun - api) / first
        print(f"re-run      {rerun:6.1f} s   (task runs {dict(states)}; {pools} process pools or clusters started)")
        print(f"API start   {api:6.1f} s   " + ("" if ready else "(no own server: PREFECT_API_URL?)"))
        verdict = "meets" if ratio <= TARGET else "misses"
        print(f"(re-run - API start) / first run = {ratio:.3f}: {verdict} the target of {TARGET}")
    finally:
        if args.data is None:
            shutil.rmtree(data, ignore_errors=True)


if __name__ == "__main__":
    main()
