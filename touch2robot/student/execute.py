"""The student's commands executed in MuJoCo, recorded like the teachers' rollouts.

The student's output for step j is the command aimed at reference frame j; the teachers'
recording loop (``touch2robot.teachers.rollouts.record``) asks its policy, at step k, for the
residual around frame k + 1 in teacher action units. ``student_policy`` turns the student's
absolute joint targets and wrist residual into that residual, so execution, early termination,
the reset-replayable row layout and the sim contacts are exactly the teachers' own.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from schemas.tables import ROBOT_REGIONS, unseeded
from schemas.vocabulary import Origin, Source
from touch2robot.metrics import contact_scores
from touch2robot.sim.env import BatchEnv
from touch2robot.sim.scene import build_scene
from touch2robot.student.augment import paired_sequences
from touch2robot.student.features import reference_inputs
from touch2robot.student.infer import StudentOutput, predict_recording
from touch2robot.student.model import StudentNet
from touch2robot.teachers.config import TeacherConfig
from touch2robot.teachers.objective import (
    JOINT_ACTIONS,
    NUM_ACTIONS,
    WRIST_POS_ACTIONS,
    WRIST_ROT_ACTIONS,
    DemoTracking,
    stack_references,
)
from touch2robot.teachers.reference import DemoReference
from touch2robot.teachers.rollouts import Policy, record, rollout_id, summary


def _pad(arrays: list[np.ndarray]) -> np.ndarray:
    T = max(len(a) for a in arrays)
    return np.stack([np.concatenate([a, np.repeat(a[-1:], T - len(a), axis=0)]) for a in arrays])


def _per_unit(values: np.ndarray, scale: float) -> np.ndarray:
    return values / scale if scale > 0 else np.zeros_like(values)


def student_policy(
    env: BatchEnv, objective: DemoTracking, outputs: list[StudentOutput], config: TeacherConfig
) -> Policy:
    """A ``record`` policy replaying the student's outputs (one per demonstration of the
    objective's references) as teacher residual actions."""
    joints = _pad([o.joints for o in outputs])
    wrist = _pad([o.wrist_residual for o in outputs])

    def act(obs: dict[str, np.ndarray]) -> np.ndarray:
        demo, frame = objective.demo, objective.frame(env, 1)
        actions = np.zeros((env.n, NUM_ACTIONS))
        actions[:, JOINT_ACTIONS] = _per_unit(
            joints[demo, frame] - objective.refs.joints[demo, frame], config.action_scale
        )
        actions[:, WRIST_POS_ACTIONS] = _per_unit(wrist[demo, frame, :3], config.wrist_pos_scale_m)
        actions[:, WRIST_ROT_ACTIONS] = _per_unit(wrist[demo, frame, 3:], config.wrist_rot_scale_rad)
        return actions

    return act


def execute(
    env: BatchEnv, objective: DemoTracking, outputs: list[StudentOutput], config: TeacherConfig, method: str
) -> tuple[pa.Table, pa.Table]:
    """One rollout per demonstration of ``objective.refs`` (``env.n`` copies, copy i follows
    demonstration i): (``rollouts`` rows of origin student, ``contacts`` rows of source
    reconstructed)."""
    if len(outputs) != len(objective.refs.ids) or env.n != len(outputs):
        raise ValueError(
            f"{len(outputs)} student outputs for {len(objective.refs.ids)} demonstrations and {env.n} env copies"
        )
    rollouts, contacts = record(env, objective, student_policy(env, objective, outputs, config), method, Origin.STUDENT)
    contacts = contacts.set_column(
        contacts.schema.get_field_index("source"), "source", pa.array([Source.RECONSTRUCTED] * len(contacts))
    )
    return rollouts, contacts


def prediction_rows(
    outputs: list[StudentOutput],
    refs_ids: tuple[str, ...],
    t_ref: list[np.ndarray],
    task: str,
    method: str,
    variant: str,
    dt: float,
) -> pa.Table:
    """``student_predictions`` rows: step j of demonstration i -> sequence ``student-<method>-<task>-<i>``,
    t = j dt (the rollout's clock), its contact logits per region."""
    tables = []
    k = len(ROBOT_REGIONS)
    for i, (out, rid, tr) in enumerate(zip(outputs, refs_ids, t_ref, strict=True)):
        n = len(out.contact_logits)
        logits = out.contact_logits.astype(np.float32)
        tables.append(
            pa.table(
                {
                    "sequence_id": pa.array([rollout_id(Origin.STUDENT, method, task, i)] * (n * k)),
                    "method": pa.array([method] * (n * k)),
                    "task": pa.array([task] * (n * k)),
                    "reference_id": pa.array([rid] * (n * k)),
                    "variant": pa.array([variant] * (n * k)),
                    "t": np.repeat(np.arange(n) * dt, k),
                    "t_ref": np.repeat(tr, k),
                    "region": pa.array(np.tile(np.asarray(ROBOT_REGIONS), n)),
                    "logit": logits.reshape(-1),
                    "contact": pc.greater(pa.array(logits.reshape(-1)), 0.0),  # pyright: ignore[reportAttributeAccessIssue]
                }
            )
        )
    return pa.concat_tables(tables).cast(unseeded("student_predictions"))


@dataclass
class Reconstruction:
    """Demonstrations of one task reconstructed by a student."""

    rollouts: pa.Table  # origin student: every reconstructed demonstration
    contacts: pa.Table  # source reconstructed: the evaluated demonstrations only
    predictions: pa.Table  # student_predictions: the evaluated demonstrations only
    figures: dict[str, float]  # over the evaluated demonstrations


def reconstruct_task(
    net: StudentNet,
    task: str,
    refs: list[DemoReference],
    config: TeacherConfig,
    method: str,
    variant: str,
    teacher_rollouts: pa.Table | None = None,
    evaluated: Collection[str] | None = None,
) -> Reconstruction:
    """Batched inference over each demonstration, execution in MuJoCo, and the figures over the
    ``evaluated`` demonstrations (recording ids; default all of ``refs``):

    - ``contact_f1`` (precision, recall): executed sim contacts vs the human preference over all
      time-region pairs; ``success_rate``;
    - ``predicted_contact_f1``: the student's predicted contacts (logit > 0) vs the preference;
    - ``joint_error_student`` / ``joint_error_kinematic``: mean |joint target - teacher's joint
      command| (rad) of the student and of its kinematic input, over the ``teacher_rollouts`` of
      these demonstrations (NaN without any)."""
    evaluated = set(r.recording_id for r in refs) if evaluated is None else set(evaluated)
    unknown = evaluated - {r.recording_id for r in refs}
    if unknown:
        raise ValueError(f"evaluated demonstrations {sorted(unknown)} are not among the reconstructed ones")
    points = build_scene(task, config.sim).point_cloud
    outputs = [predict_recording(net, reference_inputs(r), points) for r in refs]
    stacked = stack_references(refs)
    env = BatchEnv(build_scene(task, config.sim), config.sim, len(refs))
    try:
        rollouts, contacts = execute(env, DemoTracking(stacked, config, method), outputs, config, method)
    finally:
        env.close()
    keep = pa.array(sorted(evaluated))
    scored = rollouts.filter(pc.is_in(rollouts["reference_id"], keep))  # pyright: ignore[reportAttributeAccessIssue]
    contacts = contacts.filter(pc.is_in(contacts["reference_id"], keep))  # pyright: ignore[reportAttributeAccessIssue]
    figures = {k: float(v) for k, v in summary(scored, stacked, config.sim.contact_threshold_n).items()}
    chosen = [i for i, r in enumerate(refs) if r.recording_id in evaluated]
    predicted = contact_scores(
        np.concatenate([refs[i].preference for i in chosen]),
        np.concatenate([outputs[i].contact_logits > 0 for i in chosen]),
    )
    figures["predicted_contact_f1"] = predicted.f1
    student_err, kinematic_err = [], []
    if teacher_rollouts is not None:
        by_id = {refs[i].recording_id: (refs[i], outputs[i]) for i in chosen}
        for seq in paired_sequences(
            teacher_rollouts, {k: v[0] for k, v in by_id.items()}, config.sim.contact_threshold_n
        ):
            ref, out = by_id[seq.reference_id]
            frame = np.minimum(seq.step, ref.length - 1)
            student_err.append(np.abs(out.joints[frame] - seq.target_joints).ravel())
            kinematic_err.append(np.abs(ref.joints[frame] - seq.target_joints).ravel())
    figures["joint_error_student"] = float(np.concatenate(student_err).mean()) if student_err else float("nan")
    figures["joint_error_kinematic"] = float(np.concatenate(kinematic_err).mean()) if kinematic_err else float("nan")
    predictions = prediction_rows(
        outputs, stacked.ids, [r.t_ref for r in refs], task, method, variant, config.sim.control_dt
    )
    predictions = predictions.filter(pc.is_in(predictions["reference_id"], keep))  # pyright: ignore[reportAttributeAccessIssue]
    return Reconstruction(rollouts, contacts, predictions, figures)
