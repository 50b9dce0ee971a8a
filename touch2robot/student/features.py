"""The student's per-step inputs and targets, shared by augmentation, training and inference.

Input of control step j (``INPUT_DIM`` = 39 floats), all from what a new glove demonstration
provides without any simulation:

- 0:16  the raw kinematic retargeting of reference frame j (LEAP joints, rad)
- 16:23 the kinematic robot wrist pose (position m, quaternion w >= 0)
- 23:30 the demonstrated object: position relative to the wrist (world axes, m), quaternion
- 30:38 the human's aligned tactile preference over the 8 robot regions (0 / 1)
- 38    1 when a preference is given, 0 when it is hidden (no glove, tactile dropout, or the
        no-tactile ablation): hidden preference and "no contact" then stay distinguishable

Targets of step j: the teacher's command aimed at frame j (16 absolute joint targets and the
wrist residual around the kinematic wrist, in ``WRIST_UNITS``) and the sim contacts it led to.
"""

from __future__ import annotations

import numpy as np

from touch2robot.geometry import quat_conj, quat_mul, rotvec
from touch2robot.teachers.reference import DemoReference

JOINTS = slice(0, 16)
TACTILE = slice(30, 39)  # preference and its availability flag
INPUT_DIM = 39
NUM_JOINTS = 16
WRIST_DIM = 6  # position residual (3) and axis-angle rotation residual in the wrist frame (3)
NUM_REGIONS = 8
OUTPUT_DIM = NUM_JOINTS + WRIST_DIM + NUM_REGIONS
# the wrist residual is learnt in cm and tenths of a radian: the scale of the joint errors in rad
WRIST_UNITS = np.array([0.01] * 3 + [0.1] * 3)


def _canonical(quat: np.ndarray) -> np.ndarray:
    return np.where(quat[:, :1] < 0, -quat, quat)


def step_inputs(
    joints: np.ndarray, wrist_pose: np.ndarray, object_pose: np.ndarray, preference: np.ndarray | None
) -> np.ndarray:
    """(T, INPUT_DIM) float32 inputs from (T, 16) joints, (T, 7) wrist and object poses and the
    (T, 8) preference (None: no glove, the preference channels are hidden)."""
    T = len(joints)
    tactile = np.zeros((T, 9))
    if preference is not None:
        tactile[:, :8] = preference
        tactile[:, 8] = 1.0
    return np.concatenate(
        [
            joints,
            wrist_pose[:, :3],
            _canonical(wrist_pose[:, 3:]),
            object_pose[:, :3] - wrist_pose[:, :3],
            _canonical(object_pose[:, 3:]),
            tactile,
        ],
        axis=1,
    ).astype(np.float32)


def reference_inputs(ref: DemoReference, tactile: bool = True) -> np.ndarray:
    """The inputs of every frame of a demonstration."""
    wrist = np.concatenate([ref.wrist_pos, ref.wrist_quat], axis=1)
    obj = np.concatenate([ref.object_pos, ref.object_quat], axis=1)
    return step_inputs(ref.joints, wrist, obj, ref.preference if tactile else None)


def wrist_residual(reference: np.ndarray, command: np.ndarray) -> np.ndarray:
    """(T, 6) residual (m, rad) taking the kinematic wrist poses (T, 7) to the commanded ones,
    parametrised like the teachers' wrist action (world shift, rotation in the wrist frame)."""
    rot = rotvec(quat_mul(quat_conj(reference[:, 3:]), command[:, 3:]))
    return np.concatenate([command[:, :3] - reference[:, :3], rot], axis=1)
