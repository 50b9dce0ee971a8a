"""Configuration of kinematic retargeting (human hand motion -> LEAP joint trajectories).

The objective is Dex Retargeting's *vector* formulation: for every pair (robot origin link,
robot task link) <-> (human origin keypoint, human task keypoint) the robot vector between the
two links, in the robot wrist frame, should equal ``scaling`` times the human vector between the
two keypoints, in the human wrist frame, under a Huber loss; plus ``regulariser`` times the
squared change from the previous frame's solution. The defaults (``LEAP_DEFAULT``) are the
wrist-to-fingertip vectors of the four robot fingers (thumb, index, middle, ring), which, with
the robot wrist placed on the human wrist, makes them fingertip-position objectives in the
wrist frame. The human little finger has no LEAP counterpart and is not used.
"""

from __future__ import annotations

from pathlib import Path

import yaml
from pydantic import BaseModel, ConfigDict, Field, model_validator

from schemas.glove import KEYPOINT_NAMES

N_KEYPOINTS = len(KEYPOINT_NAMES)

# Robot fingertip links (the URDF's fixed tip links) in the order of the robot fingertip regions
# T1..T4 and the human keypoints they follow (MediaPipe indices: thumb, index, middle, ring tip).
FINGERTIP_LINKS: tuple[str, ...] = ("th_tip", "if_tip", "mf_tip", "rf_tip")
FINGERTIP_KEYPOINTS: tuple[int, ...] = tuple(
    KEYPOINT_NAMES.index(f"{f}_tip") for f in ("thumb", "index", "middle", "ring")
)
WRIST_LINK = "base"  # the URDF root: dex-urdf's wrist frame, origin on the wrist edge of the palm
WRIST_KEYPOINT = KEYPOINT_NAMES.index("wrist")


class RetargetConfig(BaseModel):
    """Objective, solver and input checks of the retargeter (lengths in m, times in s)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    origin_links: tuple[str, ...] = (WRIST_LINK,) * 4
    task_links: tuple[str, ...] = FINGERTIP_LINKS
    origin_keypoints: tuple[int, ...] = (WRIST_KEYPOINT,) * 4
    task_keypoints: tuple[int, ...] = FINGERTIP_KEYPOINTS
    # LEAP wrist edge to middle fingertip 0.230 m (open hand) over the same span of a mid-sized
    # adult hand (~0.20 m); measured on the demonstrator: 1.1 leaves the fingers short of their
    # targets, 1.25 and above the thumb (mean fingertip residual 2.1 mm at 1.15, 3.3 mm at 1.2).
    scaling: float = Field(
        default=1.15, gt=0, description="robot vector = scaling x human vector (the LEAP Hand is larger)"
    )
    # Hands differ by +-10 % or more; with one fixed factor a large hand asks for fingertips beyond
    # the LEAP's reach (demonstrator: mean residual 7 mm for a 1.07 hand vs 1 mm for a 0.92 one).
    reference_hand_length: float | None = Field(
        default=0.2,
        gt=0,
        description="hand length (m, wrist -> middle MCP -> middle tip along the bones, median over the recording) "
        "for which `scaling` holds; a recording's factor is scaling x reference / its hand length. "
        "None: `scaling` for every hand",
    )
    huber_delta: float = Field(default=0.02, gt=0, description="Huber (smooth-L1) transition, m of vector error")
    regulariser: float = Field(
        default=4e-3, ge=0, description="weight of |q - q_previous|^2 (Dex Retargeting's norm_delta)"
    )
    # 10 Hz keeps human finger motion (a few Hz) and halves the tracker jitter in the joints
    lowpass_cutoff_hz: float | None = Field(
        default=10.0, gt=0, description="first-order low-pass on the output joints; None: off"
    )
    ftol_abs: float = Field(default=1e-6, gt=0, description="SLSQP absolute tolerance on the objective")
    max_evaluations: int = Field(default=500, ge=10, description="objective evaluations per frame before SLSQP stops")
    max_residual: float = Field(
        default=0.08, gt=0, description="a fingertip farther than this from its target is a failed frame"
    )
    max_gap_s: float = Field(default=0.25, gt=0, description="a longer gap between hand-motion frames is missing data")
    time_tolerance_s: float = Field(
        default=1e-3, ge=0, description="keypoints and wrist pose of a frame must share its time"
    )

    @model_validator(mode="after")
    def _pairs(self) -> RetargetConfig:
        n = len(self.task_links)
        if n == 0 or not (len(self.origin_links) == len(self.origin_keypoints) == len(self.task_keypoints) == n):
            raise ValueError(
                "origin_links, task_links, origin_keypoints and task_keypoints must be non-empty and of equal length"
            )
        bad = [k for k in (*self.origin_keypoints, *self.task_keypoints) if not 0 <= k < N_KEYPOINTS]
        if bad:
            raise ValueError(f"keypoint indices must lie in 0..{N_KEYPOINTS - 1}, got {bad}")
        if any(o == t for o, t in zip(self.origin_links, self.task_links, strict=True)):
            raise ValueError("an objective vector needs two different links")
        return self

    @classmethod
    def from_yaml(cls, path: str | Path) -> RetargetConfig:
        """A configuration from a YAML mapping of the fields above (unknown keys are errors)."""
        return cls.model_validate(yaml.safe_load(Path(path).read_text()) or {})

    def to_yaml(self) -> str:
        """The configuration as YAML (the format ``from_yaml`` and profile sections read)."""
        return yaml.safe_dump(self.model_dump(mode="json"), sort_keys=False)


LEAP_DEFAULT = RetargetConfig()
"""The default for the right LEAP Hand; ``leap.yaml`` beside this file is the same as YAML."""
