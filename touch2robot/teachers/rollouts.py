"""Robot trajectories in simulation: rows of the ``rollouts`` table and their sim contacts.

One batch of copies runs one rollout each (the k-th rollout follows demonstration k mod D);
every control step records the observed state and the command applied from it. A rollout ends
at its reference's last frame or when the objective says tracking is lost; its last row is the
final state (holding its command). Teachers act deterministically and without DexMachina's
assistance; the kinematic baseline (Dex Retargeting) is the same loop with a zero residual.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pyarrow as pa

from schemas.tables import ROBOT_REGIONS, unseeded
from schemas.vocabulary import Source
from touch2robot.contacts import long_rows
from touch2robot.metrics import contact_scores
from touch2robot.sim.env import BatchEnv
from touch2robot.teachers.objective import NUM_ACTIONS, DemoTracking, References

Policy = Callable[[dict[str, np.ndarray]], np.ndarray]


def zero_residual(obs: dict[str, np.ndarray]) -> np.ndarray:
    """The kinematic baseline's 'policy': joint targets and wrist are the kinematic reference itself."""
    return np.zeros((len(obs["actor"]), NUM_ACTIONS))


def _fixed(values: np.ndarray, dtype: pa.DataType) -> pa.FixedSizeListArray:
    values = np.ascontiguousarray(values)
    return pa.FixedSizeListArray.from_arrays(pa.array(values.reshape(-1), dtype), values.shape[1])


def record(
    env: BatchEnv, objective: DemoTracking, policy: Policy, method: str, origin: str, seed: int = 0
) -> tuple[pa.Table, pa.Table]:
    """Run one rollout per copy of ``env`` and return (rollouts rows, sim contact rows)."""
    refs = objective.refs
    n = env.n
    objective.eval_demos = np.arange(n) % len(refs.ids)
    objective.assist_gain = 0.0  # the object is on its own in every recorded trajectory
    objective.reset(env, np.arange(n), np.random.default_rng(seed))
    active = np.ones(n, dtype=bool)
    steps: list[dict[str, np.ndarray]] = []
    dt = env.cfg.control_dt
    while active.any():
        obs = objective.observe(env)
        actions = np.asarray(policy(obs), dtype=np.float64)
        targets, wrist_pos, wrist_quat, _ = objective.command(env, actions)
        ended = objective.truncated(env) | objective.terminated(env)
        # a copy that has ended records its final state and holds its last command
        targets = np.where(ended[:, None], env.joint_targets, targets)
        wrist_pos = np.where(ended[:, None], env.wrist_pos, wrist_pos)
        wrist_quat = np.where(ended[:, None], env.wrist_quat, wrist_quat)
        frame = objective.frame(env)
        steps.append(
            {
                "active": active.copy(),
                "step": env.time_step.copy(),
                "t_ref": refs.t_ref[objective.demo, frame],
                "joint_position": env.hand_qpos.copy(),
                "joint_velocity": env.hand_qvel.copy(),
                "joint_target": np.clip(targets, env.ctrl_low, env.ctrl_high),
                "reference_joints": refs.joints[objective.demo, frame],
                "wrist_state": env.wrist_pose.copy(),
                "wrist_pose": np.concatenate(
                    [wrist_pos, wrist_quat / np.linalg.norm(wrist_quat, axis=1, keepdims=True)], axis=1
                ),
                "object_pose": np.concatenate([env.object_pos, env.object_quat], axis=1),
                "drawer_opening": env.drawer_opening.copy(),
                "region_force": env.region_force.copy(),
                "region_contact": env.region_contact.copy(),
                "progress": env.progress.copy(),
                "success": env.success.copy(),
            }
        )
        active &= ~ended
        if active.any():
            objective.prev_action = np.clip(actions, -1.0, 1.0)
            env.step(targets, wrist_pos, wrist_quat)
    objective.eval_demos = None
    return _tables(steps, objective, method, origin, dt, env.scene.spec.name)


def column(table: pa.Table, name: str) -> np.ndarray:
    """A fixed-size list column as a (rows, width) float64 array (a scalar column as (rows,))."""
    col = table[name].combine_chunks()
    if pa.types.is_fixed_size_list(col.type):
        return col.flatten().to_numpy(zero_copy_only=False).reshape(len(col), col.type.list_size).astype(np.float64)
    return col.to_numpy(zero_copy_only=False)


def reset_to_rows(env: BatchEnv, ids: np.ndarray, first_rows: pa.Table) -> None:
    """Reset copies ``ids`` to the states recorded in rollouts rows (one row per copy, normally
    each rollout's row 0): replaying the recorded commands from there reproduces the rollouts."""
    columns = [column(first_rows, c) for c in ("joint_position", "wrist_state", "object_pose", "drawer_opening")]
    env.reset_pose(ids, *columns)


def rollout_id(origin: str, method: str, task: str, index: int) -> str:
    return f"{origin}-{method}-{task}-{index:03d}"


def _tables(
    steps: list[dict[str, np.ndarray]], objective: DemoTracking, method: str, origin: str, dt: float, task: str
) -> tuple[pa.Table, pa.Table]:
    refs = objective.refs
    n = len(steps[0]["active"])
    rollout_tables, contact_tables = [], []
    for i in range(n):
        rows = [s for s in steps if s["active"][i]]
        d = int(objective.demo[i])
        get = lambda key: np.stack([s[key][i] for s in rows])  # noqa: E731, B023 - called in this iteration only
        k = len(rows)
        rid = rollout_id(origin, method, task, i)
        step = get("step")
        t = step * dt
        rollout_tables.append(
            pa.table(
                {
                    "rollout_id": pa.array([rid] * k),
                    "origin": pa.array([origin] * k),
                    "method": pa.array([method] * k),
                    "task": pa.array([task] * k),
                    "subject": pa.array([refs.subjects[d]] * k),
                    "reference_id": pa.array([refs.ids[d]] * k),
                    "step": pa.array(step.astype(np.int32)),
                    "t": t,
                    "t_ref": get("t_ref"),
                    "joint_position": _fixed(get("joint_position"), pa.float64()),
                    "joint_velocity": _fixed(get("joint_velocity"), pa.float64()),
                    "joint_target": _fixed(get("joint_target"), pa.float64()),
                    "reference_joints": _fixed(get("reference_joints").astype(np.float32), pa.float32()),
                    "wrist_state": _fixed(get("wrist_state"), pa.float64()),
                    "wrist_pose": _fixed(get("wrist_pose"), pa.float64()),
                    "object_pose": _fixed(get("object_pose"), pa.float64()),
                    "drawer_opening": get("drawer_opening"),
                    "region_force": _fixed(get("region_force").astype(np.float32), pa.float32()),
                    "progress": get("progress").astype(np.float32),
                    "success": get("success"),
                }
            )
        )
        contact_tables.append(
            long_rows(
                source=Source.SIM,
                method=method,
                task=task,
                subject=refs.subjects[d],
                sequence_id=rid,
                reference_id=refs.ids[d],
                t=t,
                t_ref=get("t_ref"),
                regions=ROBOT_REGIONS,
                contact=get("region_contact"),
                value=get("region_force"),
            )
        )
    rollouts = pa.concat_tables(rollout_tables).cast(unseeded("rollouts"))
    return rollouts, pa.concat_tables(contact_tables)


def summary(rollouts: pa.Table, refs: References, threshold_n: float) -> dict[str, float]:
    """A batch of rollouts: success rate and progress at their final rows, mean length, and the
    contact precision / recall / F1 of their sim contacts against the human preference over all
    time-region pairs (the paper's pooled contact metric)."""
    ids = rollouts["rollout_id"].to_numpy(zero_copy_only=False)
    last = np.r_[ids[1:] != ids[:-1], True]
    demo = np.array([refs.ids.index(r) for r in rollouts["reference_id"].to_pylist()])
    frame = np.array(
        [
            np.searchsorted(refs.t_ref[d, : refs.length[d]], t)
            for d, t in zip(demo, rollouts["t_ref"].to_numpy(), strict=True)
        ]
    )
    preference = refs.preference[demo, np.minimum(frame, refs.length[demo] - 1)]
    force = rollouts["region_force"].combine_chunks().flatten().to_numpy().reshape(-1, 8)
    scores = contact_scores(preference, force > threshold_n)
    return {
        "rollouts": int(last.sum()),
        "success_rate": float(rollouts["success"].to_numpy(zero_copy_only=False)[last].mean()),
        "final_progress": float(rollouts["progress"].to_numpy()[last].mean()),
        "mean_length_s": float(rollouts["t"].to_numpy()[last].mean()),
        "contact_precision": scores.precision,
        "contact_recall": scores.recall,
        "contact_f1": scores.f1,
    }
