"""The domain's vocabulary: every name that stands for a method, a contact source, a rollout origin, a
recording kind or an ingest status. Each is a StrEnum, so a member equals, prints and stores as its plain
string (Parquet partitions, SQL, MLflow tags and lake file ids keep their text) while the code names it."""

from __future__ import annotations

from enum import StrEnum


class Method(StrEnum):
    """A retargeting method: the paper's and its three baselines."""

    TOUCH2ROBOT = "touch2robot"
    CONTRACK = "contrack"
    DEXMACHINA = "dexmachina"
    DEX_RETARGETING = "dex-retargeting"  # kinematic retargeting only: no teacher, no contact signal


# Methods with a PPO teacher (Dex Retargeting is the kinematic baseline: nothing to train).
TEACHER_METHODS: tuple[Method, ...] = (Method.TOUCH2ROBOT, Method.CONTRACK, Method.DEXMACHINA)


class Source(StrEnum):
    """Where the rows of the `contacts` table come from."""

    HUMAN = "human"  # the glove: the human's tactile preference
    SIM = "sim"  # simulated robot trajectories (teachers' rollouts, kinematic replays)
    REAL = "real"  # robot replays: TwinTac fingertips and palm FSRs
    RECONSTRUCTED = "reconstructed"  # the student's reconstructions of held-out demonstrations


class Origin(StrEnum):
    """What produced a robot trajectory of the `rollouts` table."""

    TEACHER = "teacher"  # a method's PPO teacher
    KINEMATIC = "kinematic"  # the kinematic retargeting replayed open loop (Dex Retargeting)
    STUDENT = "student"  # the distilled student retargeter (Touch2Robot without RL)


class RecordingKind(StrEnum):
    """The kinds of MCAP recording the rig writes (schemas/messages.py lists each kind's topics)."""

    GLOVE_SESSION = "glove_session"
    ROBOT_REPLAY = "robot_replay"
    ROBOT_CALIBRATION = "robot_calibration"


class RecordingStatus(StrEnum):
    """The outcome of ingesting one recording file (the `recordings` table holds the first two)."""

    INGESTED = "ingested"
    QUARANTINED = "quarantined"
    UNCHANGED = "unchanged"  # ingested before, with the same content: nothing written
