"""The right LEAP Hand: one description (``description``) and its MJCF and URDF emitters."""

from touch2robot.leap.description import JOINT_NAMES, REGION_NAMES, TIP_SITES
from touch2robot.leap.mjcf import add_hand, hand_mjcf
from touch2robot.leap.urdf import hand_urdf

__all__ = ["JOINT_NAMES", "REGION_NAMES", "TIP_SITES", "add_hand", "hand_mjcf", "hand_urdf"]
