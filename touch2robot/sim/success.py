"""Task success as a function of the object's state, vectorised over the batch.

The criteria and their parameters come from the task specs (``TaskSpec.success``):
pick — final position within ``pos_tol_m`` of the goal after lifting at least ``lift_m``;
rotate — rotation about the spec's axis within ``angle_tol_rad`` of the target angle, centre kept
within ``pos_tol_m``; wipe — share of path waypoints the sponge centre passed within
``radius_m`` at least ``coverage``; drawer — opening along the slide at least ``opening_m``.
Progress-type quantities that need the episode's history (maximum lift, visited waypoints) are
accumulated by ``SuccessTracker``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from touch2robot.geometry import quat_mul
from touch2robot.scenes.spec import TaskSpec


def quat_conj(q: np.ndarray) -> np.ndarray:
    """Conjugate (= inverse for unit quaternions) of (..., 4) quaternions (w, x, y, z)."""
    return np.asarray(q) * np.array([1.0, -1.0, -1.0, -1.0])


def twist_angle(quat: np.ndarray, quat0: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Signed angle (rad, in (-pi, pi]) of the rotation from ``quat0`` to ``quat`` (world frame)
    about the world ``axis`` (swing-twist decomposition: the tilt about other axes is ignored)."""
    rel = quat_mul(np.asarray(quat), quat_conj(np.asarray(quat0)))
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    return 2.0 * np.arctan2(rel[..., 1:] @ axis, rel[..., 0])


def wrap_angle(angle: np.ndarray) -> np.ndarray:
    """Angles wrapped to (-pi, pi]."""
    return np.angle(np.exp(1j * np.asarray(angle)))


class SuccessTracker:
    """Per-copy success bookkeeping of one task over the episode.

    ``reset(ids, pos, quat, opening)`` stores the initial object state of copies ``ids``;
    ``update(pos, quat, opening)`` is called once per control step with the whole batch
    (``opening`` is the drawer's slide position, zeros for free objects).
    """

    def __init__(self, spec: TaskSpec, n: int) -> None:
        self.spec = spec
        self.pos0 = np.zeros((n, 3))
        self.quat0 = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
        self.max_lift = np.zeros(n)
        n_way = len(spec.wipe_path or ())
        self.visited = np.zeros((n, n_way), dtype=bool)
        self.success = np.zeros(n, dtype=bool)
        self.progress = np.zeros(n)
        self._criterion: Callable[[np.ndarray, np.ndarray, np.ndarray], None] = {
            "pick": self._pick,
            "rotate": self._rotate,
            "wipe": self._wipe,
            "drawer": self._drawer,
        }[spec.name]

    def reset(self, ids: np.ndarray, pos: np.ndarray, quat: np.ndarray) -> None:
        """Start the episode of copies ``ids`` from object poses ``pos`` (k, 3), ``quat`` (k, 4)."""
        self.pos0[ids] = pos
        self.quat0[ids] = quat
        self.max_lift[ids] = 0.0
        self.visited[ids] = False
        self.success[ids] = False
        self.progress[ids] = 0.0

    def update(self, pos: np.ndarray, quat: np.ndarray, opening: np.ndarray) -> None:
        """Advance the bookkeeping with the current object state of every copy."""
        self._criterion(pos, quat, opening)

    def _pick(self, pos: np.ndarray, quat: np.ndarray, opening: np.ndarray) -> None:
        s = self.spec.success
        self.max_lift = np.maximum(self.max_lift, pos[:, 2] - self.pos0[:, 2])
        dist = np.linalg.norm(pos - np.asarray(self.spec.goal_pos), axis=1)
        start = np.linalg.norm(self.pos0 - np.asarray(self.spec.goal_pos), axis=1)
        self.progress = np.clip(1.0 - dist / np.maximum(start, 1e-9), 0.0, 1.0)
        self.success = (dist <= s["pos_tol_m"]) & (self.max_lift >= s["lift_m"])

    def _rotate(self, pos: np.ndarray, quat: np.ndarray, opening: np.ndarray) -> None:
        s = self.spec.success
        assert self.spec.rotation_axis is not None and self.spec.rotation_angle is not None
        angle = twist_angle(quat, self.quat0, np.asarray(self.spec.rotation_axis))
        error = np.abs(wrap_angle(angle - self.spec.rotation_angle))
        self.progress = np.clip(1.0 - error / abs(self.spec.rotation_angle), 0.0, 1.0)
        drift = np.linalg.norm(pos - self.pos0, axis=1)
        self.success = (error <= s["angle_tol_rad"]) & (drift <= s["pos_tol_m"])

    def _wipe(self, pos: np.ndarray, quat: np.ndarray, opening: np.ndarray) -> None:
        s = self.spec.success
        way = np.asarray(self.spec.wipe_path)
        near = np.linalg.norm(pos[:, None, :2] - way[None], axis=2) <= s["radius_m"]
        self.visited |= near
        self.progress = self.visited.mean(axis=1)
        self.success = self.progress >= s["coverage"]

    def _drawer(self, pos: np.ndarray, quat: np.ndarray, opening: np.ndarray) -> None:
        target = self.spec.success["opening_m"]
        self.progress = np.clip(opening / target, 0.0, 1.0)
        self.success = opening >= target
