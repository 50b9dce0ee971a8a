"""Each task's reference success (`touch2robot sim check`): the kinematic replay of every
retargeted demonstration of a data folder in MuJoCo, one BatchEnv per task, with the replay speed
(env steps/s: copies x control steps over the replay's wall time; loading the references is timed
apart).

    uv run python bench/sim_check.py DATA [--profile local] [--task rotate ...]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from touch2robot.config import load_profile
from touch2robot.settings import DataLayout
from touch2robot.teachers.check import REFERENCE_TARGET, replay_references, summarize, task_references


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("data", type=Path, help="data folder with retargeted demonstrations")
    parser.add_argument("--profile", default="local")
    parser.add_argument("--task", action="append", help="task to check (repeatable; default the profile's)")
    args = parser.parse_args()
    teacher = load_profile(args.profile).teacher
    sim = teacher.sim
    lake = DataLayout(args.data).lake
    tasks = args.task or list(teacher.tasks)
    print(
        f"{args.data} ({args.profile}): {sim.substeps} x {sim.timestep} s substeps per control step "
        f"({sim.control_hz:g} Hz), {sim.threads} threads, {os.cpu_count()} CPUs, target {REFERENCE_TARGET:.2f}"
    )
    all_passed = True
    for task in tasks:
        start = time.perf_counter()
        refs = task_references(lake, task, teacher)
        load_s = time.perf_counter() - start
        if refs is None:
            print(f"{task:8s} no retargeted demonstrations")
            all_passed = False
            continue
        start = time.perf_counter()
        rows = replay_references(refs, task, sim, teacher)
        replay_s = time.perf_counter() - start
        (summary,) = summarize(rows, [task])
        assert summary.rate is not None  # rows of every demonstration of refs
        all_passed &= summary.passed
        env_steps = len(refs.ids) * (int(refs.length.max()) - 1)
        print(
            f"{task:8s} success {summary.successes}/{summary.demonstrations} = {summary.rate:.2f} "
            f"({'pass' if summary.passed else 'FAIL'})   replay {env_steps / replay_s:7.0f} env steps/s "
            f"({env_steps} in {replay_s:.2f} s; references loaded in {load_s:.2f} s)"
        )
    print(f"every task at or above {REFERENCE_TARGET:.2f}: {'yes' if all_passed else 'no'}")


if __name__ == "__main__":
    main()
