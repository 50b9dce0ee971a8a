"""A drawing of retargeting quality: the scaled human hand (the targets) and the LEAP Hand
(forward kinematics of the result) side by side in the wrist frame, for a few frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from schemas.glove import FINGERS
from touch2robot.retarget.retargeter import (
    BASE_FROM_PALM,
    HandMotion,
    LeapKinematics,
    RetargetResult,
    keypoints_in_wrist,
)

FINGER_COLOURS = {"thumb": "C0", "index": "C1", "middle": "C2", "ring": "C3", "little": "C7"}


def comparison_png(
    motion: HandMotion, result: RetargetResult, path: Path, frames: int = 4, kinematics: LeapKinematics | None = None
) -> Path:
    """Save a PNG of ``frames`` frames from open to closed hand: human keypoints scaled about the wrist (dashed,
    circles) and the robot's links and fingertips (solid, crosses), both in the human wrist frame
    (x to the fingers, y to the thumb, z back of the hand)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kin = kinematics or LeapKinematics()
    scaling = result.scaling
    local = scaling * keypoints_in_wrist(motion.keypoints, motion.wrist_pos, motion.wrist_quat)
    # frames spread over the hand's closure (mean wrist-to-fingertip distance), open to closed
    closure = np.linalg.norm(local[:, [4, 8, 12, 16]], axis=-1).mean(axis=1)
    order = np.argsort(-closure)
    picks = order[np.linspace(0, len(order) - 1, frames).round().astype(int)]
    fig = plt.figure(figsize=(4.2 * frames, 4.6))
    for k, i in enumerate(picks):
        ax = fig.add_subplot(1, frames, k + 1, projection="3d")
        kp = local[i]
        for f, finger in enumerate(FINGERS):
            chain = kp[[0, *range(1 + 4 * f, 5 + 4 * f)]]
            ax.plot(*chain.T, "--o", color=FINGER_COLOURS[finger], ms=2.5, lw=1.0, alpha=0.8)
        for finger, chain in kin.skeleton(result.joints[i]).items():
            pts = chain @ BASE_FROM_PALM  # base-frame points into the wrist (palm-axes) frame
            ax.plot(*pts.T, "-", color=FINGER_COLOURS[finger], lw=2.2)
            ax.plot(*pts[-1], "x", color="k", ms=6)
        ax.plot([0.0], [0.0], [0.0], "ks", ms=4)  # the wrist
        ax.set_title(
            f"t = {result.t[i]:.2f} s\nmean tip residual {1e3 * np.nanmean(result.residual[i]):.1f} mm", fontsize=9
        )
        # equal scales on the three axes around this frame's points, so that lengths compare
        centre = 0.5 * (kp.min(axis=0) + kp.max(axis=0))
        for lim, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre, strict=True):
            lim(c - 0.13, c + 0.13)
        ax.set_box_aspect((1.0, 1.0, 1.0))
        ax.view_init(elev=20, azim=-60)
        ax.tick_params(labelsize=6)
    fig.suptitle(f"{result.recording_id}: human x {scaling:.3f} (dashed) vs LEAP (solid), wrist frame (m)", fontsize=10)
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 0.9))  # room for the suptitle
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path
