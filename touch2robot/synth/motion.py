"""Scripted demonstrations: wrist, finger and object trajectories for the four tasks.

A demonstration is built on a fine time grid from keyframed phases (approach, close,
manipulate, open, retreat) with minimum-jerk blending. While the object is held it moves
rigidly with the wrist, and the fingers close only until the skin touches the object
(a per-finger closure found by search against the object's signed distance), so every
contact in the data is one the hand geometry really makes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from schemas.glove import FINGERTIP_TAXELS, PALM_TAXELS
from touch2robot import geometry
from touch2robot.synth.hand import HumanHand, taxel_forces

if TYPE_CHECKING:  # at run time importing touch2robot.scenes would discover the task modules, which use this one
    from touch2robot.scenes.spec import GeomSpec, TaskSpec

GRID_HZ = 500.0


def minjerk(s: np.ndarray) -> np.ndarray:
    s = np.clip(s, 0.0, 1.0)
    return s**3 * (10 - 15 * s + 6 * s * s)


def _slerp(q0: np.ndarray, q1: np.ndarray, s: np.ndarray) -> np.ndarray:
    q0 = np.asarray(q0, float)
    q1 = np.asarray(q1, float)
    if np.dot(q0, q1) < 0:
        q1 = -q1
    dot = np.clip(np.dot(q0, q1), -1.0, 1.0)
    theta = np.arccos(dot)
    s = np.asarray(s, float)[..., None]
    if theta < 1e-6:
        q = (1 - s) * q0 + s * q1
    else:
        q = (np.sin((1 - s) * theta) * q0 + np.sin(s * theta) * q1) / np.sin(theta)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


@dataclass
class Trajectory:
    """A demonstration on the fine grid; ``sample`` interpolates it at sensor stamps."""

    t: np.ndarray  # (N,)
    wrist_pos: np.ndarray  # (N, 3)
    wrist_quat: np.ndarray  # (N, 4)
    joints: np.ndarray  # (N, 20)
    object_pos: np.ndarray  # (N, 3)
    object_quat: np.ndarray  # (N, 4)

    def sample(self, times: np.ndarray) -> Trajectory:
        def lerp(a: np.ndarray) -> np.ndarray:
            return np.stack([np.interp(times, self.t, a[:, k]) for k in range(a.shape[1])], -1)

        def qlerp(q: np.ndarray) -> np.ndarray:
            v = lerp(q)
            return v / np.linalg.norm(v, axis=-1, keepdims=True)

        return Trajectory(
            np.asarray(times, float),
            lerp(self.wrist_pos),
            qlerp(self.wrist_quat),
            lerp(self.joints),
            lerp(self.object_pos),
            qlerp(self.object_quat),
        )


class _Builder:
    """Accumulates phases on the fine grid. Each phase moves wrist, joints and object
    from the current state to a target with minimum-jerk timing."""

    def __init__(self, wrist_pos, wrist_quat, joints, obj_pos, obj_quat) -> None:
        self.rows: list[tuple] = [
            (
                0.0,
                np.asarray(wrist_pos, float),
                np.asarray(wrist_quat, float),
                np.asarray(joints, float),
                np.asarray(obj_pos, float),
                np.asarray(obj_quat, float),
            )
        ]

    @property
    def state(self) -> tuple:
        return self.rows[-1]

    def phase(self, duration: float, wrist_pos=None, wrist_quat=None, joints=None, obj_pos=None, obj_quat=None) -> None:
        t0, wp, wq, jq, op, oq = self.state
        n = max(2, round(duration * GRID_HZ))
        s = minjerk(np.arange(1, n + 1) / n)
        tgt = [
            wp if wrist_pos is None else np.asarray(wrist_pos, float),
            wq if wrist_quat is None else np.asarray(wrist_quat, float),
            jq if joints is None else np.asarray(joints, float),
            op if obj_pos is None else np.asarray(obj_pos, float),
            oq if obj_quat is None else np.asarray(obj_quat, float),
        ]
        wps = wp + s[:, None] * (tgt[0] - wp)
        wqs = _slerp(wq, tgt[1], s)
        jqs = jq + s[:, None] * (tgt[2] - jq)
        ops = op + s[:, None] * (tgt[3] - op)
        oqs = _slerp(oq, tgt[4], s)
        for k in range(n):
            self.rows.append((t0 + (k + 1) / GRID_HZ, wps[k], wqs[k], jqs[k], ops[k], oqs[k]))

    def carry(self, duration: float, obj_pos, obj_quat) -> None:
        """Move the object to a pose with the hand rigidly attached (the grasp holds)."""
        t0, wp, wq, jq, op, oq = self.state
        rel_pos = geometry.inverse_transform_points(wp[None], op, oq)[0]
        rel_rot = geometry.quat_to_mat(oq).T @ geometry.quat_to_mat(wq)
        n = max(2, round(duration * GRID_HZ))
        s = minjerk(np.arange(1, n + 1) / n)
        ops = op + s[:, None] * (np.asarray(obj_pos, float) - op)
        oqs = _slerp(oq, obj_quat, s)
        wps = geometry.transform_points(np.broadcast_to(rel_pos, (n, 1, 3)), ops, oqs)[:, 0]
        wqs = geometry.mat_to_quat(geometry.quat_to_mat(oqs) @ rel_rot)
        for k in range(n):
            self.rows.append((t0 + (k + 1) / GRID_HZ, wps[k], wqs[k], jq, ops[k], oqs[k]))

    def hold(self, duration: float) -> None:
        self.phase(duration)

    def build(self) -> Trajectory:
        cols = list(zip(*self.rows, strict=True))
        return Trajectory(*(np.asarray(c, float) for c in cols))


@dataclass(frozen=True)
class Scene:
    """The contact surfaces a hand can touch: the object (moving) and the static world."""

    object_geoms: tuple[GeomSpec, ...]
    static_geoms: tuple[GeomSpec, ...]  # in the world frame (cabinet), table handled as z < 0
    table_half_extent: tuple[float, float]

    @classmethod
    def from_task(cls, spec: TaskSpec) -> Scene:
        static = spec.slide.cabinet if spec.slide is not None else ()
        return cls(spec.object.geoms, static, spec.table_half_extent)

    def penetration(self, points: np.ndarray, obj_pos: np.ndarray, obj_quat: np.ndarray) -> np.ndarray:
        """Skin compression depth (m, >= 0) of world points (T, N, 3) against all surfaces."""
        local = geometry.inverse_transform_points(points, obj_pos, obj_quat)
        depth = -geometry.body_sdf(self.object_geoms, local)
        on_table = (np.abs(points[..., 0]) < self.table_half_extent[0]) & (
            np.abs(points[..., 1]) < self.table_half_extent[1]
        )
        depth = np.maximum(depth, np.where(on_table, -points[..., 2], 0.0))
        if self.static_geoms:
            depth = np.maximum(depth, -geometry.body_sdf(self.static_geoms, points))
        return np.maximum(depth, 0.0)


def taxel_forces_along(hand: HumanHand, scene: Scene, traj: Trajectory) -> np.ndarray:
    """Per-taxel normal force (T, 256) along a (sampled) trajectory."""
    pose = hand.forward(traj.joints)
    world = geometry.transform_points(pose.taxel_points, traj.wrist_pos, traj.wrist_quat)
    return taxel_forces(scene.penetration(world, traj.object_pos, traj.object_quat))


def close_fingers(
    hand: HumanHand,
    scene: Scene,
    wrist_pos: np.ndarray,
    wrist_quat: np.ndarray,
    obj_pos: np.ndarray,
    obj_quat: np.ndarray,
    q_open: np.ndarray,
    q_close: np.ndarray,
    depth: np.ndarray,
    fingers: tuple[int, ...] = (0, 1, 2, 3, 4),
) -> np.ndarray:
    """Close each finger from ``q_open`` towards ``q_close`` until its skin is compressed
    by ``depth[f]`` metres somewhere (first touch along the closing path, refined by
    bisection). A finger that never touches stops at its ``q_close``; fingers not listed stay open."""
    steps = np.linspace(0.0, 1.0, 41)
    q = np.array(q_open, float)
    for f in fingers:
        cols = slice(4 * f, 4 * f + 4)

        # called in this iteration only, so reading the loop's cols and f is safe
        def max_depth(s: np.ndarray) -> np.ndarray:
            qs = np.repeat(q[None], len(s), 0)
            qs[:, cols] = q_open[cols] + s[:, None] * (q_close[cols] - q_open[cols])  # noqa: B023
            pts = hand.forward(qs).taxel_points
            world = geometry.transform_points(
                pts, np.broadcast_to(wrist_pos, (len(s), 3)), np.broadcast_to(wrist_quat, (len(s), 4))
            )
            pen = scene.penetration(
                world, np.broadcast_to(obj_pos, (len(s), 3)), np.broadcast_to(obj_quat, (len(s), 4))
            )
            return pen[:, _finger_taxels(f)].max(axis=1)  # noqa: B023

        d = max_depth(steps)
        hit = np.flatnonzero(d >= depth[f])
        if hit.size == 0:
            s = 1.0
        elif hit[0] == 0:
            s = 0.0
        else:
            lo, hi = steps[hit[0] - 1], steps[hit[0]]
            for _ in range(12):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if max_depth(np.array([mid]))[0] < depth[f] else (lo, mid)
            s = hi
        q[cols] = q_open[cols] + s * (q_close[cols] - q_open[cols])
    return q


def _finger_taxels(f: int) -> np.ndarray:
    """Taxels of finger ``f`` that may touch while it closes: its tip pad and, for the four
    fingers, the proximal-phalanx taxels."""
    tip = np.arange(f * FINGERTIP_TAXELS, (f + 1) * FINGERTIP_TAXELS)
    if f == 0:
        return tip
    start = 5 * FINGERTIP_TAXELS + 4 * PALM_TAXELS + (f - 1) * 6
    return np.concatenate([tip, np.arange(start, start + 6)])
