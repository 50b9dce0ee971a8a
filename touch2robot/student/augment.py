"""Paired human-robot sequences from teacher rollouts, the demonstration split, and the
augmentation to the configured number of training rollouts (paper: 400).

A teacher rollout row k holds the state at step k and the command aimed at reference frame
k + 1. The student's step j pairs what the human demonstration gives at frame j (kinematic
retargeting, wrist, object pose, tactile preference) with the teacher's command aimed at frame j
(row j - 1) and the sim contacts that command led to (row j, region force > threshold), for
j = 1 .. K - 1 of a K-row rollout.

Augmentation (per task ``augmented_rollouts / len(tasks)`` rollouts): the task's training teacher
rollouts once unchanged, then noisy copies cycling through them. A copy adds one Gaussian sample
N(0, std^2) per frame and joint to the kinematic joints (input) *and* the teacher's joint target
of that frame, so their frame-wise correspondence (the residual the student learns) holds; wrist,
object, preference and contacts are unchanged. Each copy is seeded by (seed, task, copy index).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pyarrow as pa

from schemas.tables import unseeded
from touch2robot.scenes import TASKS
from touch2robot.teachers.reference import DemoReference
from touch2robot.teachers.rollouts import column


class StudentDataError(ValueError):
    """Teacher rollouts that cannot be paired with their demonstration; the message names them."""


@dataclass(frozen=True)
class DemoSplit:
    """Glove demonstrations per role, by task. ``in_sample`` is set when no task had a
    demonstration to hold out: every demonstration is trained on and also reconstructed."""

    train: dict[str, list[str]]
    val: dict[str, list[str]]
    held_out: dict[str, list[str]]
    in_sample: bool

    def role(self, reference_id: str) -> str | None:
        for name in ("train", "val"):
            if any(reference_id in ids for ids in getattr(self, name).values()):
                return name
        return None


def split_demonstrations(
    demos: dict[str, list[str]], held_out_fraction: float, val_fraction: float, seed: int
) -> DemoSplit:
    """Split each task's demonstrations (recording ids) by demonstration, never by frame.

    Per task (seeded order): round(held_out_fraction x n) held out (at most n - 1), then
    round(val_fraction x rest) of the rest validate (at most rest - 1). When no task holds a
    demonstration out (one demo per task, as in the smoke profile) every demonstration is also
    reconstructed (``in_sample``). When no task gives a validation demonstration, one whole
    demonstration of the task with most demonstrations validates (its task then trains on the
    others, or on none)."""
    train, val, held = {}, {}, {}
    for i, task in enumerate(sorted(demos)):
        ids = sorted(demos[task])
        order = [ids[k] for k in np.random.default_rng([seed, i]).permutation(len(ids))]
        n_held = min(round(held_out_fraction * len(order)), len(order) - 1)
        held[task], rest = order[:n_held], order[n_held:]
        n_val = min(round(val_fraction * len(rest)), len(rest) - 1)
        val[task], train[task] = rest[:n_val], rest[n_val:]
    if not any(val.values()) and demos:
        task = max(sorted(train), key=lambda t: len(train[t]))
        val[task], train[task] = train[task][:1], train[task][1:]
    in_sample = not any(held.values())
    if in_sample:
        held = {task: sorted(ids) for task, ids in demos.items()}
    return DemoSplit(train, val, held, in_sample)


@dataclass(frozen=True)
class PairedSequence:
    """One teacher rollout as student steps j = 1 .. K - 1 (arrays of length T = K - 1)."""

    task: str
    reference_id: str
    source_rollout_id: str
    step: np.ndarray  # (T,) the reference frame each command aims at
    t_ref: np.ndarray
    joints: np.ndarray  # (T, 16) kinematic retargeting (input)
    wrist_pose: np.ndarray  # (T, 7) kinematic wrist (input)
    object_pose: np.ndarray  # (T, 7) demonstrated object (input)
    preference: np.ndarray  # (T, 8) bool (input)
    target_joints: np.ndarray  # (T, 16) teacher joint command
    target_wrist: np.ndarray  # (T, 7) teacher wrist command
    contact: np.ndarray  # (T, 8) bool sim contact after the command


def paired_sequences(rollouts: pa.Table, refs: dict[str, DemoReference], threshold_n: float) -> list[PairedSequence]:
    """The paired sequences of every rollout in ``rollouts`` (rows of one task, sorted by rollout
    and step as the teachers write them) whose demonstration is in ``refs``."""
    out = []
    ids = rollouts["rollout_id"].to_numpy(zero_copy_only=False)
    bounds = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1], True])
    for a, b in itertools.pairwise(bounds):
        rows = rollouts.slice(a, b - a)
        rid, ref_id = str(ids[a]), rows["reference_id"][0].as_py()
        if ref_id not in refs or b - a < 2:
            continue
        ref = refs[ref_id]
        step = rows["step"].to_numpy()
        if not np.array_equal(step, np.arange(len(step))):
            raise StudentDataError(f"rollout {rid}: steps are not 0..{len(step) - 1} in order")
        frame = np.minimum(step, ref.length - 1)
        t_ref = rows["t_ref"].to_numpy()
        if not np.allclose(ref.t_ref[frame], t_ref, atol=1e-6):
            raise StudentDataError(
                f"rollout {rid}: t_ref does not follow demonstration {ref_id} (re-run the teachers after a new "
                "retargeting)"
            )
        f = frame[1:]
        out.append(
            PairedSequence(
                task=ref.task,
                reference_id=ref_id,
                source_rollout_id=rid,
                step=step[1:],
                t_ref=t_ref[1:],
                joints=column(rows, "reference_joints")[1:],
                wrist_pose=np.concatenate([ref.wrist_pos[f], ref.wrist_quat[f]], axis=1),
                object_pose=np.concatenate([ref.object_pos[f], ref.object_quat[f]], axis=1),
                preference=ref.preference[f],
                target_joints=column(rows, "joint_target")[:-1],
                target_wrist=column(rows, "wrist_pose")[:-1],
                contact=column(rows, "region_force")[1:] > threshold_n,
            )
        )
    return out


def per_task_counts(total: int, tasks: list[str]) -> dict[str, int]:
    """``total`` rollouts balanced over ``tasks`` (the first tasks take the remainder)."""
    ordered = sorted(tasks, key=lambda t: TASKS.index(t) if t in TASKS else len(TASKS))
    base, extra = divmod(total, len(ordered))
    return {t: base + (i < extra) for i, t in enumerate(ordered)}


def _fixed(values: np.ndarray, dtype: pa.DataType) -> pa.FixedSizeListArray:
    values = np.ascontiguousarray(values)
    return pa.FixedSizeListArray.from_arrays(pa.array(values.reshape(-1), dtype), values.shape[1])


def _rows(seq: PairedSequence, sample_id: str, split: str, augment: int, noise: np.ndarray) -> pa.Table:
    n = len(seq.step)
    const = lambda v: pa.array([v] * n)  # noqa: E731
    return pa.table(
        {
            "sample_id": const(sample_id),
            "split": const(split),
            "task": const(seq.task),
            "reference_id": const(seq.reference_id),
            "source_rollout_id": const(seq.source_rollout_id),
            "augment": pa.array([augment] * n, pa.int32()),
            "step": pa.array(seq.step.astype(np.int32)),
            "t_ref": seq.t_ref,
            "kinematic_joints": _fixed((seq.joints + noise).astype(np.float32), pa.float32()),
            "wrist_pose": _fixed(seq.wrist_pose, pa.float64()),
            "object_pose": _fixed(seq.object_pose, pa.float64()),
            "preference": _fixed(seq.preference.astype(bool), pa.bool_()),
            "target_joints": _fixed(seq.target_joints + noise, pa.float64()),
            "target_wrist": _fixed(seq.target_wrist, pa.float64()),
            "contact": _fixed(seq.contact, pa.bool_()),
        }
    )


def augment(
    train: list[PairedSequence], count: int, noise_std: float, seed: int, val: Sequence[PairedSequence] = ()
) -> pa.Table:
    """``student_dataset`` rows of one task: ``count`` training rollouts (the teacher rollouts
    unchanged, then seeded noisy copies) and the validation rollouts unchanged (a task can
    have validation rollouts only: ``count`` 0)."""
    if count and not train:
        raise StudentDataError("no training teacher rollouts to augment")
    tasks = {s.task for s in [*train, *val]}
    if len(tasks) != 1:  # none: nothing to write
        raise StudentDataError(f"augment one task at a time, got {sorted(tasks)}")
    task = tasks.pop()
    t_index = TASKS.index(task) if task in TASKS else len(TASKS)
    tables = []
    for k in range(count):
        seq = train[k % len(train)]
        if k < len(train):
            noise = np.zeros_like(seq.joints)
        else:
            noise = np.random.default_rng([seed, t_index, k]).normal(0.0, noise_std, seq.joints.shape)
        tables.append(_rows(seq, f"train-{task}-{k:03d}", "train", k // len(train), noise))
    for k, seq in enumerate(val):
        tables.append(_rows(seq, f"val-{task}-{k:03d}", "val", 0, np.zeros_like(seq.joints)))
    return pa.concat_tables(tables).cast(unseeded("student_dataset"))
