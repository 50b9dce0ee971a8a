"""Task scene specifications shared by the simulated demonstrator and the MuJoCo scenes.

One source of truth for every object's geometry, mass, friction and placement, so
that the demonstrator's scripted object trajectories are feasible in the physics
scenes built from the same numbers. World frame: z up, table top at z = 0,
metres / kilograms / radians, quaternions in MuJoCo order (w, x, y, z).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

Shape = Literal["box", "cylinder", "sphere", "capsule"]


@dataclass(frozen=True)
class GeomSpec:
    """A primitive in its body's frame. ``size`` follows MuJoCo: box half-extents
    (3), cylinder/capsule (radius, half-length along local z), sphere (radius,)."""

    shape: Shape
    size: tuple[float, ...]
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    name: str = ""


@dataclass(frozen=True)
class ObjectSpec:
    """The manipulated object: a free body (or a slide-jointed drawer) made of primitives."""

    name: str
    geoms: tuple[GeomSpec, ...]
    mass: float
    friction: float
    init_pos: tuple[float, float, float]
    init_quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    rgba: tuple[float, float, float, float] = (0.8, 0.3, 0.2, 1.0)
    # A compliant object (foam): MuJoCo's solref (time constant s, damping ratio) and solimp (impedance
    # at zero and full depth, the depth in m over which it stiffens) of its contacts with the hand.
    # None = MuJoCo's rigid defaults.
    solref: tuple[float, float] | None = None
    solimp: tuple[float, float, float] | None = None
    # The object's friction against the table where it is not MuJoCo's max of the two (the table's
    # contacts then take the table's friction and stiffness); None = the max rule.
    table_friction: float | None = None


@dataclass(frozen=True)
class SlideSpec:
    """A prismatic joint for the drawer: axis in the world frame, travel range in metres."""

    axis: tuple[float, float, float]
    range: tuple[float, float]
    damping: float
    cabinet: tuple[GeomSpec, ...]  # fixed geoms of the cabinet around the drawer
    frictionloss: float = 0.0  # N: Coulomb friction of the rails (what keeps a released drawer where it is)


@dataclass(frozen=True)
class TaskSpec:
    """Everything task-specific in the scene: object, goal, success parameters, episode length."""

    name: str
    object: ObjectSpec
    episode_s: float
    success: dict[str, float]
    goal_pos: tuple[float, float, float] | None = None
    rotation_axis: tuple[float, float, float] | None = None
    rotation_angle: float | None = None
    wipe_path: tuple[tuple[float, float], ...] | None = None
    slide: SlideSpec | None = None
    table_half_extent: tuple[float, float] = (0.4, 0.4)
    # MuJoCo's noslip passes after each step: they cut the soft contacts' friction creep (0 = none)
    noslip_iterations: int = 0
    notes: str = ""
    tags: tuple[str, ...] = field(default_factory=tuple)
