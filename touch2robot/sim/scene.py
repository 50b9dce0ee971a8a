"""MuJoCo scenes of the four tasks, built from the task specs in ``touch2robot.scenes``.

Each scene: a table (top at z = 0), the task object (free body, or the drawer on its slide inside
a fixed cabinet), the LEAP Hand with its mocap-welded wrist, two RGB cameras, goal markers, and
the index bookkeeping the batched environment needs to read the flat MuJoCo state.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import mujoco
import numpy as np

from touch2robot import scenes
from touch2robot.geometry import quat_mul, quat_to_mat, sample_surface
from touch2robot.leap import description as hd
from touch2robot.leap.mjcf import REGION_SENSOR_PREFIX, WRIST_BODY, WRIST_TARGET, add_hand, mjcf_root, section, sub
from touch2robot.scenes.spec import GeomSpec, TaskSpec
from touch2robot.sim.config import SimConfig

TABLE_HALF_THICKNESS = 0.02
TABLE_FRICTION = 0.6
OBJECT_SOLMIX = 100.0  # a compliant object's weight in the solref/solimp mix of its contacts (the other's is 1)
CAMERAS = ("cam_left", "cam_right")
OBJECT_BODY = "object"
# where the grasp happens relative to the palm (palm frame): in front of the finger bases, under the
# palm centre line, where the home-pose fingertips and thumb meet (description's FK)
GRASP_POINT_IN_PALM = (-0.02, -0.035, -0.09)
# palm facing down, fingers along world +x: wrist +x (palmar normal) = world -z, wrist +z = world +x
PALM_DOWN = np.array([math.sqrt(0.5), 0.0, math.sqrt(0.5), 0.0])
HOME_JOINTS = {
    "mcp": 0.3,
    "rot": 0.0,
    "pip": 0.3,
    "dip": 0.3,
    "th_cmc": 0.6,
    "th_axl": 0.6,
    "th_mcp": 0.3,
    "th_ipl": 0.0,
}


@dataclass(frozen=True)
class Scene:
    """A compiled task scene and the addresses of everything the environment reads or writes."""

    spec: TaskSpec
    xml: str
    model: mujoco.MjModel
    hand_qpos: np.ndarray  # (16,) qpos addresses of the hand joints, reference order
    hand_dof: np.ndarray  # (16,) dof addresses of the hand joints
    wrist_qpos: int  # first qpos address of the wrist free joint (pos 3 + quat 4)
    object_qpos: int  # first qpos address of the object's free joint, or of the drawer slide
    region_sensors: np.ndarray  # (8,) sensordata addresses of the touch sensors T1..T4, P1..P4
    tip_sensors: np.ndarray  # (4, 3) sensordata addresses of th/if/mf/rf fingertip positions
    region_pos_sensors: np.ndarray  # (8, 3) sensordata addresses of the regions' centre positions
    object_dof: int  # first dof address of the object's free joint (6 dofs) or of the drawer slide (1)
    object_mass: float  # kg
    object_inertia: float  # mean principal moment of inertia, kg m^2
    home_qpos: np.ndarray  # (nq,) initial configuration
    home_wrist_pos: np.ndarray  # (3,) world
    home_wrist_quat: np.ndarray  # (4,) world
    point_cloud: np.ndarray  # (P, 3) object surface points in the object's body frame

    @property
    def is_drawer(self) -> bool:
        """Whether the object is the slide-jointed drawer (one qpos) instead of a free body (seven)."""
        return self.spec.slide is not None


def _geom_volume(g: GeomSpec) -> float:
    s = g.size
    if g.shape == "box":
        return 8.0 * s[0] * s[1] * s[2]
    if g.shape == "sphere":
        return 4.0 / 3.0 * math.pi * s[0] ** 3
    if g.shape == "capsule":
        return math.pi * s[0] ** 2 * 2.0 * s[1] + 4.0 / 3.0 * math.pi * s[0] ** 3
    if g.shape == "cylinder":
        return math.pi * s[0] ** 2 * 2.0 * s[1]
    raise ValueError(f"unsupported primitive shape {g.shape!r}")


def _add_geoms(body: ET.Element, geoms: tuple[GeomSpec, ...], prefix: str, **attrs: object) -> None:
    for i, g in enumerate(geoms):
        sub(body, "geom", name=f"{prefix}_{g.name or i}", type=g.shape, size=g.size, pos=g.pos, quat=g.quat, **attrs)


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """MJCF camera ``xyaxes`` for a camera at ``eye`` looking at ``target`` with world z up."""
    fwd = target - eye
    fwd = fwd / np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    return np.concatenate([right, up])


def grasp_target(spec: TaskSpec) -> np.ndarray:
    """The world point the hand is placed over at reset: the object centre, or the drawer handle."""
    pos = np.asarray(spec.object.init_pos, dtype=np.float64)
    if spec.slide is not None:
        handle = next(g for g in spec.object.geoms if g.name == "handle")
        pos = pos + np.asarray(handle.pos)
    return pos


def home_wrist(spec: TaskSpec) -> tuple[np.ndarray, np.ndarray]:
    """Reset pose of the wrist: palm down with the grasp point above the object (or the handle).

    For the drawer the fingers point toward -x, away from the cabinet, and the hand hovers higher
    so that the curled thumb clears the cabinet top.
    """
    quat = PALM_DOWN if spec.slide is None else quat_mul(np.array([0.0, 0.0, 0.0, 1.0]), PALM_DOWN)
    palm_rot = quat_to_mat(np.asarray(hd.PALM_IN_WRIST_QUAT))
    grasp_in_wrist = np.asarray(hd.PALM_IN_WRIST_POS) + palm_rot @ np.asarray(GRASP_POINT_IN_PALM)
    above = grasp_target(spec) + np.array([0.0, 0.0, 0.06 if spec.slide is None else 0.10])
    return above - quat_to_mat(quat) @ grasp_in_wrist, quat


def home_joint_targets() -> np.ndarray:
    """(16,) joint angles of the reset pose: a relaxed, slightly curled hand."""
    return np.array([HOME_JOINTS[n[3:]] if n.startswith(hd.FINGERS) else HOME_JOINTS[n] for n in hd.JOINT_NAMES])


def scene_xml(spec: TaskSpec, cfg: SimConfig) -> str:
    """The MJCF document of a task scene."""
    root = mjcf_root(f"touch2robot_{spec.name}", cfg.timestep)
    option = root.find("option")
    assert option is not None
    option.set("iterations", str(cfg.solver_iterations))
    option.set("ls_iterations", str(cfg.ls_iterations))
    if spec.noslip_iterations:
        option.set("noslip_iterations", str(spec.noslip_iterations))
    sub(sub(root, "visual"), "global", offwidth="640", offheight="480")
    sub(root, "statistic", center="0 0 0.05", extent="0.4")
    asset = section(root, "asset")
    sub(
        asset,
        "texture",
        name="grid",
        type="2d",
        builtin="checker",
        rgb1="0.82 0.78 0.72",
        rgb2="0.74 0.7 0.64",
        width="256",
        height="256",
    )
    sub(asset, "material", name="table", texture="grid", texrepeat="8 8")
    sub(
        asset,
        "texture",
        name="sky",
        type="skybox",
        builtin="gradient",
        rgb1="0.6 0.7 0.8",
        rgb2="0.15 0.2 0.25",
        width="64",
        height="64",
    )
    world = section(root, "worldbody")
    sub(world, "light", name="key", pos="0.3 -0.3 1.2", dir="-0.25 0.25 -1", diffuse="0.8 0.8 0.8", castshadow="false")
    sub(
        world, "light", name="fill", pos="-0.4 0.4 1.0", dir="0.3 -0.3 -1", diffuse="0.35 0.35 0.35", castshadow="false"
    )
    hx, hy = spec.table_half_extent
    obj = spec.object
    # an object with its own friction on the table: the table's geom wins their contact (MuJoCo's priority)
    own_friction = obj.table_friction is not None
    sub(
        world,
        "geom",
        name="table",
        type="box",
        size=(hx, hy, TABLE_HALF_THICKNESS),
        pos=(0, 0, -TABLE_HALF_THICKNESS),
        material="table",
        friction=(obj.table_friction if own_friction else TABLE_FRICTION, 0.005, 0.0001),
        **({"priority": "1"} if own_friction else {}),
    )

    body = sub(world, "body", name=OBJECT_BODY, pos=obj.init_pos, quat=obj.init_quat)
    if spec.slide is None:
        sub(body, "freejoint", name="object_free")
    else:
        sl = spec.slide
        sub(
            body,
            "joint",
            name="drawer_slide",
            type="slide",
            axis=sl.axis,
            range=sl.range,
            damping=sl.damping,
            frictionloss=sl.frictionloss,
        )
    # split the mass over the primitives by volume so that MuJoCo composes a consistent inertia
    volumes = np.array([_geom_volume(g) for g in obj.geoms])
    # a compliant object's softness outweighs the hand's defaults in MuJoCo's mix of the two
    compliance: dict[str, object] = {k: v for k, v in (("solref", obj.solref), ("solimp", obj.solimp)) if v is not None}
    if compliance:
        compliance["solmix"] = OBJECT_SOLMIX
    for g, m in zip(obj.geoms, obj.mass * volumes / volumes.sum(), strict=True):
        sub(
            body,
            "geom",
            name=f"object_{g.name or 'geom'}",
            type=g.shape,
            size=g.size,
            pos=g.pos,
            quat=g.quat,
            mass=m,
            rgba=obj.rgba,
            friction=(obj.friction, 0.005, 0.0001),
            condim="4",
            **compliance,
        )
    if spec.slide is not None:
        cabinet = sub(world, "body", name="cabinet")
        _add_geoms(cabinet, spec.slide.cabinet, "cabinet", rgba=(0.8, 0.78, 0.74, 1.0))
        # the slide joint is the drawer's guide: rails are not modelled as contacts
        sub(section(root, "contact"), "exclude", body1="cabinet", body2=OBJECT_BODY)
    _add_markers(world, spec)
    target = grasp_target(spec)
    for name, offset in zip(CAMERAS, ((-0.25, 0.42, 0.30), (-0.06, -0.45, 0.32)), strict=True):
        eye = target + np.asarray(offset)
        sub(world, "camera", name=name, pos=eye, xyaxes=look_at(eye, target + np.array([0.0, 0.0, 0.03])), fovy="55")
    wrist_pos, wrist_quat = home_wrist(spec)
    add_hand(root, wrist_pos, wrist_quat)
    ET.indent(root)
    return ET.tostring(root, encoding="unicode")


def _add_markers(world: ET.Element, spec: TaskSpec) -> None:
    """Non-colliding visual markers of the goal (pick) and the path (wipe), for the cameras."""
    if spec.goal_pos is not None:
        sub(world, "site", name="goal", type="sphere", size="0.012", pos=spec.goal_pos, rgba="0.1 0.8 0.2 0.5")
    for i, (x, y) in enumerate(spec.wipe_path or ()):
        sub(
            world,
            "site",
            name=f"waypoint_{i}",
            type="cylinder",
            size="0.012 0.0005",
            pos=(x, y, 0.0005),
            rgba="0.1 0.6 0.9 0.6",
        )


def build_scene(task: str | TaskSpec, cfg: SimConfig | None = None) -> Scene:
    """Compile the scene of a task (by registry name or spec) and index its state layout."""
    spec = scenes.get(task) if isinstance(task, str) else task
    cfg = cfg or SimConfig()
    xml = scene_xml(spec, cfg)
    model = mujoco.MjModel.from_xml_string(xml)
    joints = [model.joint(n) for n in hd.JOINT_NAMES]
    obj_joint = model.joint("drawer_slide" if spec.slide is not None else "object_free")
    sensors = [model.sensor(f"{REGION_SENSOR_PREFIX}{r}") for r in hd.REGION_NAMES]
    tips = [model.sensor(f"{s}_pos") for s in hd.TIP_SITES]
    hand_qpos = np.array([model.jnt_qposadr[j.id] for j in joints])
    home = model.qpos0.copy()
    home[hand_qpos] = home_joint_targets()
    wrist_pos, wrist_quat = home_wrist(spec)
    wrist_adr = int(model.jnt_qposadr[model.joint("wrist_free").id])
    assert model.body(WRIST_BODY).id > 0 and model.body(WRIST_TARGET).mocapid[0] == 0
    return Scene(
        spec=spec,
        xml=xml,
        model=model,
        hand_qpos=hand_qpos,
        hand_dof=np.array([model.jnt_dofadr[j.id] for j in joints]),
        wrist_qpos=wrist_adr,
        object_qpos=int(model.jnt_qposadr[obj_joint.id]),
        region_sensors=np.array([model.sensor_adr[s.id] for s in sensors]),
        tip_sensors=np.array([model.sensor_adr[s.id] + np.arange(3) for s in tips]),
        region_pos_sensors=np.array(
            [model.sensor_adr[model.sensor(f"{r}_zone_pos").id] + np.arange(3) for r in hd.REGION_NAMES]
        ),
        object_dof=int(model.jnt_dofadr[obj_joint.id]),
        object_mass=float(model.body_mass[model.body(OBJECT_BODY).id]),
        object_inertia=float(model.body_inertia[model.body(OBJECT_BODY).id].mean()),
        home_qpos=home,
        home_wrist_pos=wrist_pos,
        home_wrist_quat=wrist_quat,
        point_cloud=sample_surface(spec.object.geoms, cfg.point_cloud_size, seed=cfg.seed),
    )
