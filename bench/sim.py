"""Batched simulation throughput: env steps/s of BatchEnv for N copies of the Pick scene with
the hands closing on the box (contacts happening), next to the ceiling — MuJoCo's
multithreaded rollout of the same model, the same number of substeps and the same
commands precomputed, with no Python work between control steps — measured in this run.

    uv run python bench/sim.py [--n 200] [--steps 100] [--threads 2]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from mujoco import rollout

from touch2robot.sim.config import SimConfig
from touch2robot.sim.env import CONTROL_SPEC, BatchEnv
from touch2robot.sim.scene import build_scene

CLOSE = np.array([1.0, 0.0, 1.0, 0.8] * 3 + [1.0, 1.0, 0.6, 0.4])


def commands(env: BatchEnv, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Joint targets closing the hand and a wrist lowering onto the box, per control step."""
    home = env.home_state[env.layout.qpos][env.scene.hand_qpos]
    k = np.arange(steps)[:, None]
    targets = home + np.clip((k - 10) / 20, 0, 1) * CLOSE
    wrist = env.scene.home_wrist_pos - np.clip(k / 20, 0, 1) * np.array([0.0, 0.0, 0.05])
    return targets, wrist


def run_env(env: BatchEnv, steps: int) -> tuple[float, float]:
    targets, wrist = commands(env, steps)
    start = time.perf_counter()
    for k in range(steps):
        env.step(np.broadcast_to(targets[k], (env.n, 16)), np.broadcast_to(wrist[k], (env.n, 3)))
        _ = env.region_contact, env.hand_qpos, env.object_pose  # what an objective reads every step
    elapsed = time.perf_counter() - start
    return env.n * steps / elapsed, float(env.region_contact.any(axis=1).mean())


def run_ceiling(env: BatchEnv, steps: int) -> float:
    targets, wrist = commands(env, steps)
    sub = env.cfg.substeps
    control = np.empty((env.n, steps * sub, env.model.nu + 7))
    control[:, :, : env.model.nu] = np.repeat(targets, sub, axis=0)[None]
    control[:, :, env.model.nu : env.model.nu + 3] = np.repeat(wrist, sub, axis=0)[None]
    control[:, :, env.model.nu + 3 :] = env.scene.home_wrist_quat
    import mujoco

    datas = [mujoco.MjData(env.model) for _ in range(env.cfg.threads)]
    state0 = np.tile(env.home_state, (env.n, 1))
    with rollout.Rollout(nthread=env.cfg.threads) as r:
        start = time.perf_counter()
        r.rollout(env.model, datas, state0, control, control_spec=CONTROL_SPEC, nstep=steps * sub)
        elapsed = time.perf_counter() - start
    return env.n * steps / elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=200)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    cfg = SimConfig(n_envs=args.n, threads=args.threads)
    scene = build_scene("pick", cfg)
    run_env(BatchEnv(scene, cfg), 5)  # warm-up
    env_rate, contact_share = run_env(BatchEnv(scene, cfg), args.steps)
    ceiling = run_ceiling(BatchEnv(scene, cfg), args.steps)
    single = BatchEnv(scene, SimConfig(n_envs=1, threads=1))
    targets, wrist = commands(single, 200)
    lat = []
    for k in range(200):
        t = time.perf_counter()
        single.step(targets[k][None], wrist[k][None])
        lat.append(time.perf_counter() - t)
    print(f"N={args.n}, {cfg.substeps} substeps of {cfg.timestep} s per control step, {args.threads} threads")
    print(f"copies with a region in contact at the end: {contact_share:.0%}")
    print(f"BatchEnv:                 {env_rate:9.0f} env steps/s")
    print(f"ceiling (raw rollout):    {ceiling:9.0f} env steps/s")
    print(f"ratio: {env_rate / ceiling:.2f}   (target >= 0.80)")
    print(f"single-copy step latency: {np.median(lat) * 1e3:.2f} ms median, {np.percentile(lat, 95) * 1e3:.2f} ms p95")


if __name__ == "__main__":
    main()
