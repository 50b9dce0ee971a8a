"""Drawer: grasp the handle and pull the drawer open along its slide."""

from touch2robot.scenes.spec import GeomSpec, ObjectSpec, SlideSpec, TaskSpec

# Drawer body frame at the centre of its front panel; it slides along world -x (towards the hand).
FRONT = GeomSpec("box", (0.01, 0.09, 0.04), name="front")
HANDLE = GeomSpec(
    "capsule", (0.008, 0.045), pos=(-0.035, 0.0, 0.0), quat=(0.7071068, 0.7071068, 0.0, 0.0), name="handle"
)
HANDLE_POSTS = (
    GeomSpec("box", (0.0125, 0.005, 0.005), pos=(-0.0225, 0.04, 0.0), name="post_left"),
    GeomSpec("box", (0.0125, 0.005, 0.005), pos=(-0.0225, -0.04, 0.0), name="post_right"),
)
TRAY = GeomSpec("box", (0.08, 0.085, 0.005), pos=(0.09, 0.0, -0.035), name="tray")


def default_config() -> TaskSpec:
    return TaskSpec(
        name="drawer",
        object=ObjectSpec(
            name="drawer",
            geoms=(FRONT, HANDLE, *HANDLE_POSTS, TRAY),
            mass=0.4,
            friction=0.8,
            init_pos=(0.10, 0.0, 0.06),
            rgba=(0.55, 0.4, 0.25, 1.0),
        ),
        episode_s=8.0,
        slide=SlideSpec(
            axis=(-1.0, 0.0, 0.0),
            range=(0.0, 0.18),
            damping=2.0,
            cabinet=(
                GeomSpec("box", (0.1, 0.11, 0.005), pos=(0.20, 0.0, 0.105), name="cabinet_top"),
                GeomSpec("box", (0.1, 0.005, 0.05), pos=(0.20, 0.105, 0.05), name="cabinet_left"),
                GeomSpec("box", (0.1, 0.005, 0.05), pos=(0.20, -0.105, 0.05), name="cabinet_right"),
                GeomSpec("box", (0.005, 0.11, 0.05), pos=(0.30, 0.0, 0.05), name="cabinet_back"),
            ),
        ),
        # success: drawer opened at least this far along its slide
        success={"opening_m": 0.12},
    )
