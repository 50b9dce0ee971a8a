"""Wipe: press a sponge on the table and drag it along a path."""

from touch2robot.scenes.spec import GeomSpec, ObjectSpec, TaskSpec

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
        ),
        episode_s=9.0,
        wipe_path=path,
        # success: fraction of path waypoints passed within radius_m by the sponge centre
        success={"radius_m": 0.025, "coverage": 0.8},
    )
