"""Lake input and output of retargeting: a glove recording's ``hand_keypoints`` + ``wrist_pose``
rows in, its ``retargeted`` rows out (the retarget task writes them: ``touch2robot.datasets.RETARGETED``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from touch2robot.datasets import LAKE, RecordingKey
from touch2robot.retarget.config import LEAP_DEFAULT, RetargetConfig
from touch2robot.retarget.retargeter import (
    STATUS_NAMES,
    HandMotion,
    HandMotionError,
    RetargetResult,
    validate_hand_motion,
)

POSE_COLUMNS = ("px", "py", "pz", "qw", "qx", "qy", "qz")


def load_hand_motion(lake: Path, recording_id: str, config: RetargetConfig = LEAP_DEFAULT) -> HandMotion:
    """The validated hand motion of one ingested glove recording. Keypoints and wrist pose are
    paired frame by frame: the tracker stamps both with the frame's time, so they must have the
    same frames (within ``config.time_tolerance_s``); anything else is an error naming the recording."""
    paths = {name: LAKE[name].path(lake, RecordingKey(recording_id)) for name in ("hand_keypoints", "wrist_pose")}
    missing = [name for name, p in paths.items() if not p.is_file()]
    if missing:
        raise HandMotionError(f"recording {recording_id}: no {' or '.join(missing)} rows in the lake")
    kp = pq.read_table(paths["hand_keypoints"], columns=["t", "xyz"])
    wp = pq.read_table(paths["wrist_pose"], columns=["t", *POSE_COLUMNS])
    t_kp, t_wp = kp["t"].to_numpy(), wp["t"].to_numpy()
    if len(t_kp) != len(t_wp):
        raise HandMotionError(f"recording {recording_id}: {len(t_kp)} keypoint frames but {len(t_wp)} wrist poses")
    off = np.abs(t_kp - t_wp)
    if len(off) and off.max() > config.time_tolerance_s:
        i = int(np.argmax(off))
        raise HandMotionError(
            f"recording {recording_id}: keypoints at t = {t_kp[i]:.4f} s but wrist pose at {t_wp[i]:.4f} s (frame {i})"
        )
    xyz = kp["xyz"].combine_chunks()
    width = xyz.type.list_size if pa.types.is_fixed_size_list(xyz.type) else 0
    keypoints = xyz.flatten().to_numpy(zero_copy_only=False).reshape(len(t_kp), width)
    pose = np.stack([wp[c].to_numpy(zero_copy_only=False) for c in POSE_COLUMNS], axis=1).astype(np.float64)
    return validate_hand_motion(recording_id, t_kp, keypoints, pose, config.max_gap_s)


def result_rows(result: RetargetResult) -> pa.Table:
    """The rows of the ``retargeted`` table for one result."""
    n = len(result.t)

    def fixed(values: np.ndarray) -> pa.FixedSizeListArray:
        values = np.ascontiguousarray(values, dtype=np.float32)
        return pa.FixedSizeListArray.from_arrays(pa.array(values.reshape(-1)), values.shape[1])

    return pa.table(
        {
            "recording_id": pa.array([result.recording_id] * n, pa.string()),
            "t": result.t,
            "position": fixed(result.joints),
            "status": pa.array(np.asarray(STATUS_NAMES)[result.status], pa.string()),
            "residual": fixed(result.residual),
            **{c: result.wrist_pos[:, i] for i, c in enumerate(POSE_COLUMNS[:3])},
            **{c: result.wrist_quat[:, i] for i, c in enumerate(POSE_COLUMNS[3:])},
        }
    )
