"""MJCF emitter for the LEAP Hand description: a free-floating hand whose wrist follows a mocap
target through a weld, 16 position servos, fingertip sites and one touch sensor per tactile region.

Why a mocap weld for the wrist (rather than six actuated joints): human wrist trajectories arrive
as world poses; a mocap target takes them as they are (no Euler decomposition, no gimbal lock), the
batched rollout can feed mocap poses per substep alongside the servo commands, and the weld's
finite stiffness gives the compliance of the arm that would carry the hand.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np

from touch2robot.leap import description as hd

WRIST_BODY = "wrist"
WRIST_TARGET = "wrist_target"
WELD_SOLREF = (0.02, 1.0)  # s, damping ratio: stiffest MuJoCo allows at a 10 ms step (2 x timestep)
REGION_SENSOR_PREFIX = "touch_"
HAND_RGBA = (0.18, 0.18, 0.2, 1.0)
TIP_RGBA = (0.85, 0.85, 0.8, 1.0)
PAD_RGBA = (0.35, 0.6, 0.85, 1.0)
HAND_FRICTION = 0.2  # plastic links (Menagerie/Playground default)
PAD_FRICTION = 0.7  # rubber fingertip pads (Playground's fingertip value), also used for palm pads


def fmt(values: object) -> str:
    """MJCF attribute text for a number or a sequence of numbers."""
    arr = np.atleast_1d(np.asarray(values, dtype=np.float64))
    return " ".join(f"{v:.9g}" for v in arr)


def sub(parent: ET.Element, tag: str, **attrs: object) -> ET.Element:
    """Append an element; attribute values that are not strings are formatted as numbers."""
    return ET.SubElement(parent, tag, {k: v if isinstance(v, str) else fmt(v) for k, v in attrs.items()})


def section(root: ET.Element, tag: str) -> ET.Element:
    """The top-level ``<tag>`` section of an MJCF root, created if missing."""
    found = root.find(tag)
    return found if found is not None else sub(root, tag)


def _add_defaults(root: ET.Element) -> None:
    default = section(root, "default")
    leap = sub(default, "default", **{"class": "leap"})
    sub(
        leap,
        "joint",
        axis=hd.JOINT_AXIS,
        damping=hd.JOINT_DAMPING,
        armature=hd.ARMATURE,
        frictionloss=hd.FRICTIONLOSS,
        limited="true",
    )
    sub(
        leap,
        "position",
        kp=hd.KP,
        forcerange=(-hd.TORQUE_LIMIT, hd.TORQUE_LIMIT),
        forcelimited="true",
        ctrllimited="true",
    )
    sub(leap, "geom", rgba=HAND_RGBA, friction=(HAND_FRICTION, 0.05, 0.0002), condim="3", density="0", group="0")
    pad = sub(leap, "default", **{"class": "leap_pad"})
    sub(pad, "geom", rgba=PAD_RGBA, friction=(PAD_FRICTION, 0.05, 0.0002))


def _add_body(parent: ET.Element, lk: hd.Link, children: dict[str, list[hd.Link]]) -> None:
    attrs: dict[str, object] = {"name": lk.name, "pos": lk.pos, "quat": lk.quat, "childclass": "leap"}
    if lk.name == "palm":
        # the arm carries the palm: compensate its weight so that the soft weld does not sag
        attrs = {
            "name": "palm",
            "pos": hd.PALM_IN_WRIST_POS,
            "quat": hd.PALM_IN_WRIST_QUAT,
            "childclass": "leap",
            "gravcomp": "1",
        }
    body = sub(parent, "body", **attrs)
    sub(body, "inertial", pos=lk.com, mass=lk.mass, diaginertia=lk.diaginertia)
    if lk.joint is not None:
        sub(body, "joint", name=lk.joint.name, range=(lk.joint.lower, lk.joint.upper))
    for box in hd.PALM_BOXES if lk.name == "palm" else ():
        sub(body, "geom", name=box.name, type="box", size=box.half, pos=box.pos, quat=box.quat)
    for cap in hd.CAPSULES:
        if cap.body == lk.name:
            a, b = hd.palm_point_to_body(lk.name, cap.start), hd.palm_point_to_body(lk.name, cap.end)
            sub(body, "geom", name=f"{lk.name}_link", type="capsule", fromto=np.concatenate([a, b]), size=cap.radius)
    for region in hd.REGIONS:
        box = region.box
        if box.body == lk.name:
            rgba = TIP_RGBA if region.name.startswith("T") else PAD_RGBA
            sub(
                body,
                "geom",
                name=box.name,
                type="box",
                size=box.half,
                pos=box.pos,
                quat=box.quat,
                rgba=rgba,
                **{"class": "leap_pad"},
            )
            half = np.asarray(box.half) + np.asarray(region.margin)
            sub(
                body,
                "site",
                name=f"{region.name}_zone",
                type="box",
                size=half,
                pos=box.pos,
                quat=box.quat,
                rgba=(0, 0, 0, 0),
                group="4",
            )
    for site, (body_name, offset) in hd.TIP_SITES.items():
        if body_name == lk.name:
            sub(body, "site", name=site, pos=offset, size=0.004, rgba=(1, 0.2, 0.2, 1), group="4")
    for child in children.get(lk.name, []):
        _add_body(body, child, children)


def add_hand(root: ET.Element, wrist_pos: np.ndarray, wrist_quat: np.ndarray) -> None:
    """Add the hand to an MJCF ``<mujoco>`` root: a free ``wrist`` body (dex-urdf base frame) welded
    to the mocap body ``wrist_target``, both at the given world pose, plus servos and sensors."""
    _add_defaults(root)
    world = section(root, "worldbody")
    wrist = sub(world, "body", name=WRIST_BODY, pos=wrist_pos, quat=wrist_quat)
    sub(wrist, "freejoint", name="wrist_free")
    children: dict[str, list[hd.Link]] = {}
    for lk in hd.LINKS:
        children.setdefault(lk.parent, []).append(lk)
    _add_body(wrist, hd.link("palm"), children)
    target = sub(world, "body", name=WRIST_TARGET, pos=wrist_pos, quat=wrist_quat, mocap="true")
    sub(target, "site", name="wrist_target_site", size=0.005, rgba=(0.2, 1, 0.2, 0.5), group="4")

    sub(
        section(root, "equality"),
        "weld",
        name="wrist_weld",
        body1=WRIST_BODY,
        body2=WRIST_TARGET,
        relpose=(0, 0, 0, 1, 0, 0, 0),
        solref=WELD_SOLREF,
    )
    contact = section(root, "contact")
    for a, b in hd.EXCLUDES:
        sub(contact, "exclude", body1=a, body2=b)
    actuator = section(root, "actuator")
    for name in hd.JOINT_NAMES:
        lo, hi = _joint_range(name)
        sub(actuator, "position", name=name, joint=name, ctrlrange=(lo, hi), **{"class": "leap"})
    sensor = section(root, "sensor")
    for region in hd.REGION_NAMES:
        sub(sensor, "touch", name=f"{REGION_SENSOR_PREFIX}{region}", site=f"{region}_zone")
    for region in hd.REGION_NAMES:  # where each region is: contact-position rewards aim these at object points
        sub(sensor, "framepos", name=f"{region}_zone_pos", objtype="site", objname=f"{region}_zone")
    for site in hd.TIP_SITES:
        sub(sensor, "framepos", name=f"{site}_pos", objtype="site", objname=site)


def _joint_range(name: str) -> tuple[float, float]:
    for lk in hd.LINKS:
        if lk.joint is not None and lk.joint.name == name:
            return lk.joint.lower, lk.joint.upper
    raise KeyError(name)


def mjcf_root(model_name: str, timestep: float = 0.01) -> ET.Element:
    """An MJCF root with the compiler and physics options every touch2robot model shares."""
    root = ET.Element("mujoco", model=model_name)
    sub(root, "compiler", angle="radian", autolimits="true")
    # implicitfast: stable with the servos' damping at 10 ms; Newton converges in a few iterations
    sub(
        root,
        "option",
        timestep=timestep,
        integrator="implicitfast",
        cone="pyramidal",
        iterations="10",
        ls_iterations="8",
    )
    return root


def hand_mjcf(
    wrist_pos: tuple[float, float, float] = (0.0, 0.0, 0.3),
    wrist_quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0),
    timestep: float = 0.01,
) -> str:
    """A stand-alone MJCF document with only the hand (for tests and inspection)."""
    root = mjcf_root("leap_right_hand", timestep)
    add_hand(root, np.asarray(wrist_pos), np.asarray(wrist_quat))
    ET.indent(root)
    return ET.tostring(root, encoding="unicode")
