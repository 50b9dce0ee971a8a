"""Wipe: press a sponge on the table and drag it along a path."""

from __future__ import annotations

import numpy as np

from touch2robot.scenes.base import SuccessCriterion, Task
from touch2robot.scenes.spec import GeomSpec, ObjectSpec, TaskSpec
from touch2robot.synth.demos import Q_FLAT, offset, yaw
from touch2robot.synth.hand import HumanHand
from touch2robot.synth.motion import Trajectory, _Builder

SIZE = (0.05, 0.035, 0.015)


def default_config() -> TaskSpec:
    path = tuple((-0.08 + 0.04 * i, 0.03 * (-1) ** i) for i in range(5))
    return TaskSpec(
        name="wipe",
        object=ObjectSpec(
            name="sponge",
            geoms=(GeomSpec("box", SIZE),),
            mass=0.05,
            friction=0.9,
            init_pos=(path[0][0], path[0][1], SIZE[2]),
            rgba=(0.9, 0.8, 0.2, 1.0),
            # Foam that the palm presses into, stiffening over 20 mm of its 30 mm, on a scouring face that
            # slides on the table at mu 0.5. Rigid, at the max rule's mu 0.9 both sides, the LEAP's palm
            # slid over it: 4 of 8 kinematic replays passed their waypoints (issue 33).
            solref=(0.04, 1.0),
            solimp=(0.3, 0.95, 0.02),
            table_friction=0.5,
        ),
        episode_s=9.0,
        # without them the sponge crept under the palm at about half its speed (soft contacts' creep)
        noslip_iterations=3,
        wipe_path=path,
        # success: fraction of path waypoints passed within radius_m by the sponge centre
        success={"radius_m": 0.025, "coverage": 0.8},
    )


class WipeSuccess(SuccessCriterion):
    """The share of path waypoints the sponge centre has passed within ``radius_m`` (the progress)
    reaches ``coverage``."""

    def __init__(self, spec: TaskSpec, n: int) -> None:
        super().__init__(spec, n)
        self.visited = np.zeros((n, len(spec.wipe_path or ())), dtype=bool)

    def reset(self, ids: np.ndarray) -> None:
        self.visited[ids] = False

    def update(
        self, pos0: np.ndarray, quat0: np.ndarray, pos: np.ndarray, quat: np.ndarray, opening: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        s = self.spec.success
        way = np.asarray(self.spec.wipe_path)
        near = np.linalg.norm(pos[:, None, :2] - way[None], axis=2) <= s["radius_m"]
        self.visited |= near
        progress = self.visited.mean(axis=1)
        return progress >= s["coverage"], progress


def demonstrate(spec: TaskSpec, hand: HumanHand, rng: np.random.Generator, pace: float) -> Trajectory:
    """Press the sponge with the flat palm and drag it through the path's waypoints."""
    assert spec.wipe_path is not None
    shift = np.r_[rng.uniform(-0.01, 0.01, 2), 0.0]
    path = np.array([[x, y, spec.object.init_pos[2]] for x, y in spec.wipe_path]) + shift
    obj_quat = yaw(0.0)
    hand_quat = obj_quat
    top = spec.object.geoms[0].size[2] * 2
    # palm pads centred over the sponge, pressed in by a subject-dependent depth
    press = rng.uniform(0.003, 0.006)
    grasp = offset(path[0], hand_quat, [-0.05 * hand.scale, 0.0, top / 2 + 0.015 * hand.scale - press])
    b = _Builder(offset(grasp, hand_quat, [-0.03, 0.0, 0.10]), hand_quat, Q_FLAT, path[0], obj_quat)
    b.hold(0.3 * pace)
    b.phase(1.0 * pace, wrist_pos=grasp + [0.0, 0.0, 0.01])
    b.phase(0.4 * pace, wrist_pos=grasp)
    for p in path[1:]:
        b.carry(1.1 * pace, p, obj_quat)
    b.phase(0.4 * pace, wrist_pos=b.state[1] + [0.0, 0.0, 0.02])
    b.phase(0.8 * pace, wrist_pos=b.state[1] + [0.0, 0.0, 0.10])
    return b.build()


TASK = Task(
    name="wipe",
    position=2,
    instruction="wipe the table along the marked path",
    default_config=default_config,
    demonstrate=demonstrate,
    criterion=WipeSuccess,
)
