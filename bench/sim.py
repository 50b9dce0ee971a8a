"""Batched simulation throughput on the Pick scene with the hands closing on the box (contacts
happening): env steps/s of BatchEnv (observations, contacts and success bookkeeping read every
control step) next to the ceiling measured in the same run -- MuJoCo's multithreaded rollout of
the same model, N and substeps with the commands precomputed and no Python work in between:
(a) one rollout call per control step, (b) one rollout call over the whole horizon; the faster
is the ceiling. Rounds interleave the three so that load from other processes hits all alike;
the best round of each is reported. Also: single-copy step latency.

    uv run python bench/sim.py [--n 200] [--steps 60] [--rounds 5] [--threads 2]
"""

from __future__ import annotations

import argparse
import os
import time

import mujoco
import numpy as np
from mujoco import rollout

from touch2robot.sim.config import SimConfig
from touch2robot.sim.env import CONTROL_SPEC, BatchEnv
from touch2robot.sim.scene import build_scene

CLOSE = np.array([1.0, 0.0, 1.0, 0.8] * 3 + [1.0, 1.0, 0.6, 0.4])


def commands(env: BatchEnv, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Per control step: joint targets closing the hand, and the wrist lowering onto the box."""
    home = env.home_state[env.layout.qpos][env.scene.hand_qpos]
    k = np.arange(steps)[:, None]
    targets = home + np.clip((k - 5) / 10, 0, 1) * CLOSE
    wrist = env.scene.home_wrist_pos - np.clip(k / 12, 0, 1) * np.array([0.0, 0.0, 0.048])
    return targets, wrist


def run_env(env: BatchEnv, steps: int) -> tuple[float, float]:
    """Env steps/s of BatchEnv from the home state, and the share of steps x copies in contact."""
    env.reset(np.arange(env.n))
    targets, wrist = commands(env, steps)
    targets, wrist = np.repeat(targets[:, None], env.n, 1), np.repeat(wrist[:, None], env.n, 1)
    in_contact = 0
    start = time.perf_counter()
    for k in range(steps):
        env.step(targets[k], wrist[k])
        contact = env.region_contact  # what an objective reads every step
        _ = env.hand_qpos, env.hand_qvel, env.object_pos, env.object_quat, env.fingertip_pos, env.success
        in_contact += int(contact.any(axis=1).sum())
    elapsed = time.perf_counter() - start
    return env.n * steps / elapsed, in_contact / (env.n * steps)


def _raw_control(env: BatchEnv, steps: int) -> np.ndarray:
    targets, wrist = commands(env, steps)
    nu, nv, sub = env.model.nu, env.model.nv, env.cfg.substeps
    control = np.zeros((steps, env.n, sub, nu + nv + 7))  # ctrl, qfrc_applied (none), mocap pos, quat
    control[..., :nu] = targets[:, None, None, :]
    control[..., nu + nv : nu + nv + 3] = wrist[:, None, None, :]
    control[..., nu + nv + 3 :] = env.scene.home_wrist_quat
    return control


def run_ceiling_per_step(env: BatchEnv, steps: int, pool: rollout.Rollout, datas: list[mujoco.MjData]) -> float:
    """Raw rollout, one call per control step, outputs preallocated, no Python work between."""
    control = _raw_control(env, steps)
    models = [env.model] * env.n
    state = np.tile(env.home_state, (env.n, 1))
    warm = np.zeros((env.n, env.model.nv))
    out = np.empty((2, env.n, env.cfg.substeps, env.nstate))
    sens = np.empty((env.n, env.cfg.substeps, env.model.nsensordata))
    start = time.perf_counter()
    for k in range(steps):
        pool.rollout(
            models,
            datas,
            state,
            control[k],
            control_spec=CONTROL_SPEC,
            skip_checks=True,
            nstep=env.cfg.substeps,
            initial_warmstart=warm,
            state=out[k % 2],
            sensordata=sens,
        )
        state = out[k % 2, :, -1]
    return env.n * steps / (time.perf_counter() - start)


def run_ceiling_one_call(env: BatchEnv, steps: int, pool: rollout.Rollout, datas: list[mujoco.MjData]) -> float:
    """Raw rollout, the whole horizon in one call."""
    sub = env.cfg.substeps
    control = np.ascontiguousarray(_raw_control(env, steps).transpose(1, 0, 2, 3).reshape(env.n, steps * sub, -1))
    out = np.empty((env.n, steps * sub, env.nstate))
    sens = np.empty((env.n, steps * sub, env.model.nsensordata))
    state = np.tile(env.home_state, (env.n, 1))
    start = time.perf_counter()
    pool.rollout(
        [env.model] * env.n,
        datas,
        state,
        control,
        control_spec=CONTROL_SPEC,
        skip_checks=True,
        nstep=steps * sub,
        initial_warmstart=np.zeros((env.n, env.model.nv)),
        state=out,
        sensordata=sens,
    )
    return env.n * steps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--n", type=int, default=200)
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    cfg = SimConfig(n_envs=args.n, threads=args.threads)
    scene = build_scene("pick", cfg)
    env = BatchEnv(scene, cfg)
    datas = [mujoco.MjData(scene.model) for _ in range(args.threads)]
    pool = rollout.Rollout(nthread=args.threads if args.threads > 1 else 0)
    run_env(env, 5)  # warm-up: thread pool, caches
    rates: dict[str, list[float]] = {"env": [], "per_step": [], "one_call": []}
    contact_share = 0.0
    for _ in range(args.rounds):
        rate, contact_share = run_env(env, args.steps)
        rates["env"].append(rate)
        rates["per_step"].append(run_ceiling_per_step(env, args.steps, pool, datas))
        rates["one_call"].append(run_ceiling_one_call(env, args.steps, pool, datas))
    pool.close()
    env.close()
    best = {k: max(v) for k, v in rates.items()}
    ceiling = max(best["per_step"], best["one_call"])

    single = BatchEnv(scene, SimConfig(n_envs=1, threads=1))
    targets, wrist = commands(single, 60)
    lat = []
    for _ in range(5):
        single.reset(np.array([0]))
        for k in range(60):
            t = time.perf_counter()
            single.step(targets[k][None], wrist[k][None])
            lat.append(time.perf_counter() - t)
    single.close()

    print(
        f"Pick scene, N={args.n}, {cfg.substeps} x {cfg.timestep} s substeps per control step ({cfg.control_hz:g} Hz), "
        f"{args.threads} threads, {os.cpu_count()} CPUs, best of {args.rounds} interleaved rounds of {args.steps} "
        "control steps"
    )
    print(f"copies with a tactile region in contact (over all steps): {contact_share:.0%}")
    print(
        f"BatchEnv:                         {best['env']:9.0f} env steps/s  ({best['env'] * cfg.substeps:.0f} physics "
        "steps/s)"
    )
    print(f"ceiling, rollout per control step:{best['per_step']:9.0f} env steps/s")
    print(f"ceiling, rollout in one call:     {best['one_call']:9.0f} env steps/s")
    print(f"ratio BatchEnv / ceiling: {best['env'] / ceiling:.2f}   (target >= 0.80)")
    print(
        f"single-copy control step latency: {np.median(lat) * 1e3:.3f} ms median, {np.percentile(lat, 95) * 1e3:.3f} "
        "ms p95"
    )


if __name__ == "__main__":
    main()
