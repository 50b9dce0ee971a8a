"""Where a teacher's PPO iteration goes: MuJoCo stepping, the objective's observation / reward /
reset work, policy inference, and the PPO update, for one task and method on demonstrator data;
the collection rate (env steps/s) next to the raw-rollout ceiling measured in the same run the
way bench/sim measures it: MuJoCo's multithreaded rollout, one call per control step, replaying
the very states and commands the collection produced, with no Python work in between.

The PPO update against its own ceiling: the update's matmul FLOPs counted from the network shapes
(``update_flops``) over its measured time, next to the raw fp32 matmul rate of the same shapes
(``matmul_ceiling``) at the same torch thread count, measured in the same run. Two code paths
alternate iteration by iteration on one runner: today's (update on 1 thread) and the new one
(update on ``update_threads``, default the physics' ``--threads``); the speed-up is the ratio of
their iteration times. ``--profile-update`` adds torch's profile of one update on the new path.

    uv run python bench/teacher.py [--task pick] [--method touch2robot] [--n 200] [--steps 64]
                                   [--iterations 3] [--threads 2] [--update-threads N]
                                   [--hidden 1024 1024 512] [--profile-update]

Needs glove recordings: it synthesises, ingests and retargets one demonstration of the task
into a temporary data folder first (library calls, not timed).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from collections import defaultdict
from functools import partial
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
from touch2robot.teachers.train import make_teacher_env, runner_config, torch_threads, update_threads


def demonstration(task: str, root: Path) -> dict:
    """One ingested, contact-labelled, retargeted glove demonstration of ``task``."""
    layout = DataLayout(root)
    config = SynthConfig(tasks=(task,), subjects=1, demos_per_subject=1)
    ingest_file(
        write_recording(config, RecordingJob(task, 1, 1), layout.recordings, layout.groundtruth),
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


def linear_layers(runner: OnPolicyRunner) -> list[tuple[int, int, bool]]:
    """(in, out, whether its input needs a gradient) of every linear layer of the actor and the
    critic. A network's first layer gets the normalised observation, which needs none."""
    layers = []
    for net in (runner.alg.actor, runner.alg.critic):
        linears = [m for m in net.modules() if isinstance(m, torch.nn.Linear)]
        layers += [(m.in_features, m.out_features, index > 0) for index, m in enumerate(linears)]
    return layers


def minibatch_flops(layers: list[tuple[int, int, bool]], rows: int) -> float:
    """Matmul FLOPs of one minibatch's forward and backward through the layers: per layer, forward
    X W^T (2 rows in out), weight gradient X^T G (2 rows in out), and input gradient G W (2 rows in
    out) where the input needs one: about 3x the forward. Bias, activations, losses and the
    optimiser are left out: they are the update's overhead, not its matmuls."""
    return sum(2.0 * rows * fan_in * fan_out * (3 if input_grad else 2) for fan_in, fan_out, input_grad in layers)


def update_flops(runner: OnPolicyRunner, ppo: PPOConfig) -> tuple[float, int]:
    """(matmul FLOPs of one PPO update, minibatch rows): epochs x minibatches x ``minibatch_flops``
    (one forward of the actor and one of the critic per minibatch, as rsl-rl's PPO.update does)."""
    storage = runner.alg.storage
    rows = storage.num_envs * storage.num_transitions_per_env // ppo.num_mini_batches
    per_minibatch = minibatch_flops(linear_layers(runner), rows)
    return ppo.num_learning_epochs * ppo.num_mini_batches * per_minibatch, rows


def matmul_ceiling(layers: list[tuple[int, int, bool]], rows: int, threads: int, passes: int = 5) -> float:
    """FLOP/s of the raw fp32 matmuls of one minibatch (``minibatch_flops``'s products, with the
    shapes and transposes autograd uses, into preallocated outputs) on ``threads`` torch threads:
    the best of ``passes`` passes over all of them after one warm-up pass."""
    products = []
    for fan_in, fan_out, input_grad in layers:
        x, w, b, g = (
            torch.randn(rows, fan_in),
            torch.randn(fan_out, fan_in),
            torch.randn(fan_out),
            torch.randn(rows, fan_out),
        )
        products.append(partial(torch.addmm, b, x, w.t(), out=torch.empty(rows, fan_out)))
        products.append(partial(torch.mm, x.t(), g, out=torch.empty(fan_in, fan_out)))
        if input_grad:
            products.append(partial(torch.mm, g, w, out=torch.empty(rows, fan_in)))
    best = float("inf")
    with torch_threads(threads):
        for _ in range(passes + 1):
            start = time.perf_counter()
            for product in products:
                product()
            best = min(best, time.perf_counter() - start)
    return minibatch_flops(layers, rows) / best


class ThreadedUpdate:
    """The PPO update on ``threads`` torch threads (settable between iterations), timed into
    ``totals``; with ``profile`` set, the next update runs under torch's profiler."""

    def __init__(self, update, totals: dict[str, float], key: str) -> None:
        self.update, self.totals, self.key = update, totals, key
        self.threads, self.profile = 1, False

    def __call__(self):
        with torch_threads(self.threads):
            if not self.profile:
                start = time.perf_counter()
                result = self.update()
                self.totals[self.key] += time.perf_counter() - start
                return result
            self.profile = False
            with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU]) as profile:
                result = self.update()
            print(f"torch profile of one PPO update on {self.threads} thread(s), by self CPU time:")
            print(profile.key_averages().table(sort_by="self_cpu_time_total", row_limit=15))
            return result


def busy_cpu_seconds() -> float:
    """CPU seconds all processes of the machine have spent so far (Linux /proc/stat: user, nice,
    system, irq, softirq), to tell this run's own load from what else ran beside it."""
    fields = Path("/proc/stat").read_text().splitlines()[0].split()[1:]
    return sum(int(fields[i]) for i in (0, 1, 2, 5, 6)) / os.sysconf("SC_CLK_TCK")


def print_breakdown(totals: dict[str, float], total: float, iterations: int) -> None:
    accounted = 0.0
    for key, seconds in sorted(totals.items(), key=lambda kv: -kv[1]):
        accounted += seconds
        print(f"  {key:34s} {1e3 * seconds / iterations:8.0f} ms  {100 * seconds / total:5.1f} %")
    print(
        f"  {'rest (storage, logging, rsl-rl)':34s} {1e3 * (total - accounted) / iterations:8.0f} ms  "
        f"{100 * (total - accounted) / total:5.1f} %"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--task", default="pick")
    parser.add_argument("--method", default="touch2robot")
    parser.add_argument("--n", type=int, default=200)
    parser.add_argument("--steps", type=int, default=64, help="rollout length per env per iteration (Table VII: 512)")
    parser.add_argument("--iterations", type=int, default=3, help="timed iterations of each code path")
    parser.add_argument("--threads", type=int, default=2, help="MuJoCo rollout threads (sim.threads)")
    parser.add_argument(
        "--update-threads", type=int, default=None, help="the new path's update threads (default --threads)"
    )
    parser.add_argument("--hidden", type=int, nargs="+", default=[1024, 1024, 512])
    parser.add_argument("--profile-update", action="store_true", help="print torch's profile of one new-path update")
    args = parser.parse_args()
    torch.set_num_threads(1)

    with tempfile.TemporaryDirectory() as tmp:
        recording = demonstration(args.task, Path(tmp) / "data")
        refs = stack_references([load_reference(DataLayout(Path(tmp) / "data").lake, recording)])
    config = TeacherConfig(
        sim=SimConfig(n_envs=args.n, threads=args.threads),
        ppo=PPOConfig(num_steps_per_env=args.steps, hidden_dims=tuple(args.hidden), update_threads=args.update_threads),
    )
    paths = {
        "today (update on 1 thread)": 1,
        f"new (update on {update_threads(config)} threads)": update_threads(config),
    }
    vec_env = make_teacher_env(args.task, refs, config, args.method)
    totals: dict[str, float] = defaultdict(float)
    env, objective = vec_env.env, vec_env.objective
    recorder = Recorded(env, totals, "physics (BatchEnv.step)")
    env.step = recorder
    for name in ("observe", "reward", "terminated", "truncated", "reset", "command", "episode_end"):
        setattr(objective, name, Timed(getattr(objective, name), totals, "objective (obs, reward, resets)"))
    runner = OnPolicyRunner(vec_env, runner_config(config.ppo), log_dir=None, device="cpu")
    runner.alg.act = Timed(runner.alg.act, totals, "policy inference (act)")
    update = runner.alg.update = ThreadedUpdate(runner.alg.update, totals, "PPO update")
    runner.alg.compute_returns = Timed(runner.alg.compute_returns, totals, "returns (GAE)")
    flops, rows = update_flops(runner, config.ppo)

    # the paths alternate iteration by iteration, so that both see the same load of the machine
    path_totals = {path: defaultdict(float) for path in paths}
    wall = dict.fromkeys(paths, 0.0)
    machine_cpu, own_cpu, timed_start = busy_cpu_seconds(), time.process_time(), time.perf_counter()
    for iteration in range(args.iterations + 1):  # the first round warms up thread pools and allocations
        for path, threads in paths.items():
            update.threads = threads
            totals.clear()
            start = time.perf_counter()
            runner.learn(1)
            if iteration:
                wall[path] += time.perf_counter() - start
                for key, seconds in totals.items():
                    path_totals[path][key] += seconds
        if not iteration:
            recorder.inputs.clear()
    timed_wall = time.perf_counter() - timed_start
    others = (busy_cpu_seconds() - machine_cpu - (time.process_time() - own_cpu)) / timed_wall
    if args.profile_update:
        update.threads, update.profile = update_threads(config), True
        runner.learn(1)
    env_steps = args.n * args.steps * args.iterations * len(paths)
    physics = sum(t["physics (BatchEnv.step)"] for t in path_totals.values())
    collect = sum(wall.values()) - sum(t["PPO update"] + t["returns (GAE)"] for t in path_totals.values())

    best_ceiling = max(ceiling(env, recorder.inputs, args.threads) for _ in range(2))
    env.close()
    layers = linear_layers(runner)
    ceilings = {threads: matmul_ceiling(layers, rows, threads) for threads in sorted(set(paths.values()))}

    print(
        f"teacher {args.task}/{args.method}: N={args.n}, {args.steps} steps/env/iteration, hidden {args.hidden}, "
        f"{args.iterations} iterations of each path, alternating; physics on {args.threads} threads"
    )
    print(
        f"PPO update: {config.ppo.num_learning_epochs} epochs x {config.ppo.num_mini_batches} minibatches of {rows} "
        f"rows, layers {[layer[:2] for layer in layers]}: {flops / 1e9:.0f} GFLOP of matmuls per update"
    )
    for path, threads in paths.items():
        total, seconds = wall[path], path_totals[path]["PPO update"]
        print(f"{path}: PPO iteration {1e3 * total / args.iterations:.0f} ms")
        print_breakdown(path_totals[path], total, args.iterations)
        achieved = flops * args.iterations / seconds
        print(
            f"  update {achieved / 1e9:.1f} GFLOP/s; raw fp32 matmul ceiling of its shapes on {threads} thread(s) "
            f"{ceilings[threads] / 1e9:.1f} GFLOP/s; ratio {achieved / ceilings[threads]:.2f}; update share of the "
            f"iteration {100 * seconds / total:.1f} %"
        )
    today, new = wall.values()
    print(
        f"other processes beside this run: {others:.2f} of {os.cpu_count()} cores busy on average (a torch update on "
        "every core waits at each op for a thread the scheduler has parked)"
    )
    print(f"iteration speed-up, new path over today's: {today / new:.2f}x")
    rate = env_steps / collect
    print(f"collection: {rate:.0f} env steps/s; physics alone {env_steps / physics:.0f} env steps/s")
    print(f"ceiling (raw rollout of the same states and commands): {best_ceiling:.0f} env steps/s")
    print(
        f"ratio physics / ceiling: {env_steps / physics / best_ceiling:.2f}; collection / ceiling: "
        f"{rate / best_ceiling:.2f}"
    )


if __name__ == "__main__":
    main()
