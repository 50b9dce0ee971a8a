"""Which robot trajectories the replay stage executes on the twin (or a lab's rig), and where the
recordings go.

Every method is replayed on the same glove demonstrations of a task (the first ``demos_per_task``
in file-name order), so the methods' real-side figures compare like with like; a demonstration's
replays also share the twin's draw of hardware (the seed is the task's and the demonstration's,
not the method's). Which trajectory stands for a method is data: its rollouts of one origin (a
teacher's, the kinematic baseline's or the distilled student's), the first that follows the
demonstration. A method without such a trajectory is skipped with the reason.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import pyarrow.compute as pc
import pyarrow.parquet as pq
from pydantic import BaseModel, ConfigDict, Field

from schemas.vocabulary import Method, Origin
from touch2robot import scenes
from touch2robot.datasets import ROLLOUTS, glove_sessions, rollouts_key


class ReplayConfig(BaseModel):
    """What the replay stage executes (defaults: the paper profile). The twin's hardware is the
    ``twin`` section (:class:`touch2robot.twin.config.TwinConfig`)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    tasks: tuple[str, ...] = scenes.TASKS
    methods: tuple[str, ...] = tuple(Method)
    demos_per_task: int = Field(
        default=10, ge=1, le=1000, description="glove demonstrations per task replayed, the same ones for every method"
    )
    touch2robot_origin: Literal["student", "teacher"] = Field(
        default="student",
        description="Touch2Robot's trajectories: the distilled student's reconstructions (the paper's robot "
        "demonstrations) or its teacher's rollouts",
    )
    seed: int = Field(default=0, ge=0, description="seed of the twin's per-replay draws")

    def origin(self, method: str) -> str:
        """The rollouts origin whose trajectories stand for ``method``."""
        if method == Method.DEX_RETARGETING:
            return Origin.KINEMATIC
        if method == Method.TOUCH2ROBOT:
            return self.touch2robot_origin
        return Origin.TEACHER


@dataclass(frozen=True)
class ReplayJob:
    """One trajectory to execute: the rollout, the demonstration it follows and the files to write."""

    task: str
    method: str
    origin: str
    trajectory: str  # rollout_id
    rollouts_file: str
    reference_id: str  # the glove session's recording id
    reference_recording: str  # its file name
    subject: str
    demo_index: int  # the demonstration's place among the task's replayed ones: seeds the twin's draw
    folder: str  # the glove session's folder: a replay names its reference and calibration by file name there
    seed: int  # the sweep seed of the trajectory

    @property
    def stem(self) -> str:
        return f"{Path(self.reference_recording).stem.removesuffix('_glove')}_{self.method}_seed{self.seed}"

    @property
    def replay_path(self) -> Path:
        return Path(self.folder) / f"{self.stem}_replay.mcap"

    @property
    def calibration_path(self) -> Path:
        return Path(self.folder) / f"{self.stem}_calib.mcap"

    def twin_seed(self, base: int) -> tuple[int, int, int]:
        """The twin's seed under the sweep seed's ``replay.seed``: the same hardware draw for every method's replay
        of one demonstration."""
        return (base, scenes.TASKS.index(self.task), self.demo_index)

    def metadata(self, rig: str) -> dict[str, str]:
        """The replay MCAP's metadata, as schemas.messages.METADATA_KEYS asks for a robot replay."""
        return {
            "task": self.task,
            "subject": self.subject,
            "method": self.method,
            "reference_recording": self.reference_recording,
            "calibration_recording": self.calibration_path.name,
            "trajectory": self.trajectory,
            "seed": str(self.seed),
            "rig": rig,
        }


@dataclass(frozen=True)
class Skipped:
    """A task x method (or one of its demonstrations) with nothing to replay, and why."""

    task: str
    method: str
    reason: str


def _trajectories(path: Path) -> dict[str, str]:
    """reference_id -> the first rollout_id that follows it, in a rollouts file."""
    table = pq.read_table(path, columns=["rollout_id", "reference_id", "step"])
    first = table.filter(pc.field("step") == 0).sort_by("rollout_id")
    out: dict[str, str] = {}
    for rid, ref in zip(first["rollout_id"].to_pylist(), first["reference_id"].to_pylist(), strict=True):
        out.setdefault(ref, rid)
    return out


def _glove_folder(glove: dict, recordings: Path) -> Path:
    """Where a glove session is now: under this data folder's recordings where it was ingested from there
    (a copied data folder's rows still name the old place), else where it was ingested from (``--folder``)."""
    recordings = recordings.resolve()
    ingested_from = Path(glove["path"])
    if ingested_from.is_relative_to(recordings) and ingested_from.is_file():
        return ingested_from.parent
    if (recordings / glove["file_name"]).is_file():
        return recordings
    return ingested_from.parent if ingested_from.is_file() else recordings


def plan_replays(
    lake: Path, recordings: Path, config: ReplayConfig, seed: int
) -> tuple[list[ReplayJob], list[Skipped]]:
    """The replays ``config`` (sweep seed ``seed``'s) asks for, given the lake's glove sessions and that seed's
    rollouts; and what is skipped."""
    for method in config.methods:
        if method not in set(Method):
            raise ValueError(f"replay.methods: unknown method {method!r}; expected one of {', '.join(Method)}")
    jobs: list[ReplayJob] = []
    skipped: list[Skipped] = []
    gloves = glove_sessions(lake)
    for task in config.tasks:
        demos = [g for g in gloves if g["task"] == task][: config.demos_per_task]
        if not demos:
            skipped += [Skipped(task, m, f"no ingested glove session of task {task!r}") for m in config.methods]
            continue
        for method in config.methods:
            origin = config.origin(method)
            path = ROLLOUTS.path(lake, rollouts_key(origin, task, seed), method=method)
            if not path.is_file():
                skipped.append(Skipped(task, method, f"no {origin} rollouts of {method} on {task} ({path.name})"))
                continue
            following = _trajectories(path)
            for k, glove in enumerate(demos):
                trajectory = following.get(glove["recording_id"])
                if trajectory is None:
                    reason = f"no {origin} rollout of {method} follows demonstration {glove['file_name']}"
                    skipped.append(Skipped(task, method, reason))
                    continue
                folder = _glove_folder(glove, recordings)
                jobs.append(
                    ReplayJob(
                        task=task,
                        method=method,
                        origin=origin,
                        trajectory=trajectory,
                        rollouts_file=str(path),
                        reference_id=glove["recording_id"],
                        reference_recording=glove["file_name"],
                        subject=glove["subject"],
                        demo_index=k,
                        folder=str(folder),
                        seed=seed,
                    )
                )
    return jobs, skipped
