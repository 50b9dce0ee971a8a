"""The four scripted tasks. Each script takes the task spec (shared with the MuJoCo
scenes), a subject's hand and a random generator, and returns a Trajectory whose object
motion stays feasible in the scene: objects move only while grasped, rest on the table
otherwise, and the drawer moves only along its slide within its range."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from touch2robot import geometry
from touch2robot.scenes import TaskSpec
from touch2robot.synth.hand import HumanHand
from touch2robot.synth.motion import Scene, Trajectory, _Builder, close_fingers

# Relaxed open hand and a full power-grasp posture (20 glove joints, see GLOVE_JOINT_NAMES).
Q_OPEN = np.array([0.0, 0.2, 0.1, 0.05] + [0.0, 0.1, 0.1, 0.05] * 4)
Q_CLOSE = np.array([0.25, 0.9, 0.9, 0.7] + [0.0, 1.5, 1.7, 1.1] * 4)
Q_FLAT = np.array([0.0, 0.25, 0.05, 0.0] + [0.0, 0.02, 0.0, 0.0] * 4)  # palm-press posture


def _yaw(a: float) -> np.ndarray:
    return geometry.quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), a)


def _offset(pos: np.ndarray, quat: np.ndarray, local: np.ndarray) -> np.ndarray:
    return pos + geometry.quat_to_mat(quat) @ np.asarray(local, float)


def _depths(rng: np.random.Generator) -> np.ndarray:
    return rng.uniform(0.004, 0.008, size=5)


def pick(spec: TaskSpec, hand: HumanHand, rng: np.random.Generator, pace: float) -> Trajectory:
    scene = Scene.from_task(spec)
    obj_pos = np.asarray(spec.object.init_pos) + np.r_[rng.uniform(-0.015, 0.015, 2), 0.0]
    obj_quat = _yaw(rng.uniform(-0.25, 0.25))
    hand_quat = obj_quat
    half = spec.object.geoms[0].size
    grasp = _offset(obj_pos, hand_quat, [-0.058 * hand.scale, 0.0, half[2] + 0.02])
    b = _Builder(_offset(grasp, hand_quat, [-0.05, 0.0, 0.10]), hand_quat, Q_OPEN, obj_pos, obj_quat)
    b.hold(0.3 * pace)
    b.phase(1.2 * pace, wrist_pos=grasp)
    q = close_fingers(hand, scene, grasp, hand_quat, obj_pos, obj_quat, Q_OPEN, Q_CLOSE, _depths(rng))
    b.phase(0.6 * pace, joints=q)
    b.hold(0.2 * pace)
    lift = obj_pos + [0.0, 0.0, 0.10]
    goal = np.asarray(spec.goal_pos) + np.r_[rng.uniform(-0.01, 0.01, 2), 0.0]
    b.carry(1.0 * pace, lift, obj_quat)
    b.carry(1.4 * pace, goal + [0.0, 0.0, 0.10], obj_quat)
    b.carry(1.0 * pace, goal, obj_quat)
    b.hold(0.2 * pace)
    b.phase(0.6 * pace, joints=Q_OPEN)
    wrist = b.state[1]
    b.phase(1.0 * pace, wrist_pos=wrist + [0.0, 0.0, 0.10])
    return b.build()


def rotate(spec: TaskSpec, hand: HumanHand, rng: np.random.Generator, pace: float) -> Trajectory:
    """Turn the cube about the vertical in three re-grasps of 30 degrees each."""
    scene = Scene.from_task(spec)
    obj_pos = np.asarray(spec.object.init_pos) + np.r_[rng.uniform(-0.015, 0.015, 2), 0.0]
    yaw0 = rng.uniform(-0.2, 0.2)
    half = spec.object.geoms[0].size
    step = spec.rotation_angle / 3
    b = None
    for k in range(3):
        obj_quat = _yaw(yaw0 + k * step)
        hand_quat = obj_quat
        grasp = _offset(obj_pos, hand_quat, [-0.058 * hand.scale, 0.0, half[2] + 0.02])
        if b is None:
            b = _Builder(_offset(grasp, hand_quat, [-0.04, 0.0, 0.08]), hand_quat, Q_OPEN, obj_pos, obj_quat)
            b.hold(0.3 * pace)
            b.phase(1.0 * pace, wrist_pos=grasp)
        else:
            b.phase(0.5 * pace, wrist_pos=_offset(grasp, hand_quat, [0.0, 0.0, 0.02]), wrist_quat=hand_quat)
            b.phase(0.3 * pace, wrist_pos=grasp)
        q = close_fingers(
            hand, scene, grasp, hand_quat, obj_pos, obj_quat, Q_OPEN, Q_CLOSE, _depths(rng), fingers=(0, 1, 2, 3)
        )
        b.phase(0.5 * pace, joints=q)
        b.carry(1.0 * pace, obj_pos, _yaw(yaw0 + (k + 1) * step))
        b.phase(0.4 * pace, joints=Q_OPEN)
    b.phase(0.8 * pace, wrist_pos=b.state[1] + [0.0, 0.0, 0.08])
    return b.build()


def wipe(spec: TaskSpec, hand: HumanHand, rng: np.random.Generator, pace: float) -> Trajectory:
    """Press the sponge with the flat palm and drag it through the path's waypoints."""
    shift = np.r_[rng.uniform(-0.01, 0.01, 2), 0.0]
    path = np.array([[x, y, spec.object.init_pos[2]] for x, y in spec.wipe_path]) + shift
    obj_quat = _yaw(0.0)
    hand_quat = obj_quat
    top = spec.object.geoms[0].size[2] * 2
    # palm pads centred over the sponge, pressed in by a subject-dependent depth
    press = rng.uniform(0.003, 0.006)
    grasp = _offset(path[0], hand_quat, [-0.05 * hand.scale, 0.0, top / 2 + 0.015 * hand.scale - press])
    b = _Builder(_offset(grasp, hand_quat, [-0.03, 0.0, 0.10]), hand_quat, Q_FLAT, path[0], obj_quat)
    b.hold(0.3 * pace)
    b.phase(1.0 * pace, wrist_pos=grasp + [0.0, 0.0, 0.01])
    b.phase(0.4 * pace, wrist_pos=grasp)
    for p in path[1:]:
        b.carry(1.1 * pace, p, obj_quat)
    b.phase(0.4 * pace, wrist_pos=b.state[1] + [0.0, 0.0, 0.02])
    b.phase(0.8 * pace, wrist_pos=b.state[1] + [0.0, 0.0, 0.10])
    return b.build()


def drawer(spec: TaskSpec, hand: HumanHand, rng: np.random.Generator, pace: float) -> Trajectory:
    """Reach the handle palm-forward, hook the fingers round it and pull along the slide."""
    scene = Scene.from_task(spec)
    obj_pos = np.asarray(spec.object.init_pos, float)
    obj_quat = np.array([1.0, 0.0, 0.0, 0.0])
    # hand frame: fingers pointing down in front of the handle, palm facing +x (the drawer):
    # a half-turn about (1, 0, -1)/sqrt(2) maps hand x -> world -z and hand -z -> world +x
    hand_quat = np.array([0.0, np.sqrt(0.5), 0.0, -np.sqrt(0.5)])
    handle = _offset(obj_pos, obj_quat, spec.object.geoms[1].pos)
    grasp = handle + np.array([-0.026, 0.0, 0.13 * hand.scale])
    b = _Builder(grasp + [-0.10, 0.0, 0.03], hand_quat, Q_OPEN, obj_pos, obj_quat)
    b.hold(0.3 * pace)
    b.phase(1.2 * pace, wrist_pos=grasp)
    q = close_fingers(
        hand, scene, grasp, hand_quat, obj_pos, obj_quat, Q_OPEN, Q_CLOSE, _depths(rng), fingers=(1, 2, 3, 4, 0)
    )
    b.phase(0.6 * pace, joints=q)
    opening = rng.uniform(0.13, min(0.17, spec.slide.range[1]))
    b.carry(2.0 * pace, obj_pos + opening * np.asarray(spec.slide.axis), obj_quat)
    b.hold(0.3 * pace)
    b.phase(0.6 * pace, joints=Q_OPEN)
    b.phase(1.0 * pace, wrist_pos=b.state[1] + [-0.08, 0.0, 0.0])
    return b.build()


SCRIPTS: dict[str, Callable[[TaskSpec, HumanHand, np.random.Generator, float], Trajectory]] = {
    "pick": pick,
    "rotate": rotate,
    "wipe": wipe,
    "drawer": drawer,
}
