"""URDF emitter for the LEAP Hand description: the kinematic tree for kinematic-retargeting tools
(dex-retargeting and the like). Root link ``base`` in dex-urdf's wrist convention, links named
like the MJCF bodies, joints named like the MJCF joints (if_mcp ... th_ipl), fixed fingertip links
``th_tip``/``if_tip``/``mf_tip``/``rf_tip`` at the fingertip site points (dex-urdf's ``*_tip_head``).
Inertials, and visuals from the collision geometry (capsules drawn as cylinders, palm and tactile pads as
boxes) for viewers such as Foxglove's 3D panel: no meshes, so the file stands alone."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np

from touch2robot.geometry import quat_to_mat
from touch2robot.leap import description as hd
from touch2robot.leap.mjcf import sub


def quat_to_rpy(quat: tuple[float, ...] | np.ndarray) -> np.ndarray:
    """URDF roll-pitch-yaw (R = Rz(yaw) Ry(pitch) Rx(roll)) of a (w, x, y, z) quaternion."""
    m = quat_to_mat(np.asarray(quat))
    pitch = math.asin(max(-1.0, min(1.0, -m[2, 0])))
    if abs(m[2, 0]) < 1.0 - 1e-9:
        roll = math.atan2(m[2, 1], m[2, 2])
        yaw = math.atan2(m[1, 0], m[0, 0])
    else:  # gimbal lock: put all of the remaining rotation into yaw
        roll = 0.0
        yaw = math.atan2(-m[0, 1], m[1, 1])
    return np.array([roll, pitch, yaw])


def _z_to(direction: np.ndarray) -> np.ndarray:
    """The (w, x, y, z) quaternion turning +z onto ``direction`` (a URDF cylinder's axis is its z)."""
    d = direction / np.linalg.norm(direction)
    axis, cos = np.cross([0.0, 0.0, 1.0], d), float(d[2])
    if np.linalg.norm(axis) < 1e-9:
        return np.array([1.0, 0.0, 0.0, 0.0]) if cos > 0 else np.array([0.0, 1.0, 0.0, 0.0])
    half = math.acos(max(-1.0, min(1.0, cos))) / 2
    return np.r_[math.cos(half), math.sin(half) * axis / np.linalg.norm(axis)]


def _visuals(link: ET.Element, name: str) -> None:
    boxes = [b for b in hd.PALM_BOXES if b.body == name] + [r.box for r in hd.REGIONS if r.box.body == name]
    for box in boxes:
        visual = sub(link, "visual", name=box.name)
        sub(visual, "origin", xyz=box.pos, rpy=quat_to_rpy(box.quat))
        sub(sub(visual, "geometry"), "box", size=2 * np.asarray(box.half))
    for cap in (c for c in hd.CAPSULES if c.body == name):
        a, b = hd.palm_point_to_body(name, cap.start), hd.palm_point_to_body(name, cap.end)
        visual = sub(link, "visual", name=f"{name}_link")
        sub(visual, "origin", xyz=(a + b) / 2, rpy=quat_to_rpy(_z_to(b - a)))
        sub(sub(visual, "geometry"), "cylinder", radius=cap.radius, length=float(np.linalg.norm(b - a)))


def _fixed(robot: ET.Element, name: str, parent: str, child: str, xyz: object, rpy: object) -> None:
    joint = sub(robot, "joint", name=name, type="fixed")
    sub(joint, "origin", xyz=xyz, rpy=rpy)
    sub(joint, "parent", link=parent)
    sub(joint, "child", link=child)


URDF_ROOT = "base"  # the root link: the wrist frame (schemas.glove.WRIST_FRAME)


def hand_urdf() -> str:
    """The URDF document of the right LEAP Hand."""
    robot = ET.Element("robot", name="leap_hand_right")
    sub(robot, "link", name=URDF_ROOT)
    for lk in hd.LINKS:
        link = sub(robot, "link", name=lk.name)
        inertial = sub(link, "inertial")
        sub(inertial, "origin", xyz=lk.com, rpy="0 0 0")
        sub(inertial, "mass", value=lk.mass)
        ixx, iyy, izz = lk.diaginertia
        sub(inertial, "inertia", ixx=ixx, iyy=iyy, izz=izz, ixy="0", ixz="0", iyz="0")
        _visuals(link, lk.name)
        if lk.name == "palm":
            _fixed(robot, "base_to_palm", URDF_ROOT, "palm", hd.PALM_IN_WRIST_POS, quat_to_rpy(hd.PALM_IN_WRIST_QUAT))
            continue
        assert lk.joint is not None  # every link but the palm is jointed
        joint = sub(robot, "joint", name=lk.joint.name, type="revolute")
        sub(joint, "origin", xyz=lk.pos, rpy=quat_to_rpy(lk.quat))
        sub(joint, "parent", link=lk.parent)
        sub(joint, "child", link=lk.name)
        sub(joint, "axis", xyz=hd.JOINT_AXIS)
        sub(
            joint,
            "limit",
            lower=lk.joint.lower,
            upper=lk.joint.upper,
            effort=hd.TORQUE_LIMIT,
            velocity=hd.VELOCITY_LIMIT,
        )
    for site, (body, offset) in hd.TIP_SITES.items():
        sub(robot, "link", name=site)
        _fixed(robot, f"{site}_joint", body, site, offset, "0 0 0")
    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


__all__ = ["URDF_ROOT", "hand_urdf", "quat_to_rpy"]
