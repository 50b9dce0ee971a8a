"""A human right-hand kinematic model with the glove's sensing surfaces.

Hand frame (the wrist frame): origin at the wrist centre, +x towards the fingers, +y
towards the thumb (radial side), -z out of the palm (palmar side) — the same axes as the
LEAP palm frame, so a palm-down hand with fingers pointing along world +x has the
identity orientation. The 20 joint angles follow ``schemas.glove.GLOVE_JOINT_NAMES``
(flexion positive, towards -z). Every taxel of the glove has a point on the skin in
this model; a taxel is loaded when that point lies inside an object (soft tissue
compression), which is what makes contacts happen only where the hand really touches.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from schemas.glove import FINGERS, FINGERTIP_TAXELS, PALM_TAXELS, PHALANX_TAXELS, TAXEL_REGION

# Segment lengths (m) of a mid-sized adult hand; scaled per subject.
PHALANX_LENGTHS: dict[str, tuple[float, float, float]] = {
    "thumb": (0.046, 0.032, 0.028),  # metacarpal, proximal, distal
    "index": (0.045, 0.026, 0.022),
    "middle": (0.050, 0.030, 0.023),
    "ring": (0.047, 0.028, 0.022),
    "little": (0.037, 0.021, 0.020),
}
# Finger base (MCP, thumb CMC) in the hand frame, and resting splay about z (rad).
FINGER_BASES: dict[str, tuple[float, float, float]] = {
    "thumb": (0.025, 0.022, -0.012),
    "index": (0.092, 0.026, 0.0),
    "middle": (0.096, 0.004, 0.0),
    "ring": (0.090, -0.016, 0.0),
    "little": (0.080, -0.034, 0.0),
}
FINGER_SPLAY: dict[str, float] = {"thumb": 0.95, "index": 0.10, "middle": 0.0, "ring": -0.10, "little": -0.22}
THUMB_PRONATION = -1.0  # rad about the thumb's own axis: turns its flexion towards the palm
FINGER_RADIUS = 0.008
PALM_HALF_THICKNESS = 0.015
TISSUE_STIFFNESS = 400.0  # N per m of skin compression, per taxel patch

# Palm pads (x range, y range) on the palmar surface z = -PALM_HALF_THICKNESS.
PALM_PADS: dict[str, tuple[tuple[float, float], tuple[float, float]]] = {
    "P1": ((0.060, 0.088), (-0.002, 0.030)),  # distal radial (below index/middle)
    "P2": ((0.060, 0.088), (-0.040, -0.006)),  # distal ulnar (below ring/little)
    "P3": ((0.012, 0.054), (0.004, 0.034)),  # proximal radial (thenar)
    "P4": ((0.012, 0.054), (-0.040, -0.004)),  # proximal ulnar (hypothenar)
}


def _rot_z(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def _rot_y(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def _rot_x(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


@dataclass(frozen=True)
class HandPose:
    """Forward kinematics of a batch of frames, in the hand frame."""

    keypoints: np.ndarray  # (T, 21, 3)
    taxel_points: np.ndarray  # (T, 256, 3) skin points of the taxels


class HumanHand:
    """A subject's hand: segment lengths scaled by ``scale``."""

    def __init__(self, scale: float = 1.0) -> None:
        self.scale = scale
        self.lengths = {f: tuple(scale * v for v in PHALANX_LENGTHS[f]) for f in FINGERS}
        self.bases = {f: scale * np.asarray(FINGER_BASES[f]) for f in FINGERS}
        # taxel layouts in the local frames (fixed per glove, scaled with the hand)
        u = np.linspace(0.30, 0.92, FINGERTIP_TAXELS // 4)
        phi = np.linspace(-0.9, 0.9, 4)
        uu, pp = np.meshgrid(u, phi, indexing="ij")
        self._tip_uv = np.stack([uu.ravel(), pp.ravel()], -1)  # fraction along distal, angle around
        pu = np.linspace(0.2, 0.8, 2)
        pphi = np.linspace(-0.6, 0.6, 3)
        a, b = np.meshgrid(pu, pphi, indexing="ij")
        self._phalanx_uv = np.stack([a.ravel(), b.ravel()], -1)  # 6 per finger on the proximal phalanx
        palm = []
        for region in ("P1", "P2", "P3", "P4"):
            (x0, x1), (y0, y1) = PALM_PADS[region]
            gx, gy = np.meshgrid(np.linspace(x0, x1, 4), np.linspace(y0, y1, PALM_TAXELS // 4), indexing="ij")
            palm.append(np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, -PALM_HALF_THICKNESS)], -1))
        self._palm_points = scale * np.concatenate(palm)
        assert len(TAXEL_REGION) == 5 * FINGERTIP_TAXELS + len(self._palm_points) + 4 * len(self._phalanx_uv)
        assert 4 * len(self._phalanx_uv) == PHALANX_TAXELS

    def forward(self, joints: np.ndarray) -> HandPose:
        """Keypoints and taxel skin points for joint angles (T, 20)."""
        joints = np.asarray(joints, dtype=np.float64)
        t = joints.shape[0]
        keypoints = np.zeros((t, 21, 3))
        tips, phalanges = [], []
        for i, finger in enumerate(FINGERS):
            abd, flex1, flex2, flex3 = (joints[:, 4 * i + k] for k in range(4))
            base_rot = _rot_z(np.full(t, FINGER_SPLAY[finger]) + abd)
            if finger == "thumb":
                base_rot = base_rot @ _rot_x(np.full(t, THUMB_PRONATION))
            r1 = base_rot @ _rot_y(flex1)
            r2 = r1 @ _rot_y(flex2)
            r3 = r2 @ _rot_y(flex3)
            l1, l2, l3 = self.lengths[finger]
            p0 = np.broadcast_to(self.bases[finger], (t, 3))
            p1 = p0 + r1[..., :, 0] * l1
            p2 = p1 + r2[..., :, 0] * l2
            p3 = p2 + r3[..., :, 0] * l3
            keypoints[:, 1 + 4 * i : 5 + 4 * i] = np.stack([p0, p1, p2, p3], 1)
            tips.append(self._surface(p2, r3, l3, self._tip_uv))
            if finger != "thumb":
                # proximal phalanx of the four fingers (the glove's non-region taxels)
                phalanges.append(self._surface(p0, r1, l1, self._phalanx_uv))
        palm = np.broadcast_to(self._palm_points, (t, *self._palm_points.shape))
        taxel_points = np.concatenate(tips + [palm] + phalanges, axis=1)
        return HandPose(keypoints, taxel_points)

    def _surface(self, start: np.ndarray, rot: np.ndarray, length: float, uv: np.ndarray) -> np.ndarray:
        """Skin points of a segment: fraction u along its x axis, angle phi around it,
        phi = 0 on the palmar side (-z of the segment frame)."""
        r = FINGER_RADIUS * self.scale
        local = np.stack([uv[:, 0] * length, r * np.sin(uv[:, 1]), -r * np.cos(uv[:, 1])], -1)
        return start[:, None, :] + np.einsum("tij,nj->tni", rot, local)


def taxel_forces(penetration: np.ndarray) -> np.ndarray:
    """Normal force (N) on each taxel patch from skin compression depth (m)."""
    return TISSUE_STIFFNESS * np.maximum(penetration, 0.0)
