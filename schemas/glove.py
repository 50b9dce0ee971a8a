"""The simulated demonstrator's glove: which of its 256 taxels belongs to which human region, and the
joint angles its SDK reports. This is the simulated rig's glove (``schemas.rig.DEFAULT_RIG``); a lab's
glove is described by its own rig file, not by this module."""

from __future__ import annotations

import numpy as np

N_TAXELS = 256

# Human regions: fingertips T1..T5 (thumb, index, middle, ring, little), palm P1..P4:
# P1 distal palm radial (below index/middle), P2 distal palm ulnar (below ring/little),
# P3 proximal palm radial (thenar), P4 proximal palm ulnar (hypothenar).
FINGERTIP_TAXELS = 24  # per fingertip pad, a 4 x 6 grid
PALM_TAXELS = 28  # per palm pad, a 4 x 7 grid
PHALANX_TAXELS = 24  # on the proximal/middle phalanges; no region ("-")

TAXEL_REGION: tuple[str, ...] = (
    tuple(r for r in ("T1", "T2", "T3", "T4", "T5") for _ in range(FINGERTIP_TAXELS))
    + tuple(r for r in ("P1", "P2", "P3", "P4") for _ in range(PALM_TAXELS))
    + ("-",) * PHALANX_TAXELS
)
assert len(TAXEL_REGION) == N_TAXELS


def region_taxels(region: str) -> np.ndarray:
    """Indices of the taxels of one human region."""
    return np.flatnonzero(np.asarray(TAXEL_REGION) == region)


FINGERS: tuple[str, ...] = ("thumb", "index", "middle", "ring", "little")

# Wrist pose convention (/glove/wrist_pose, world frame): origin at the wrist centre, +x
# towards the fingers (along the middle metacarpal), +y towards the thumb (radial side of a
# right hand), -z out of the palm (palmar side). These are the LEAP palm frame's axes, so a
# palm-down hand with fingers along world +x has the identity orientation.
WRIST_FRAME = "x: to fingers, y: to thumb (radial), -z: palmar; origin at the wrist centre"

# 20 joint angles as the glove SDK reports them, 4 per finger (rad; flexion positive).
GLOVE_JOINT_NAMES: tuple[str, ...] = (
    "thumb_cmc_abd", "thumb_cmc_flex", "thumb_mcp", "thumb_ip",
    "index_mcp_abd", "index_mcp_flex", "index_pip", "index_dip",
    "middle_mcp_abd", "middle_mcp_flex", "middle_pip", "middle_dip",
    "ring_mcp_abd", "ring_mcp_flex", "ring_pip", "ring_dip",
    "little_mcp_abd", "little_mcp_flex", "little_pip", "little_dip",
)  # fmt: skip

# 21 keypoints (MediaPipe order): wrist, then per finger thumb..little the four joints
# from base to tip (thumb: CMC, MCP, IP, TIP; fingers: MCP, PIP, DIP, TIP).
KEYPOINT_NAMES: tuple[str, ...] = ("wrist",) + tuple(
    f"{finger}_{joint}"
    for finger, joints in zip(FINGERS, [("cmc", "mcp", "ip", "tip")] + [("mcp", "pip", "dip", "tip")] * 4, strict=True)
    for joint in joints
)
FINGERTIP_KEYPOINTS: dict[str, int] = {f: KEYPOINT_NAMES.index(f"{f}_tip") for f in FINGERS}
