"""One glove session and the robot trajectories made from it, as the view shows them: read from the lake
through the read-only catalog, every stream on the reference recording's clock (``t_ref``)."""

from __future__ import annotations

from dataclasses import dataclass

import duckdb
import numpy as np

from schemas.tables import HUMAN_REGIONS, ROBOT_REGIONS
from schemas.vocabulary import Origin, RecordingKind, RecordingStatus, Source
from touch2robot import catalog
from touch2robot.settings import DataLayout


class ViewError(ValueError):
    """A demonstration or trajectory the view cannot show; the message says what to do instead."""


@dataclass(frozen=True)
class TrajectoryChoice:
    """One robot trajectory of a demonstration: ``key`` identifies it (a rollout id, or a replay's
    recording id), ``label`` is what the menu says."""

    key: str
    label: str
    kind: str  # "rollout" or "replay"
    origin: str
    method: str
    seed: int


@dataclass(frozen=True)
class RobotTrajectory:
    """A robot trajectory on its own stamps on the reference clock (``t_ref``): joints (N, 16), wrist
    (N, 7: px py pz qw qx qy qz), object (N, 7) and drawer opening (N,), and its contacts (M, 8) in
    ``ROBOT_REGIONS`` order at ``contact_t`` (M,)."""

    choice: TrajectoryChoice
    t_ref: np.ndarray
    joints: np.ndarray
    wrist: np.ndarray
    object_pose: np.ndarray
    drawer_opening: np.ndarray
    contact_t: np.ndarray
    contacts: np.ndarray
    contact_source: str

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """Joints, wrist, object pose and drawer opening at reference time ``t`` (the sample at or before it)."""
        i = _index_at(self.t_ref, t)
        return self.joints[i], self.wrist[i], self.object_pose[i], float(self.drawer_opening[i])

    def contacts_at(self, t: float) -> np.ndarray:
        """The 8 robot regions' contacts at ``t`` (none before the first contact row or without any)."""
        if not len(self.contact_t) or t < self.contact_t[0]:
            return np.zeros(len(ROBOT_REGIONS), bool)
        return self.contacts[_index_at(self.contact_t, t)]


@dataclass(frozen=True)
class Demonstration:
    """A glove session: keypoints (T, 21, 3) at ``t`` and the human's contacts (M, 9) in ``HUMAN_REGIONS``
    order at ``contact_t``. The lake keeps the 8 regions that have a robot counterpart: T5 (the little
    finger) is never in contact there."""

    recording_id: str
    file_name: str
    task: str
    subject: str
    t: np.ndarray
    keypoints: np.ndarray
    contact_t: np.ndarray
    contacts: np.ndarray
    trajectories: tuple[TrajectoryChoice, ...]

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self.t) else 0.0

    def keypoints_at(self, t: float) -> np.ndarray:
        return self.keypoints[_index_at(self.t, t)]

    def contacts_at(self, t: float) -> np.ndarray:
        if not len(self.contact_t) or t < self.contact_t[0]:
            return np.zeros(len(HUMAN_REGIONS), bool)
        return self.contacts[_index_at(self.contact_t, t)]


def _index_at(stamps: np.ndarray, t: float) -> int:
    return int(np.clip(np.searchsorted(stamps, t, side="right") - 1, 0, len(stamps) - 1))


def _columns(con: duckdb.DuckDBPyConnection, sql: str, params: list) -> dict[str, np.ndarray]:
    """A query's columns as arrays, list columns stacked to 2-D."""
    table = con.sql(sql, params=params).to_arrow_table()
    out = {}
    for name in table.column_names:
        values = table[name].to_pylist()
        out[name] = np.array(values, dtype=np.float64) if values else np.zeros(0)
    return out


def _connect(layout: DataLayout) -> duckdb.DuckDBPyConnection:
    try:
        return catalog.connect_read_only(layout)
    except FileNotFoundError as e:
        raise ViewError(str(e)) from None


def glove_sessions(layout: DataLayout) -> list[tuple[str, str, str]]:
    """(recording_id, file_name, task) of every ingested glove session, by file name."""
    with _connect(layout) as con:
        return con.sql(
            "SELECT recording_id, file_name, task FROM recordings WHERE kind = ? AND status = ? ORDER BY file_name",
            params=[RecordingKind.GLOVE_SESSION, RecordingStatus.INGESTED],
        ).fetchall()


def _contact_matrix(rows: list[tuple[float, str, bool]], regions: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Long contact rows (t_ref, region, contact) as stamps (M,) and a (M, len(regions)) matrix."""
    if not rows:
        return np.zeros(0), np.zeros((0, len(regions)), bool)
    t = np.array(sorted({r[0] for r in rows}))
    out = np.zeros((len(t), len(regions)), bool)
    column = {r: k for k, r in enumerate(regions)}
    for t_ref, region, contact in rows:
        if region in column:
            out[np.searchsorted(t, t_ref), column[region]] = bool(contact)
    return t, out


def load_demonstration(layout: DataLayout, recording_id: str) -> Demonstration:
    """The glove session ``recording_id`` (an id or its file name), its keypoints, its human contacts and the
    robot trajectories made from it. ``ViewError`` names what exists when it is not in the lake."""
    with _connect(layout) as con:
        found = con.sql(
            "SELECT recording_id, file_name, task, subject, kind, status FROM recordings"
            " WHERE recording_id = ? OR file_name = ?",
            params=[recording_id, recording_id],
        ).fetchall()
        glove = [r for r in found if r[4] == RecordingKind.GLOVE_SESSION and r[5] == RecordingStatus.INGESTED]
        if not glove:
            known = con.sql(
                "SELECT recording_id || ' (' || file_name || ')' FROM recordings WHERE kind = ? AND status = ?"
                " ORDER BY file_name LIMIT 5",
                params=[RecordingKind.GLOVE_SESSION, RecordingStatus.INGESTED],
            ).fetchall()
            what = (
                f"is a {found[0][4]} recording ({found[0][5]}), not an ingested glove session"
                if found
                else "is not in the lake's recordings"
            )
            listing = ", ".join(k[0] for k in known) or "none: run `touch2robot ingest` first"
            raise ViewError(
                f"recording {recording_id!r} {what}; glove sessions: {listing}"
                " (all: touch2robot sql \"select recording_id, file_name from recordings where kind='glove_session'\")"
            )
        rid, file_name, task, subject = glove[0][:4]
        key = _columns(con, "SELECT t, xyz FROM hand_keypoints WHERE recording_id = ? ORDER BY t", [rid])
        if not len(key["t"]):
            raise ViewError(f"recording {rid!r} ({file_name}) has no hand keypoints in the lake")
        human = con.sql(
            "SELECT t_ref, region, contact FROM contacts WHERE source = ? AND sequence_id = ?",
            params=[Source.HUMAN, rid],
        ).fetchall()
        rollouts = con.sql(
            "SELECT DISTINCT rollout_id, origin, method, seed FROM rollouts WHERE reference_id = ? ORDER BY ALL",
            params=[rid],
        ).fetchall()
        replays = con.sql(
            "SELECT DISTINCT c.sequence_id, r.method, c.seed, r.trajectory FROM contacts c"
            " JOIN recordings r ON r.recording_id = c.sequence_id WHERE c.source = ? AND c.reference_id = ?"
            " ORDER BY ALL",
            params=[Source.REAL, rid],
        ).fetchall()
    origin_of = {r[0]: r[1] for r in rollouts}
    choices = [
        TrajectoryChoice(
            rollout, f"{_ORIGIN_LABEL.get(origin, origin)} · seed {seed} · {rollout}", "rollout", origin, method, seed
        )
        for rollout, origin, method, seed in rollouts
    ] + [
        TrajectoryChoice(
            replay,
            f"twin replay · seed {seed} · {trajectory} ({replay})",
            "replay",
            origin_of.get(trajectory, ""),
            method,
            seed,
        )
        for replay, method, seed, trajectory in replays
    ]
    contact_t, contacts = _contact_matrix(human, HUMAN_REGIONS)
    xyz = key["xyz"].reshape(len(key["t"]), -1, 3)
    return Demonstration(rid, file_name, task, subject, key["t"], xyz, contact_t, contacts, tuple(choices))


_ORIGIN_LABEL = {
    Origin.KINEMATIC: "retargeted (kinematic)",
    Origin.TEACHER: "teacher rollout",
    Origin.STUDENT: "student reconstruction",
}


def _rollout_rows(con: duckdb.DuckDBPyConnection, rollout_id: str) -> dict[str, np.ndarray]:
    return _columns(
        con,
        "SELECT t_ref, joint_position, wrist_state, object_pose, drawer_opening FROM rollouts"
        " WHERE rollout_id = ? ORDER BY step",
        [rollout_id],
    )


def load_trajectory(layout: DataLayout, choice: TrajectoryChoice) -> RobotTrajectory:
    """The robot trajectory ``choice`` names. A twin replay's joints are the replay's measured joint states
    on the reference clock (its time map); wrist and object are those of the trajectory it executed (the
    replay records neither)."""
    with _connect(layout) as con:
        if choice.kind == "rollout":
            rows = _rollout_rows(con, choice.key)
            t_ref, joints = rows["t_ref"], rows["joint_position"]
            source = Source.RECONSTRUCTED if choice.origin == Origin.STUDENT else Source.SIM
            wrist, obj, drawer = rows["wrist_state"], rows["object_pose"], rows["drawer_opening"]
        else:
            found = con.sql("SELECT trajectory FROM recordings WHERE recording_id = ?", params=[choice.key]).fetchall()
            trajectory = found[0][0] if found else ""
            rows = _rollout_rows(con, trajectory)
            states = _columns(
                con, "SELECT t, position FROM robot_joint_states WHERE recording_id = ? ORDER BY t", [choice.key]
            )
            time_map = _columns(con, "SELECT t, t_ref FROM time_map WHERE recording_id = ? ORDER BY t", [choice.key])
            if not len(states["t"]) or not len(time_map["t"]) or not len(rows["t_ref"]):
                raise ViewError(f"twin replay {choice.key!r} lacks joint states, a time map or its trajectory")
            t_ref = np.asarray(np.interp(states["t"], time_map["t"], time_map["t_ref"]))
            joints = states["position"]
            at = np.clip(np.searchsorted(rows["t_ref"], t_ref, side="right") - 1, 0, len(rows["t_ref"]) - 1)
            wrist, obj, drawer = rows["wrist_state"][at], rows["object_pose"][at], rows["drawer_opening"][at]
            source = Source.REAL
        contact_rows = con.sql(
            "SELECT t_ref, region, contact FROM contacts WHERE source = ? AND sequence_id = ?",
            params=[source, choice.key],
        ).fetchall()
    if not len(t_ref):
        raise ViewError(f"trajectory {choice.key!r} has no rows in the lake")
    contact_t, contacts = _contact_matrix(contact_rows, ROBOT_REGIONS)
    return RobotTrajectory(choice, t_ref, joints, wrist, obj, drawer, contact_t, contacts, str(source))
