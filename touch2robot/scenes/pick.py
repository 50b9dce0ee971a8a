"""Pick: lift a box off the table and place it at a goal 12 cm away."""

from __future__ import annotations

import numpy as np

from touch2robot.scenes.base import SuccessCriterion, Task
from touch2robot.scenes.spec import GeomSpec, ObjectSpec, TaskSpec
from touch2robot.synth.demos import Q_CLOSE, Q_OPEN, offset, skin_depths, yaw
from touch2robot.synth.hand import HumanHand
from touch2robot.synth.motion import Scene, Trajectory, _Builder, close_fingers

HALF = 0.03


def default_config() -> TaskSpec:
    return TaskSpec(
        name="pick",
        object=ObjectSpec(
            name="box",
            geoms=(GeomSpec("box", (HALF, HALF, HALF)),),
            mass=0.10,
            friction=1.0,
            init_pos=(0.0, 0.0, HALF),
        ),
        episode_s=8.0,
        goal_pos=(0.10, 0.06, HALF),
        # success: final object position within this distance of the goal, lifted at least lift_m on the way
        success={"pos_tol_m": 0.03, "lift_m": 0.05},
    )


class PickSuccess(SuccessCriterion):
    """Within ``pos_tol_m`` of the goal after a lift of at least ``lift_m``; progress is the share of
    the start's distance to the goal covered."""

    def __init__(self, spec: TaskSpec, n: int) -> None:
        super().__init__(spec, n)
        self.max_lift = np.zeros(n)

    def reset(self, ids: np.ndarray) -> None:
        self.max_lift[ids] = 0.0

    def update(
        self, pos0: np.ndarray, quat0: np.ndarray, pos: np.ndarray, quat: np.ndarray, opening: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        s = self.spec.success
        self.max_lift = np.maximum(self.max_lift, pos[:, 2] - pos0[:, 2])
        dist = np.linalg.norm(pos - np.asarray(self.spec.goal_pos), axis=1)
        start = np.linalg.norm(pos0 - np.asarray(self.spec.goal_pos), axis=1)
        progress = np.clip(1.0 - dist / np.maximum(start, 1e-9), 0.0, 1.0)
        return (dist <= s["pos_tol_m"]) & (self.max_lift >= s["lift_m"]), progress


def demonstrate(spec: TaskSpec, hand: HumanHand, rng: np.random.Generator, pace: float) -> Trajectory:
    """Grasp the box from above, lift it, carry it over the goal, set it down and let go."""
    scene = Scene.from_task(spec)
    obj_pos = np.asarray(spec.object.init_pos) + np.r_[rng.uniform(-0.015, 0.015, 2), 0.0]
    obj_quat = yaw(rng.uniform(-0.25, 0.25))
    hand_quat = obj_quat
    half = spec.object.geoms[0].size
    grasp = offset(obj_pos, hand_quat, [-0.058 * hand.scale, 0.0, half[2] + 0.02])
    b = _Builder(offset(grasp, hand_quat, [-0.05, 0.0, 0.10]), hand_quat, Q_OPEN, obj_pos, obj_quat)
    b.hold(0.3 * pace)
    b.phase(1.2 * pace, wrist_pos=grasp)
    q = close_fingers(hand, scene, grasp, hand_quat, obj_pos, obj_quat, Q_OPEN, Q_CLOSE, skin_depths(rng))
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


TASK = Task(
    name="pick",
    position=0,
    instruction="pick up the box and place it at the goal",
    default_config=default_config,
    demonstrate=demonstrate,
    criterion=PickSuccess,
)
