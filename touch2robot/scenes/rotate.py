"""Rotate: turn a cube about the vertical axis by 90 degrees with the fingers."""

import math

from touch2robot.scenes.spec import GeomSpec, ObjectSpec, TaskSpec

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
