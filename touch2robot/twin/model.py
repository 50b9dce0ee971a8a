"""The twin's physics: a perturbed copy of a task's nominal MuJoCo scene, drawn per replay.

Perturbed, as public LEAP Hand sim-to-real setups randomise them (ranges and sources in
``touch2robot.twin.config``): sliding friction of the hand's and of the object's geoms, the object's
mass (inertia scaled with it) and centre of mass, damping and armature of the 16 hand joints, the servos'
position gain and torque limit, plus a command latency and joint-encoder noise that the replay applies.
The nominal scene's model is never changed.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import mujoco
import numpy as np

from touch2robot.leap import description as hd
from touch2robot.leap.mjcf import WRIST_BODY
from touch2robot.sim.scene import OBJECT_BODY, Scene
from touch2robot.twin.config import TwinConfig


def _move_centre_of_mass(model: mujoco.MjModel, body: int, offset: np.ndarray) -> None:
    """Shift a body's centre of mass in its frame. The compiler marked the body's inertial frame as its own
    frame (and its dofs as "simple"); MuJoCo would ignore the shift, so those shortcuts are cleared here and
    ``mj_setConst`` derives them again for the new frame."""
    model.body_ipos[body] += offset
    model.body_sameframe[body] = 0
    model.body_simple[body] = 0
    first, count = model.body_dofadr[body], model.body_dofnum[body]
    model.dof_simplenum[first : first + count] = 0
    # a run of simple dofs counted from an earlier dof stops before this body's
    earlier = np.arange(first)
    model.dof_simplenum[:first] = np.minimum(model.dof_simplenum[:first], first - earlier)


@dataclass(frozen=True)
class TwinModel:
    """One replay's rig: its MuJoCo model, command latency and encoder noise, and every value drawn."""

    model: mujoco.MjModel
    latency_steps: int  # physics steps between a command's send time and its effect
    encoder_noise_rad: float  # std of the noise on recorded joint positions
    perturbation: dict[str, float]


def perturb(
    scene: Scene, twin: TwinConfig, timestep: float, rng: np.random.Generator, scratch: mujoco.MjData
) -> TwinModel:
    """Draw one rig from ``twin``'s ranges (in a fixed order, so a seed gives the same rig) and apply it
    to a copy of ``scene.model``; ``scratch`` is any data of the scene (its contents are overwritten)."""
    model = copy.copy(scene.model)
    drawn: dict[str, float] = {}

    def draw(name: str, bounds: tuple[float, float]) -> float:
        drawn[name] = float(rng.uniform(bounds[0], bounds[1]))
        return drawn[name]

    def per_joint(name: str, bounds: tuple[float, float]) -> np.ndarray:
        values = rng.uniform(bounds[0], bounds[1], len(hd.JOINT_NAMES))
        drawn.update({f"{name}.{joint}": float(v) for joint, v in zip(hd.JOINT_NAMES, values, strict=True)})
        return values

    hand_root = model.body(WRIST_BODY).id
    object_body = model.body(OBJECT_BODY).id
    geom_body = model.geom_bodyid
    hand_geoms = model.body_rootid[geom_body] == hand_root
    object_geoms = geom_body == object_body
    model.geom_friction[hand_geoms, 0] *= draw("hand_friction_scale", twin.friction_scale)
    object_friction = draw("object_friction_scale", twin.friction_scale)
    model.geom_friction[object_geoms, 0] *= object_friction
    if scene.spec.object.table_friction is not None:  # the object's own friction on the table: the table's geom
        model.geom_friction[model.geom("table").id, 0] *= object_friction

    mass_scale = draw("object_mass_scale", twin.object_mass_scale)
    model.body_mass[object_body] *= mass_scale
    model.body_inertia[object_body] *= mass_scale
    com_offset = rng.uniform(-twin.object_com_offset_m, twin.object_com_offset_m, 3)
    drawn.update({f"object_com_offset_{axis}_m": float(v) for axis, v in zip("xyz", com_offset, strict=True)})
    if com_offset.any():
        _move_centre_of_mass(model, object_body, com_offset)

    dof = scene.hand_dof
    model.dof_damping[dof] *= per_joint("joint_damping_scale", twin.joint_damping_scale)
    model.dof_armature[dof] *= per_joint("armature_scale", twin.armature_scale)
    actuators = np.array([model.actuator(name).id for name in hd.JOINT_NAMES])
    kp = per_joint("kp_scale", twin.kp_scale)
    # a position servo is gain kp, bias (0, -kp, -kd): its whole PD loop scales together
    model.actuator_gainprm[actuators, 0] *= kp
    model.actuator_biasprm[actuators, 1:3] *= kp[:, None]
    model.actuator_forcerange[actuators] *= per_joint("force_limit_scale", twin.force_limit_scale)[:, None]

    latency_steps = round(draw("latency_s", twin.latency_s) / timestep)
    drawn["latency_s"] = latency_steps * timestep  # as applied
    encoder_noise = draw("encoder_noise_rad", twin.encoder_noise_rad)
    # masses and inertias enter constants MuJoCo derives at compile time (the solver's inverse weights)
    mujoco.mj_setConst(model, scratch)
    return TwinModel(model, latency_steps, encoder_noise, drawn)
