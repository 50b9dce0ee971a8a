"""Building blocks shared by the scripted demonstrations, which live with their tasks in
``touch2robot.scenes`` (``Task.demonstrate``). Each script takes the task spec (shared with the
MuJoCo scenes), a subject's hand, a random generator and a pace, and returns a Trajectory whose
object motion stays feasible in the scene: objects move only while grasped, rest on the table
otherwise, and the drawer moves only along its slide within its range."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from touch2robot import geometry

# Relaxed open hand and a full power-grasp posture (20 glove joints, see GLOVE_JOINT_NAMES).
Q_OPEN = np.array([0.0, 0.2, 0.1, 0.05] + [0.0, 0.1, 0.1, 0.05] * 4)
Q_CLOSE = np.array([0.25, 0.9, 0.9, 0.7] + [0.0, 1.5, 1.7, 1.1] * 4)
Q_FLAT = np.array([0.0, 0.25, 0.05, 0.0] + [0.0, 0.02, 0.0, 0.0] * 4)  # palm-press posture


def yaw(angle: float) -> np.ndarray:
    """The quaternion of a turn by ``angle`` (rad) about the vertical."""
    return geometry.quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), angle)


def offset(pos: np.ndarray, quat: np.ndarray, local: ArrayLike) -> np.ndarray:
    """The point at ``local`` in the frame of pose (``pos``, ``quat``), in the parent frame."""
    return pos + geometry.quat_to_mat(quat) @ np.asarray(local, float)


def skin_depths(rng: np.random.Generator) -> np.ndarray:
    """How deep (m) each of the five fingers presses its skin into the object when it closes."""
    return rng.uniform(0.004, 0.008, size=5)
