"""Pick: lift a box off the table and place it at a goal 12 cm away."""

from touch2robot.scenes.spec import GeomSpec, ObjectSpec, TaskSpec

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
