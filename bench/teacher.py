"""Where a teacher's PPO iteration goes: MuJoCo stepping, the objective's observation / reward /
reset work, policy inference, and the PPO update, for one task and method on demonstrator data;
the collection rate (env steps/s) next to the raw-rollout ceiling measured in the same run the
way bench/sim measures it: MuJoCo's multithreaded rollout, one call per control step, replaying
the very states and commands the collection produced, with no Python work in between.

    uv run python bench/teacher.py [--task pick] [--method touch2robot] [--n 200] [--steps 64]
                                   [--iterations 3] [--hidden 1024 1024 512]

Needs glove recordings: it synthesises, ingests and retargets one demonstration of the task
into a temporary data folder first (library calls, not timed).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import mujoco
import numpy as np
import torch
from mujoco import rollout
from rsl_rl.runners import OnPolicyRunner

from touch2robot import lake as lake_io
from touch2robot.contacts import ContactsConfig
from touch2robot.contacts.extract import human_contacts
from touch2robot.ingest import ingest_file, recording_rows
from touch2robot.retarget import LEAP_DEFAULT
from touch2robot.retarget.lake import load_hand_motion, result_rows
from touch2robot.retarget.retargeter import Retargeter, retarget_motion
from touch2robot.settings import DataLayout
from touch2robot.sim.config import SimConfig
from touch2robot.sim.env import CONTROL_SPEC, BatchEnv
from touch2robot.synth.config import SynthConfig
from touch2robot.synth.generate import RecordingJob, write_recording
from touch2robot.teachers.config import PPOConfig, TeacherConfig
from touch2robot.teachers.objective import stack_references
from touch2robot.teachers.reference import load_reference
from touch2robot.teachers.train import make_teacher_env, runner_config


def demonstration(task: str, root: Path) -> dict:
    """One ingested, contact-labelled, retargeted glove demonstration of ``task``."""
    layout = DataLayout(root)
    config = SynthConfig(tasks=(task,), subjects=1, demos_per_subject=1, replays_per_task=0)
    ingest_file(
        write_recording(config, RecordingJob("glove_session", task, 1, 1), layout.recordings, layout.groundtruth),
        layout.lake,
    )
    recording = recording_rows(layout.lake).to_pylist()[0]
    rows, _ = human_contacts(layout.lake, recording, ContactsConfig())
    lake_io.write_rows(layout.lake, "contacts", recording["recording_id"], rows, {"source": "human", "task": task})
    rid = recording["recording_id"]
    result = retarget_motion(load_hand_motion(layout.lake, rid), LEAP_DEFAULT, Retargeter(LEAP_DEFAULT))
    lake_io.write_rows(layout.lake, "retargeted", rid, result_rows(result))
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


class Recorded:
    """Wraps BatchEnv.step: times it and keeps each step's start state and control inputs."""

    def __init__(self, env: BatchEnv, totals: dict[str, float], key: str) -> None:
        self.env, self.step, self.totals, self.key = env, env.step, totals, key
        self.inputs: list[tuple[np.ndarray, np.ndarray]] = []

    def __call__(self, *args, **kwargs):
        state = self.env.state.copy()
        start = time.perf_counter()
        self.step(*args, **kwargs)
        self.totals[self.key] += time.perf_counter() - start
        self.inputs.append((state, self.env._control.copy()))


def ceiling(env: BatchEnv, inputs: list[tuple[np.ndarray, np.ndarray]], threads: int) -> float:
    """Env steps/s of the raw rollout over the recorded states and commands, one call per step."""
    datas = [mujoco.MjData(env.model) for _ in range(threads)]
    pool = rollout.Rollout(nthread=threads if threads > 1 else 0)
    models = [env.model] * env.n
    warm = np.zeros((env.n, env.model.nv))
    out = np.empty((env.n, env.cfg.substeps, env.nstate))
    sens = np.empty((env.n, env.cfg.substeps, env.model.nsensordata))
    start = time.perf_counter()
    for state, control in inputs:
        pool.rollout(
            models,
            datas,
            state,
            control,
            control_spec=CONTROL_SPEC,
            skip_checks=True,
            nstep=env.cfg.substeps,
            initial_warmstart=warm,
            state=out,
            sensordata=sens,
        )
    rate = env.n * len(inputs) / (time.perf_counter() - start)
    pool.close()
    return rate


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
    recorder = Recorded(env, totals, "physics (BatchEnv.step)")
    env.step = recorder
    for name in ("observe", "reward", "terminated", "truncated", "reset", "command", "episode_end"):
        setattr(objective, name, Timed(getattr(objective, name), totals, "objective (obs, reward, resets)"))
    runner = OnPolicyRunner(vec_env, runner_config(config.ppo), log_dir=None, device="cpu")
    runner.alg.act = Timed(runner.alg.act, totals, "policy inference (act)")
    runner.alg.update = Timed(runner.alg.update, totals, "PPO update")
    runner.alg.compute_returns = Timed(runner.alg.compute_returns, totals, "returns (GAE)")
    runner.learn(1)  # warm-up: thread pools, allocations
    totals.clear()
    recorder.inputs.clear()
    start = time.perf_counter()
    runner.learn(args.iterations)
    total = time.perf_counter() - start
    env_steps = args.n * args.steps * args.iterations

    best_ceiling = max(ceiling(env, recorder.inputs, args.threads) for _ in range(2))
    env.close()

    print(
        f"teacher {args.task}/{args.method}: N={args.n}, {args.steps} steps/env/iteration, hidden {args.hidden}, "
        f"{args.iterations} iterations"
    )
    print(f"PPO iteration: {1e3 * total / args.iterations:.0f} ms")
    accounted = 0.0
    for key, seconds in sorted(totals.items(), key=lambda kv: -kv[1]):
        accounted += seconds
        print(f"  {key:34s} {1e3 * seconds / args.iterations:8.0f} ms  {100 * seconds / total:5.1f} %")
    print(
        f"  {'rest (storage, logging, rsl-rl)':34s} {1e3 * (total - accounted) / args.iterations:8.0f} ms  "
        f"{100 * (total - accounted) / total:5.1f} %"
    )
    collect = total - totals["PPO update"] - totals["returns (GAE)"]
    rate = env_steps / collect
    print(
        f"collection: {rate:.0f} env steps/s; physics alone {env_steps / totals['physics (BatchEnv.step)']:.0f} env "
        "steps/s"
    )
    print(f"ceiling (raw rollout of the same states and commands): {best_ceiling:.0f} env steps/s")
    print(
        f"ratio physics / ceiling: {env_steps / totals['physics (BatchEnv.step)'] / best_ceiling:.2f}; collection / "
        f"ceiling: {rate / best_ceiling:.2f}"
    )


if __name__ == "__main__":
    main()
