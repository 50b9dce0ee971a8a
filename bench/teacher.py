"""Where a teacher's PPO iteration goes: MuJoCo stepping, the objective's observation / reward /
reset work, policy inference, and the PPO update, for one task and method on demonstrator data;
the collection rate (env steps/s) next to the raw-rollout ceiling of bench/sim measured in the
same run (same model, N and substeps, commands precomputed, no Python in between).

    uv run python bench/teacher.py [--task pick] [--method touch2robot] [--n 200] [--steps 64]
                                   [--iterations 3] [--hidden 1024 1024 512]

Needs glove recordings: it synthesises, ingests and retargets one demonstration of the task
into a temporary data folder first (library calls, not timed).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import mujoco
import numpy as np
import torch
from mujoco import rollout
from rsl_rl.runners import OnPolicyRunner

sys.path.insert(0, str(Path(__file__).parent))
from sim import run_ceiling_per_step  # noqa: E402  (bench/sim.py)

from touch2robot import lake as lake_io  # noqa: E402
from touch2robot.contacts import ContactsConfig  # noqa: E402
from touch2robot.contacts.extract import human_contacts  # noqa: E402
from touch2robot.ingest import ingest_file, recording_rows  # noqa: E402
from touch2robot.retarget import LEAP_DEFAULT  # noqa: E402
from touch2robot.retarget.lake import load_hand_motion, write_result  # noqa: E402
from touch2robot.retarget.retargeter import Retargeter, retarget_motion  # noqa: E402
from touch2robot.settings import DataLayout  # noqa: E402
from touch2robot.sim.config import SimConfig  # noqa: E402
from touch2robot.synth.config import SynthConfig  # noqa: E402
from touch2robot.synth.generate import RecordingJob, write_recording  # noqa: E402
from touch2robot.teachers.config import PPOConfig, TeacherConfig  # noqa: E402
from touch2robot.teachers.objective import stack_references  # noqa: E402
from touch2robot.teachers.reference import load_reference  # noqa: E402
from touch2robot.teachers.train import make_teacher_env, runner_config  # noqa: E402


def demonstration(task: str, root: Path) -> dict:
    """One ingested, contact-labelled, retargeted glove demonstration of ``task``."""
    layout = DataLayout(root)
    config = SynthConfig(tasks=(task,), subjects=1, demos_per_subject=1, replays_per_task=0)
    ingest_file(write_recording(config, RecordingJob("glove_session", task, 1, 1), layout.recordings, layout.groundtruth), layout.lake)
    recording = recording_rows(layout.lake).to_pylist()[0]
    rows, _ = human_contacts(layout.lake, recording, ContactsConfig())
    lake_io.write_rows(layout.lake, "contacts", recording["recording_id"], rows, {"source": "human", "task": task})
    write_result(layout.lake, retarget_motion(load_hand_motion(layout.lake, recording["recording_id"]), LEAP_DEFAULT, Retargeter(LEAP_DEFAULT)))
    return recording


class Timed:
    """Wraps a callable and adds its wall time to a shared total."""

    def __init__(self, fn, totals: dict[str, float], key: str) -> None:
        self.fn, self.totals, self.key = fn, totals, key

    def __call__(self, *args, **kwargs):
        start = time.perf_counter()
        try:
            return self.fn(*args, **kwargs)
        finally:
            self.totals[self.key] += time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--task", default="pick")
    parser.add_argument("--method", default="touch2robot")
    parser.add_argument("--n", type=int, default=200)
    parser.add_argument("--steps", type=int, default=64, help="rollout length per env per iteration (Table VII: 512)")
    parser.add_argument("--iterations", type=int, default=3)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--hidden", type=int, nargs="+", default=[1024, 1024, 512])
    args = parser.parse_args()
    torch.set_num_threads(1)

    with tempfile.TemporaryDirectory() as tmp:
        recording = demonstration(args.task, Path(tmp) / "data")
        refs = stack_references([load_reference(DataLayout(Path(tmp) / "data").lake, recording)])
    config = TeacherConfig(
        sim=SimConfig(n_envs=args.n, threads=args.threads),
        ppo=PPOConfig(num_steps_per_env=args.steps, hidden_dims=tuple(args.hidden)),
    )
    vec_env = make_teacher_env(args.task, refs, config, args.method)
    totals: dict[str, float] = defaultdict(float)
    env, objective = vec_env.env, vec_env.objective
    env.step = Timed(env.step, totals, "physics (BatchEnv.step)")
    for name in ("observe", "reward", "terminated", "truncated", "reset", "command", "episode_end"):
        setattr(objective, name, Timed(getattr(objective, name), totals, "objective (obs, reward, resets)"))
    runner = OnPolicyRunner(vec_env, runner_config(config.ppo), log_dir=None, device="cpu")
    runner.alg.act = Timed(runner.alg.act, totals, "policy inference (act)")
    runner.alg.update = Timed(runner.alg.update, totals, "PPO update")
    runner.alg.compute_returns = Timed(runner.alg.compute_returns, totals, "returns (GAE)")
    runner.learn(1)  # warm-up: thread pools, allocations
    totals.clear()
    start = time.perf_counter()
    runner.learn(args.iterations)
    total = time.perf_counter() - start
    env_steps = args.n * args.steps * args.iterations

    # the ceiling: bench/sim's raw rollout of the same scene, N and substeps
    ceiling_env = vec_env.env
    datas = [mujoco.MjData(ceiling_env.model) for _ in range(args.threads)]
    pool = rollout.Rollout(nthread=args.threads if args.threads > 1 else 0)
    ceiling = max(run_ceiling_per_step(ceiling_env, args.steps, pool, datas) for _ in range(2))
    pool.close()
    ceiling_env.close()

    print(f"teacher {args.task}/{args.method}: N={args.n}, {args.steps} steps/env/iteration, hidden {args.hidden}, {args.iterations} iterations")
    print(f"PPO iteration: {1e3 * total / args.iterations:.0f} ms")
    accounted = 0.0
    for key, seconds in sorted(totals.items(), key=lambda kv: -kv[1]):
        accounted += seconds
        print(f"  {key:34s} {1e3 * seconds / args.iterations:8.0f} ms  {100 * seconds / total:5.1f} %")
    print(f"  {'rest (storage, logging, rsl-rl)':34s} {1e3 * (total - accounted) / args.iterations:8.0f} ms  {100 * (total - accounted) / total:5.1f} %")
    collect = total - totals["PPO update"] - totals["returns (GAE)"]
    rate = env_steps / collect
    print(f"collection: {rate:.0f} env steps/s; physics alone {env_steps / totals['physics (BatchEnv.step)']:.0f} env steps/s")
    print(f"ceiling (bench/sim raw rollout, same N): {ceiling:.0f} env steps/s")
    print(f"ratio collection / ceiling: {rate / ceiling:.2f}")


if __name__ == "__main__":
    main()
