"""URDF emitter for the LEAP Hand description: the kinematic tree for kinematic-retargeting tools
(dex-retargeting and the like). Root link ``base`` in dex-urdf's wrist convention, links named
like the MJCF bodies, joints named like the MJCF joints (if_mcp ... th_ipl), fixed fingertip links
``th_tip``/``if_tip``/``mf_tip``/``rf_tip`` at the fingertip site points (dex-urdf's ``*_tip_head``).
Inertials only: no meshes, so the file stands alone."""

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


def _fixed(robot: ET.Element, name: str, parent: str, child: str, xyz: object, rpy: object) -> None:
    joint = sub(robot, "joint", name=name, type="fixed")
    sub(joint, "origin", xyz=xyz, rpy=rpy)
    sub(joint, "parent", link=parent)
    sub(joint, "child", link=child)


def hand_urdf() -> str:
    """The URDF document of the right LEAP Hand."""
    robot = ET.Element("robot", name="leap_hand_right")
    sub(robot, "link", name="base")
    for lk in hd.LINKS:
        link = sub(robot, "link", name=lk.name)
        inertial = sub(link, "inertial")
        sub(inertial, "origin", xyz=lk.com, rpy="0 0 0")
        sub(inertial, "mass", value=lk.mass)
        ixx, iyy, izz = lk.diaginertia
        sub(inertial, "inertia", ixx=ixx, iyy=iyy, izz=izz, ixy="0", ixz="0", iyz="0")
        if lk.name == "palm":
            _fixed(robot, "base_to_palm", "base", "palm", hd.PALM_IN_WRIST_POS, quat_to_rpy(hd.PALM_IN_WRIST_QUAT))
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


__all__ = ["hand_urdf", "quat_to_rpy"]
