"""Each task's reference success: the kinematic replay of every demonstration in MuJoCo.

A demonstration's kinematic reference (Dex Retargeting's joints and the robot wrist pose on the
control grid) is replayed open loop from the demonstration's first frame, object at its recorded
pose, to its last frame, with no residual, no assistance and no early termination. The replay is
the teachers' own (``DemoTracking``'s reset and command with zero actions, as the kinematic
rollouts), so what succeeds here is what a teacher starts from. Success is the task's criterion at
the demonstration's last frame; tracking is lost when the object leaves its reference by more than
the objective's thresholds (``TeacherConfig.lost_pos_m`` / ``lost_rot_rad``, after its grace steps).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from schemas.vocabulary import Method
from touch2robot.datasets import retargeted_demonstrations
from touch2robot.scenes.spec import TaskSpec
from touch2robot.sim.config import SimConfig
from touch2robot.sim.env import BatchEnv
from touch2robot.sim.guard import LostPhysicsError
from touch2robot.sim.scene import build_scene
from touch2robot.teachers.config import TeacherConfig
from touch2robot.teachers.objective import NUM_ACTIONS, DemoTracking, References, load_references

REFERENCE_TARGET = 0.9  # issue 33: share of each task's demonstrations whose kinematic replay succeeds


@dataclass(frozen=True)
class ReferenceCheck:
    """The kinematic replay of one demonstration."""

    task: str
    recording_id: str
    subject: str
    success: bool  # the task's criterion at the demonstration's last frame
    progress: float  # the task's progress there, in [0, 1]
    lost_at_s: float | None  # first time past the grace steps the object left its reference; None = never
    max_pos_error_m: float  # object position (drawer: opening) distance to its reference, largest over the replay
    max_rot_error_rad: float  # object orientation distance to its reference (0 for the drawer)
    duration_s: float  # the demonstration's length on the control grid
    steps: int  # control steps replayed
    physics_error: str | None = None  # the replay lost its physics (``LostPhysicsError``): a failure, said why


@dataclass(frozen=True)
class TaskSummary:
    """One task's reference success against ``REFERENCE_TARGET``."""

    task: str
    demonstrations: int
    successes: int

    @property
    def rate(self) -> float | None:
        """Share of demonstrations that succeed; None without demonstrations."""
        return self.successes / self.demonstrations if self.demonstrations else None

    @property
    def passed(self) -> bool:
        """At or above the target (a task without demonstrations has shown nothing)."""
        return self.rate is not None and self.rate >= REFERENCE_TARGET


def _with_sim(teacher: TeacherConfig | None, sim: SimConfig) -> TeacherConfig:
    """The teacher settings with ``sim`` as their simulation: the references' grid is its control rate."""
    return (teacher or TeacherConfig()).model_copy(update={"sim": sim})


def task_references(lake: Path, task: str, teacher: TeacherConfig) -> References | None:
    """A task's retargeted demonstrations on the control grid, as the teachers load them; None
    when the task has none."""
    recordings = retargeted_demonstrations(lake, [task])
    return load_references(lake, recordings, teacher) if recordings else None


def replay_references(
    refs: References,
    task: str | TaskSpec,
    sim: SimConfig,
    teacher: TeacherConfig | None = None,
) -> list[ReferenceCheck]:
    """Replay every demonstration of ``refs`` kinematically, all as copies of one BatchEnv of the
    scene of ``task`` (a registry name or a spec)."""
    teacher = _with_sim(teacher, sim)
    scene = build_scene(task, sim)
    n = len(refs.ids)
    env = BatchEnv(scene, sim, n)
    try:
        objective = DemoTracking(refs, teacher, Method.TOUCH2ROBOT)
        objective.eval_demos = np.arange(n)  # copy i follows demonstration i
        objective.assist_gain = 0.0
        objective.reset(env, np.arange(n), np.random.default_rng(sim.seed))
        no_residual = np.zeros((n, NUM_ACTIONS))
        active = np.ones(n, dtype=bool)
        success, progress = np.zeros(n, dtype=bool), np.zeros(n)
        lost_step = np.full(n, -1)
        max_pos, max_rot = np.zeros(n), np.zeros(n)
        physics_error: dict[int, str] = {}
        while active.any():
            pos_err, rot_err = objective.tracking_errors(env)  # the objective's own distances to the reference
            max_pos = np.where(active, np.maximum(max_pos, pos_err), max_pos)
            max_rot = np.where(active, np.maximum(max_rot, rot_err), max_rot)
            newly_lost = active & (lost_step < 0) & objective.terminated(env)
            lost_step[newly_lost] = env.time_step[newly_lost]
            ended = active & objective.truncated(env)
            success[ended], progress[ended] = env.success[ended], env.progress[ended]
            active &= ~ended
            if active.any():
                # a copy past its last frame is commanded that frame again (its result is taken)
                targets, wrist_pos, wrist_quat, _ = objective.command(env, no_residual)
                try:
                    env.step(targets, wrist_pos, wrist_quat)
                except LostPhysicsError as e:
                    # that replay fails, saying why; the copy rests at the home state (stable by
                    # construction) for the others to go on, its figures no longer taken
                    if e.env is None or e.env in physics_error:  # not one replay's: the check cannot go on
                        raise
                    physics_error[e.env] = str(e)
                    active[e.env], success[e.env] = False, False
                    progress[e.env] = env.progress[e.env]
                    env.reset(np.array([e.env]))
    finally:
        env.close()
    dt = sim.control_dt
    name = scene.spec.name
    return [
        ReferenceCheck(
            task=name,
            recording_id=refs.ids[i],
            subject=refs.subjects[i],
            success=bool(success[i]),
            progress=float(progress[i]),
            lost_at_s=None if lost_step[i] < 0 else round(float(lost_step[i] * dt), 6),
            max_pos_error_m=float(max_pos[i]),
            max_rot_error_rad=float(max_rot[i]),
            duration_s=round(float((refs.length[i] - 1) * dt), 6),
            steps=int(refs.length[i] - 1),
            physics_error=physics_error.get(i),
        )
        for i in range(n)
    ]


def check_references(
    lake: Path,
    tasks: Iterable[str],
    sim: SimConfig,
    teacher: TeacherConfig | None = None,
    spec_override: Mapping[str, TaskSpec] | None = None,
) -> list[ReferenceCheck]:
    """The kinematic replay of every retargeted demonstration of ``tasks``, one BatchEnv per task.
    ``spec_override`` builds a task's scene from another spec (a task's name -> its spec); a task
    without retargeted demonstrations has no rows (``summarize`` reports it)."""
    teacher = _with_sim(teacher, sim)
    overrides = spec_override or {}
    rows: list[ReferenceCheck] = []
    for task in tasks:
        refs = task_references(Path(lake), task, teacher)
        if refs is not None:
            rows += replay_references(refs, overrides.get(task, task), sim, teacher)
    return rows


def summarize(rows: Iterable[ReferenceCheck], tasks: Iterable[str]) -> list[TaskSummary]:
    """Successes per task of ``tasks``, in their order (zero demonstrations for a task without rows)."""
    rows = list(rows)
    return [
        TaskSummary(
            task=task,
            demonstrations=sum(r.task == task for r in rows),
            successes=sum(r.task == task and r.success for r in rows),
        )
        for task in tasks
    ]
