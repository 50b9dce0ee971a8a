"""Rotate: turn a cube about the vertical axis by 90 degrees with the fingers."""

from __future__ import annotations

import math

import numpy as np

from touch2robot.geometry import twist_angle, wrap_angle
from touch2robot.scenes.base import SuccessCriterion, Task
from touch2robot.scenes.spec import GeomSpec, ObjectSpec, TaskSpec
from touch2robot.synth.demos import Q_CLOSE, Q_OPEN, offset, skin_depths, yaw
from touch2robot.synth.hand import HumanHand
from touch2robot.synth.motion import Scene, Trajectory, _Builder, close_fingers

HALF = 0.03


def default_config() -> TaskSpec:
    return TaskSpec(
        name="rotate",
        object=ObjectSpec(
            name="cube",
            geoms=(GeomSpec("box", (HALF, HALF, HALF)),),
            mass=0.08,
            friction=0.8,
            init_pos=(0.0, 0.0, HALF),
            rgba=(0.2, 0.5, 0.8, 1.0),
        ),
        episode_s=9.0,
        rotation_axis=(0.0, 0.0, 1.0),
        rotation_angle=math.pi / 2,
        # success: rotation about the axis within angle_tol of the target, centre kept within pos_tol
        success={"angle_tol_rad": math.radians(20.0), "pos_tol_m": 0.05},
    )


class RotateSuccess(SuccessCriterion):
    """Rotation about the spec's axis within ``angle_tol_rad`` of the target angle (tilt about other
    axes ignored), centre kept within ``pos_tol_m`` of its start; progress is the closed share of the
    angle error."""

    def update(
        self, pos0: np.ndarray, quat0: np.ndarray, pos: np.ndarray, quat: np.ndarray, opening: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        s = self.spec.success
        assert self.spec.rotation_axis is not None and self.spec.rotation_angle is not None
        angle = twist_angle(quat, quat0, np.asarray(self.spec.rotation_axis))
        error = np.abs(wrap_angle(angle - self.spec.rotation_angle))
        progress = np.clip(1.0 - error / abs(self.spec.rotation_angle), 0.0, 1.0)
        drift = np.linalg.norm(pos - pos0, axis=1)
        return (error <= s["angle_tol_rad"]) & (drift <= s["pos_tol_m"]), progress


def demonstrate(spec: TaskSpec, hand: HumanHand, rng: np.random.Generator, pace: float) -> Trajectory:
    """Turn the cube about the vertical in three re-grasps of 30 degrees each."""
    assert spec.rotation_angle is not None
    scene = Scene.from_task(spec)
    obj_pos = np.asarray(spec.object.init_pos) + np.r_[rng.uniform(-0.015, 0.015, 2), 0.0]
    yaw0 = rng.uniform(-0.2, 0.2)
    half = spec.object.geoms[0].size
    step = spec.rotation_angle / 3
    b = None
    for k in range(3):
        obj_quat = yaw(yaw0 + k * step)
        hand_quat = obj_quat
        grasp = offset(obj_pos, hand_quat, [-0.058 * hand.scale, 0.0, half[2] + 0.02])
        if b is None:
            b = _Builder(offset(grasp, hand_quat, [-0.04, 0.0, 0.08]), hand_quat, Q_OPEN, obj_pos, obj_quat)
            b.hold(0.3 * pace)
            b.phase(1.0 * pace, wrist_pos=grasp)
        else:
            b.phase(0.5 * pace, wrist_pos=offset(grasp, hand_quat, [0.0, 0.0, 0.02]), wrist_quat=hand_quat)
            b.phase(0.3 * pace, wrist_pos=grasp)
        q = close_fingers(
            hand, scene, grasp, hand_quat, obj_pos, obj_quat, Q_OPEN, Q_CLOSE, skin_depths(rng), fingers=(0, 1, 2, 3)
        )
        b.phase(0.5 * pace, joints=q)
        b.carry(1.0 * pace, obj_pos, yaw(yaw0 + (k + 1) * step))
        b.phase(0.4 * pace, joints=Q_OPEN)
    assert b is not None  # made in the loop's first round
    b.phase(0.8 * pace, wrist_pos=b.state[1] + [0.0, 0.0, 0.08])
    return b.build()


TASK = Task(
    name="rotate",
    position=1,
    instruction="rotate the object about the vertical axis",
    default_config=default_config,
    demonstrate=demonstrate,
    criterion=RotateSuccess,
)
