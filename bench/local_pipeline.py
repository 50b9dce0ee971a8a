"""Where the local comparison's time goes: every stage of a profile, one ``touch2robot`` command each,
timed on a fresh data folder (issue 29: the whole local run, policies included, in <= 2 hours on 2 cores).

    uv run python bench/local_pipeline.py [--profile local] [--data FOLDER] [--from STAGE] [--to STAGE]

Runs ``touch2robot synth``, ``ingest``, ``retarget``, ``teachers``, ``student``, ``replay``, ``evaluate``,
``policy`` and ``report`` in that order (what ``touch2robot run`` does as one flow) and prints each stage's
wall time, its share of the total, and the total against the 2-hour target. Each command also starts the
data folder's Prefect API (a few seconds, counted in its stage). A stage's time goes to
``<data>/bench/local_pipeline.json`` as soon as it ends, so a run split over several calls (``--from``,
``--to``) still prints the whole table; a stage run again replaces its time. FOLDER defaults to a new
temporary folder, kept afterwards (it holds the results)."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

STAGES = ("synth", "ingest", "retarget", "teachers", "student", "replay", "evaluate", "policy", "report")
TARGET_S = 2 * 3600.0


def timings_file(data: Path) -> Path:
    return data / "bench" / "local_pipeline.json"


def run_stage(stage: str, profile: str, data: Path, env: dict[str, str]) -> float:
    """Wall time of one stage command; its output goes to <data>/bench/<stage>.log."""
    log = data / "bench" / f"{stage}.log"
    log.parent.mkdir(parents=True, exist_ok=True)
    command = [str(Path(sys.executable).with_name("touch2robot")), stage, "-p", profile, "--data", str(data)]
    started = time.perf_counter()
    with open(log, "w") as out:
        proc = subprocess.run(command, env=env, stdout=out, stderr=subprocess.STDOUT)
    elapsed = time.perf_counter() - started
    if proc.returncode != 0:
        raise SystemExit(f"touch2robot {stage} failed ({proc.returncode}); its output: {log}")
    return elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--profile", default="local")
    parser.add_argument("--data", type=Path, help="the data folder (default: a new temporary one, kept)")
    parser.add_argument("--from", dest="first", choices=STAGES, default=STAGES[0], help="first stage to run")
    parser.add_argument("--to", dest="last", choices=STAGES, default=STAGES[-1], help="last stage to run")
    args = parser.parse_args()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONDONTWRITEBYTECODE", "PREFECT_API_URL")}
    data = (args.data or Path(tempfile.mkdtemp(prefix="touch2robot-local-pipeline-"))).resolve()
    record = timings_file(data)
    times: dict[str, float] = json.loads(record.read_text()) if record.is_file() else {}
    print(f"profile {args.profile}, data folder {data}", flush=True)
    for stage in STAGES[STAGES.index(args.first) : STAGES.index(args.last) + 1]:
        times[stage] = run_stage(stage, args.profile, data, env)
        record.parent.mkdir(parents=True, exist_ok=True)
        tmp = record.with_suffix(".tmp")
        tmp.write_text(json.dumps(times, indent=1))
        tmp.replace(record)
        print(f"  {stage:<9} {times[stage] / 60:7.1f} min", flush=True)
    total = sum(times.values())
    print(f"\n{'stage':<9} {'min':>7} {'share':>6}")
    for stage in STAGES:
        if stage in times:
            print(f"{stage:<9} {times[stage] / 60:7.1f} {times[stage] / total:6.1%}")
        else:
            print(f"{stage:<9} {'not run':>7}")
    missing = [s for s in STAGES if s not in times]
    print(f"total     {total / 60:7.1f} min" + (f" (without {', '.join(missing)})" if missing else ""))
    verdict = "meets" if total <= TARGET_S and not missing else ("misses" if total > TARGET_S else "so far within")
    print(f"total / 2 h target = {total / TARGET_S:.2f}: {verdict} the target")


if __name__ == "__main__":
    main()
