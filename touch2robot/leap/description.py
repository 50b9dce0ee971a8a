"""The one description of the right LEAP Hand that every emitter (MJCF, URDF) reads.

Numbers are carried over from public models (MuJoCo Menagerie ``leap_hand/right_hand.xml``,
MIT, Copyright 2023 Ananye Agarwal; MuJoCo Playground ``leap_rh_mjx.xml``, Apache-2.0;
dexsuite/dex-urdf and leap-hand/LEAP_Hand_Sim URDFs), tabulated, not copied as files.

Frames (palm frame = Menagerie's ``palm`` body): +x from the palm toward the fingertips,
+y from the ring finger toward the index finger / thumb (radial), -z the palmar side.
The "wrist" frame is dex-urdf's root ``base`` link: +z = palm +x (wrist to fingertips),
+x = palm -z (out of the palm), +y = palm +y, origin on the wrist edge of the palm.
Every hinge sits at its body origin with local axis (0, 0, -1). Lengths in m, angles in rad,
masses in kg, quaternions (w, x, y, z).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from touch2robot.geometry import quat_mul, quat_to_mat

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]

JOINT_AXIS: Vec3 = (0.0, 0.0, -1.0)


@dataclass(frozen=True)
class Joint:
    """A hinge at its body's origin about ``JOINT_AXIS``."""

    name: str
    lower: float
    upper: float


@dataclass(frozen=True)
class Link:
    """A rigid body of the hand: pose in its parent at q = 0, joint, and inertia."""

    name: str
    parent: str
    pos: Vec3
    quat: Quat
    joint: Joint | None
    mass: float
    com: Vec3
    diaginertia: Vec3


@dataclass(frozen=True)
class Capsule:
    """A collision capsule given by its end points in the *palm frame at q = 0*, where link
    geometry is easiest to read off the joint-anchor table; emitters map it into its body."""

    body: str
    start: Vec3
    end: Vec3
    radius: float


@dataclass(frozen=True)
class Box:
    """A collision box in its own body's frame (half sizes)."""

    name: str
    body: str
    half: Vec3
    pos: Vec3
    quat: Quat = (1.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Region:
    """One tactile region: a dedicated collision box and the touch-sensor volume around it."""

    name: str
    box: Box
    margin: Vec3  # how far the sensing volume reaches past the box faces, per box axis


# --- joints ----------------------------------------------------------------------------------
FINGER_JOINTS = {"mcp": (-0.314, 2.23), "rot": (-1.047, 1.047), "pip": (-0.506, 1.885), "dip": (-0.366, 2.042)}
# Thumb limits: the two URDFs (official LEAP_Hand_Sim and dex-urdf) agree on th_axl -0.47..2.443 and
# th_mcp -1.20..1.90, while the Menagerie/Playground MJCFs give th_axl the th_cmc range and th_mcp the
# URDF's th_axl range -- a one-row shift, the signature of a transcription slip in the conversion.
# We take the URDF values: two independent sources, one of them the hand's authors' own.
THUMB_JOINTS = {"cmc": (-0.349, 2.094), "axl": (-0.47, 2.443), "mcp": (-1.20, 1.90), "ipl": (-1.34, 1.88)}

FINGERS = ("if", "mf", "rf")
JOINT_NAMES: tuple[str, ...] = (
    *(f"{f}_{j}" for f in FINGERS for j in FINGER_JOINTS),
    *(f"th_{j}" for j in THUMB_JOINTS),
)

# --- actuation (Playground's leap_rh_mjx.xml: these keep a 0.01 s timestep stable) -----------------
KP = 3.0  # position-servo gain, N·m/rad (Menagerie and Playground agree)
TORQUE_LIMIT = 0.2196  # N·m, Playground's XL330 current-limit figure (the URDF's 0.95 is the stall rating)
JOINT_DAMPING = 0.2  # N·m·s/rad
ARMATURE = 0.00149376  # kg·m², rotor inertia 1.7e-8 × gear 288²: what makes 10 ms steps stable
FRICTIONLOSS = 0.02  # N·m
VELOCITY_LIMIT = 8.48  # rad/s (URDF)

# --- body tree -------------------------------------------------------------------------------------
_BS_Q: Quat = (0.500003, 0.5, 0.5, -0.499997)
_PX_Q: Quat = (0.500003, -0.5, -0.499997, 0.5)
_MD_Q: Quat = (0.500003, 0.5, -0.5, 0.499997)
_ID_Q: Quat = (1.0, 0.0, 0.0, 0.0)
_IN = {
    "palm": (4.07345e-4, 3.04759e-4, 1.80736e-4),
    "bs": (1.74972e-5, 1.61504e-5, 7.21342e-6),
    "px": (4.8853e-6, 4.3733e-6, 3.0933e-6),
    "md": (8.28004e-6, 8.1598e-6, 5.39516e-6),
    "ds": (3.71863e-6, 3.02396e-6, 1.6518e-6),
    "th_bs": (6.1932e-7, 5.351e-7, 2.1516e-7),
    "th_px": (9.87104e-6, 9.32653e-6, 4.36203e-6),
    "th_ds": (2.08591e-5, 2.0402e-5, 4.71335e-6),
}
_MCP_POS = {"if": (-0.007, 0.023, -0.0187), "mf": (-0.0071, -0.0224, -0.0187), "rf": (-0.00709, -0.0678, -0.0187)}
_DS_POS = {"if": (0.0, -0.0361, 0.0002), "mf": (0.0, -0.0361, 0.0002), "rf": (0.0, -0.03609, 0.0002)}


def _finger(f: str) -> tuple[Link, ...]:
    j = {k: Joint(f"{f}_{k}", *v) for k, v in FINGER_JOINTS.items()}
    return (
        Link(f"{f}_bs", "palm", _MCP_POS[f], _BS_Q, j["mcp"], 0.044, (-0.022516, 0.033882, 0.016359), _IN["bs"]),
        Link(
            f"{f}_px",
            f"{f}_bs",
            (-0.0122, 0.0381, 0.0145),
            _PX_Q,
            j["rot"],
            0.032,
            (0.0075, -0.0002, -0.011),
            _IN["px"],
        ),
        Link(
            f"{f}_md",
            f"{f}_px",
            (0.015, 0.0143, -0.013),
            _MD_Q,
            j["pip"],
            0.037,
            (0.0054215, -0.029148, 0.015),
            _IN["md"],
        ),
        Link(f"{f}_ds", f"{f}_md", _DS_POS[f], _ID_Q, j["dip"], 0.016, (-0.0008794, -0.027019, 0.014594), _IN["ds"]),
    )


_TH = {k: Joint(f"th_{k}", *v) for k, v in THUMB_JOINTS.items()}
LINKS: tuple[Link, ...] = (
    Link("palm", "wrist", (0.0, 0.0, 0.0), _ID_Q, None, 0.237, (-0.049542, -0.042914, -0.010227), _IN["palm"]),
    *(link for f in FINGERS for link in _finger(f)),
    Link(
        "th_mp",
        "palm",
        (-0.0693, -0.0012, -0.0216),
        (0.707109, 0.0, 0.707105, 0.0),
        _TH["cmc"],
        0.032,
        (0.0075, -0.0002, -0.011),
        _IN["px"],
    ),
    Link("th_bs", "th_mp", (0.0, 0.0143, -0.013), _MD_Q, _TH["axl"], 0.003, (0.0, 0.0, -0.0070806), _IN["th_bs"]),
    Link(
        "th_px",
        "th_bs",
        (0.0, 0.0145, -0.017),
        (0.707109, -0.707105, 0.0, 0.0),
        _TH["mcp"],
        0.038,
        (-0.0020593, 0.015912, -0.013733),
        _IN["th_px"],
    ),
    Link(
        "th_ds",
        "th_px",
        (0.0, 0.0466, 0.0002),
        (1.32679e-06, 0.0, 0.0, 1.0),
        _TH["ipl"],
        0.049,
        (0.00096191, -0.024203, -0.014419),
        _IN["th_ds"],
    ),
)

# The wrist ("base") frame in dex-urdf: palm fixed at xyz (0, 0.038, 0.098), rpy (0, -pi/2, 0).
PALM_IN_WRIST_POS: Vec3 = (0.0, 0.038, 0.098)
PALM_IN_WRIST_QUAT: Quat = (math.cos(-math.pi / 4), 0.0, math.sin(-math.pi / 4), 0.0)

# --- fingertips (Playground's fingertip sites = dex-urdf tip heads up to 2 mm) ---------------------
TIP_SITES: dict[str, tuple[str, Vec3]] = {
    "th_tip": ("th_ds", (0.0, -0.06, -0.015)),
    "if_tip": ("if_ds", (0.0, -0.05, 0.015)),
    "mf_tip": ("mf_ds", (0.0, -0.05, 0.015)),
    "rf_tip": ("rf_ds", (0.0, -0.05, 0.015)),
}

# --- tactile regions --------------------------------------------------------------------------------
# Fingertips: Playground's fingertip boxes (the pad the real TwinTac sensors sit on).
_TIP_HALF: Vec3 = (0.01, 0.012, 0.016)
_TIP_FINGER = ((-0.0012969, -0.0335524, 0.0145207), (0.703552, 0.709596, -0.0292107, -0.0252203))
_TIP_THUMB = ((-0.00127744, -0.0455619, -0.0144774), (0.708101, 0.705072, -0.0294902, -0.024426))

# Palm pads: four thin plates on the palmar face (where the real rig's FSRs sit), laid out like the
# glove's P1..P4. The split lines: distal/proximal at palm x = -0.036 (just behind the finger-base
# servos), radial/ulnar between middle and ring MCP (y = -0.045) distally -- "below index/middle" vs
# "below ring" -- and at the palm's mid-line (y = -0.035) proximally, with the thumb root on the radial
# side. The plates' outer face is 2.5 mm proud of the deepest palm box (z = -0.0345) so that objects
# meet the pads first; 1 mm gaps keep neighbouring sensing volumes apart.
_PAD_Z, _PAD_HZ = -0.033, 0.004
PALM_PADS: dict[str, tuple[Vec3, Vec3]] = {  # name -> (centre xy-z in palm frame, half sizes)
    "P1": ((-0.018, -0.0095, _PAD_Z), (0.0175, 0.035, _PAD_HZ)),  # distal radial: below index/middle
    "P2": ((-0.018, -0.069, _PAD_Z), (0.0175, 0.0235, _PAD_HZ)),  # distal ulnar: below ring
    "P3": ((-0.066, -0.0045, _PAD_Z), (0.0295, 0.030, _PAD_HZ)),  # proximal radial: thenar (thumb root)
    "P4": ((-0.066, -0.0645, _PAD_Z), (0.0295, 0.029, _PAD_HZ)),  # proximal ulnar: hypothenar
}

REGION_NAMES: tuple[str, ...] = ("T1", "T2", "T3", "T4", "P1", "P2", "P3", "P4")
_TIP_BODY = {"T1": "th_ds", "T2": "if_ds", "T3": "mf_ds", "T4": "rf_ds"}
# Touch sensors count contacts whose point lies in the sensing volume; MuJoCo puts the point midway
# through the penetration, i.e. up to ~1 mm outside the pad, so the volume reaches 3 mm past the
# faces that objects press. Fingertips are pressed on every face; palm pads on their outer face only,
# laterally the volumes grow by less than half the 1 mm gap so that neighbouring pads never overlap.
TIP_MARGIN: Vec3 = (0.003, 0.003, 0.003)
PAD_MARGIN: Vec3 = (0.0004, 0.0004, 0.003)


def _regions() -> tuple[Region, ...]:
    out = []
    for name, body in _TIP_BODY.items():
        pos, quat = _TIP_THUMB if body == "th_ds" else _TIP_FINGER
        out.append(Region(name, Box(f"{name}_pad", body, _TIP_HALF, pos, quat), TIP_MARGIN))
    for name, (pos, half) in PALM_PADS.items():
        out.append(Region(name, Box(f"{name}_pad", "palm", half, pos), PAD_MARGIN))
    return tuple(out)


REGIONS: tuple[Region, ...] = _regions()

# --- other collision geometry -----------------------------------------------------------------------
# Palm: Menagerie's ten structural boxes (half sizes, pos, quat) in the palm frame.
PALM_BOXES: tuple[Box, ...] = tuple(
    Box(f"palm_{i}", "palm", h, p, q)
    for i, (h, p, q) in enumerate(
        [
            ((0.011, 0.013, 0.017), (-0.009, 0.008, -0.011), _ID_Q),
            ((0.011, 0.013, 0.017), (-0.009, -0.037, -0.011), _ID_Q),
            ((0.011, 0.013, 0.017), (-0.009, -0.082, -0.011), _ID_Q),
            ((0.029, 0.01, 0.023), (-0.066, -0.078, -0.0115), (0.989016, 0.0, 0.0, -0.147806)),
            ((0.01, 0.06, 0.015), (-0.03, -0.035, -0.003), _ID_Q),
            ((0.005, 0.06, 0.01), (-0.032, -0.035, -0.024), (0.923956, 0.0, 0.382499, 0.0)),
            ((0.012, 0.058, 0.023), (-0.048, -0.033, -0.0115), _ID_Q),
            ((0.022, 0.026, 0.023), (-0.078, -0.053, -0.0115), _ID_Q),
            ((0.002, 0.018, 0.017), (-0.098, -0.009, -0.006), _ID_Q),
            ((0.022, 0.028, 0.002), (-0.078, -0.003, 0.01), _ID_Q),
        ]
    )
)


def _finger_capsules(f: str) -> tuple[Capsule, ...]:
    """Link capsules along the finger's centre line, read off the joint anchors at q = 0: the
    servo horns (body origins) sit on one end of each joint axis, the finger runs 15.4 mm over."""
    y0 = _MCP_POS[f][1] - 0.023  # offset of this finger from the index finger
    c = 0.0076 + y0  # finger centre line, palm y
    return (
        Capsule(f"{f}_bs", (-0.004, 0.019 + y0, -0.016), (0.024, 0.011 + y0, -0.010), 0.011),
        Capsule(f"{f}_px", (0.031, c + 0.006, -0.012), (0.046, c + 0.008, -0.0195), 0.010),
        Capsule(f"{f}_md", (0.052, c + 0.004, -0.0195), (0.078, c + 0.004, -0.0195), 0.011),
        Capsule(f"{f}_ds", (0.086, c, -0.0195), (0.094, c, -0.0195), 0.010),
    )


CAPSULES: tuple[Capsule, ...] = (
    *(c for f in FINGERS for c in _finger_capsules(f)),
    Capsule("th_mp", (-0.0715, 0.001, -0.0216), (-0.0823, 0.0131, -0.0216), 0.010),
    Capsule("th_bs", (-0.0823, 0.0150, -0.0150), (-0.0823, 0.0290, -0.0100), 0.009),
    Capsule("th_px", (-0.0823, 0.0340, -0.0150), (-0.0823, 0.0720, -0.0150), 0.011),
    Capsule("th_ds", (-0.0823, 0.0800, -0.0219), (-0.0823, 0.0940, -0.0219), 0.010),
)

# Collision exclusions (Menagerie and Playground, plus one of ours): the palm may touch only the
# distal links; the finger bases overlap each other and the thumb metacarpal by construction.
EXCLUDES: tuple[tuple[str, str], ...] = (
    *(("palm", f"{f}_{b}") for f in FINGERS for b in ("bs", "px", "md")),
    ("palm", "th_mp"),
    ("palm", "th_bs"),
    ("palm", "th_px"),
    ("if_bs", "mf_bs"),
    ("if_bs", "rf_bs"),
    ("mf_bs", "rf_bs"),
    *(("th_mp", f"{f}_bs") for f in FINGERS),
    # ours only: the capsules of the thumb metacarpal and proximal links (one link apart) overlap
    # around the tiny th_bs link over half the joint space, where the real servo brackets clear
    ("th_mp", "th_px"),
)


# --- kinematics of the description itself (used to place palm-frame geometry in bodies) -----------
def link(name: str) -> Link:
    """The link called ``name``."""
    for lk in LINKS:
        if lk.name == name:
            return lk
    raise KeyError(name)


def body_pose_in_palm(name: str, q: dict[str, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(pos, quat) of a hand body in the palm frame for joint angles ``q`` (default all zero)."""
    q = q or {}
    if name == "palm":
        return np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0])
    lk = link(name)
    ppos, pquat = body_pose_in_palm(lk.parent, q)
    pos = ppos + quat_to_mat(pquat) @ np.asarray(lk.pos)
    quat = quat_mul(pquat, np.asarray(lk.quat))
    if lk.joint is not None:
        angle = q.get(lk.joint.name, 0.0)
        half = 0.5 * angle
        # rotation about the local axis (0, 0, -1)
        quat = quat_mul(quat, np.array([math.cos(half), 0.0, 0.0, -math.sin(half)]))
    return pos, quat / np.linalg.norm(quat)


def palm_point_to_body(body: str, point: Vec3) -> np.ndarray:
    """A palm-frame point at q = 0 expressed in ``body``'s frame."""
    pos, quat = body_pose_in_palm(body)
    return quat_to_mat(quat).T @ (np.asarray(point) - pos)


def tip_positions_in_palm(q: dict[str, float] | None = None) -> dict[str, np.ndarray]:
    """Fingertip site positions in the palm frame (the description's own forward kinematics)."""
    out = {}
    for site, (body, offset) in TIP_SITES.items():
        pos, quat = body_pose_in_palm(body, q)
        out[site] = pos + quat_to_mat(quat) @ np.asarray(offset)
    return out
