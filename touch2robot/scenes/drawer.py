"""Drawer: grasp the handle and pull the drawer open along its slide."""

from __future__ import annotations

import numpy as np

from touch2robot.scenes.base import SuccessCriterion, Task
from touch2robot.scenes.spec import GeomSpec, ObjectSpec, SlideSpec, TaskSpec
from touch2robot.synth.demos import Q_CLOSE, Q_OPEN, offset, skin_depths
from touch2robot.synth.hand import HumanHand
from touch2robot.synth.motion import Scene, Trajectory, _Builder, close_fingers

# Drawer body frame at the centre of its front panel; it slides along world -x (towards the hand).
FRONT = GeomSpec("box", (0.01, 0.09, 0.04), name="front")
# A bar pull of the common 128 mm hole spacing standing 40 mm proud of the panel (32 mm clear behind the
# bar): LEAP fingers are about 20 mm thick and span 75 mm; behind a 25 mm stand-off between posts 80 mm
# apart, their kinematic replays jammed against the panel and hooked the posts instead of the bar.
HANDLE = GeomSpec("capsule", (0.008, 0.07), pos=(-0.05, 0.0, 0.0), quat=(0.7071068, 0.7071068, 0.0, 0.0), name="handle")
HANDLE_POSTS = (
    GeomSpec("box", (0.02, 0.005, 0.005), pos=(-0.03, 0.064, 0.0), name="post_left"),
    GeomSpec("box", (0.02, 0.005, 0.005), pos=(-0.03, -0.064, 0.0), name="post_right"),
)
# The cabinet stands on a 60 mm plinth: hooked round a handle 60 mm above the table, the LEAP's fingers
# (15 % longer than the human's they follow) drove their tips into the table top in every replay.
PLINTH = 0.06
WALL_HALF = 0.05 + PLINTH / 2  # half height of the cabinet's sides and back, standing on the table
MASS = 0.4
RAIL_FRICTION = 0.25  # the tray sliding on its rails
TRAY = GeomSpec("box", (0.08, 0.085, 0.005), pos=(0.09, 0.0, -0.035), name="tray")


def default_config() -> TaskSpec:
    return TaskSpec(
        name="drawer",
        object=ObjectSpec(
            name="drawer",
            geoms=(FRONT, HANDLE, *HANDLE_POSTS, TRAY),
            mass=MASS,
            friction=0.8,
            init_pos=(0.10, 0.0, 0.06 + PLINTH),
            rgba=(0.55, 0.4, 0.25, 1.0),
        ),
        episode_s=8.0,
        slide=SlideSpec(
            axis=(-1.0, 0.0, 0.0),
            range=(0.0, 0.18),
            damping=2.0,
            # Coulomb friction of the rails (mu m g): without it, the fingers opening to let go pushed a
            # released drawer back 2-3 cm in the kinematic replays
            frictionloss=RAIL_FRICTION * MASS * 9.81,
            cabinet=(
                GeomSpec("box", (0.1, 0.11, 0.005), pos=(0.20, 0.0, 0.105 + PLINTH), name="cabinet_top"),
                GeomSpec("box", (0.1, 0.005, WALL_HALF), pos=(0.20, 0.105, WALL_HALF), name="cabinet_left"),
                GeomSpec("box", (0.1, 0.005, WALL_HALF), pos=(0.20, -0.105, WALL_HALF), name="cabinet_right"),
                GeomSpec("box", (0.005, 0.11, WALL_HALF), pos=(0.30, 0.0, WALL_HALF), name="cabinet_back"),
            ),
        ),
        # success: drawer opened at least this far along its slide
        success={"opening_m": 0.12},
    )


class DrawerSuccess(SuccessCriterion):
    """The opening along the slide reaches ``opening_m``; progress is the opening's share of it."""

    def update(
        self, pos0: np.ndarray, quat0: np.ndarray, pos: np.ndarray, quat: np.ndarray, opening: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        target = self.spec.success["opening_m"]
        return opening >= target, np.clip(opening / target, 0.0, 1.0)


def demonstrate(spec: TaskSpec, hand: HumanHand, rng: np.random.Generator, pace: float) -> Trajectory:
    """Reach the handle palm-forward, hook the fingers round it and pull along the slide."""
    assert spec.slide is not None
    scene = Scene.from_task(spec)
    obj_pos = np.asarray(spec.object.init_pos, float)
    obj_quat = np.array([1.0, 0.0, 0.0, 0.0])
    # hand frame: fingers pointing down in front of the handle, palm facing +x (the drawer):
    # a half-turn about (1, 0, -1)/sqrt(2) maps hand x -> world -z and hand -z -> world +x
    hand_quat = np.array([0.0, np.sqrt(0.5), 0.0, -np.sqrt(0.5)])
    handle = offset(obj_pos, obj_quat, spec.object.geoms[1].pos)
    grasp = handle + np.array([-0.026, 0.0, 0.13 * hand.scale])
    b = _Builder(grasp + [-0.10, 0.0, 0.03], hand_quat, Q_OPEN, obj_pos, obj_quat)
    b.hold(0.3 * pace)
    b.phase(1.2 * pace, wrist_pos=grasp)
    q = close_fingers(
        hand, scene, grasp, hand_quat, obj_pos, obj_quat, Q_OPEN, Q_CLOSE, skin_depths(rng), fingers=(1, 2, 3, 4, 0)
    )
    b.phase(0.6 * pace, joints=q)
    opening = rng.uniform(0.13, min(0.17, spec.slide.range[1]))
    b.carry(2.0 * pace, obj_pos + opening * np.asarray(spec.slide.axis), obj_quat)
    b.hold(0.3 * pace)
    b.phase(0.6 * pace, joints=Q_OPEN)
    b.phase(1.0 * pace, wrist_pos=b.state[1] + [-0.08, 0.0, 0.0])
    return b.build()


TASK = Task(
    name="drawer",
    position=3,
    instruction="pull the drawer open",
    default_config=default_config,
    demonstrate=demonstrate,
    criterion=DrawerSuccess,
)
