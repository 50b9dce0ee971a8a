"""Turning a decoded recording into rows of the lake's stream tables."""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from touch2robot.ingest.reader import DecodedRecording
from touch2robot.recording.cdr import Batch


def _fixed_list(values: np.ndarray, dtype: pa.DataType) -> pa.FixedSizeListArray:
    values = np.ascontiguousarray(values, dtype=dtype.to_pandas_dtype())
    return pa.FixedSizeListArray.from_arrays(pa.array(values.reshape(-1), type=dtype), values.shape[1])


def _base(rec: DecodedRecording, batch: Batch) -> dict[str, pa.Array]:
    n = len(batch.stamp_ns)
    return {
        "recording_id": pa.array([rec.recording_id] * n, pa.string()),
        "t": pa.array((batch.stamp_ns - rec.start_ns) / 1e9, pa.float64()),
    }


def _pose_columns(pose: np.ndarray) -> dict[str, np.ndarray]:
    # geometry_msgs/Pose order: x y z qx qy qz qw
    return {
        "px": pose[:, 0],
        "py": pose[:, 1],
        "pz": pose[:, 2],
        "qw": pose[:, 6],
        "qx": pose[:, 3],
        "qy": pose[:, 4],
        "qz": pose[:, 5],
    }


def stream_tables(rec: DecodedRecording) -> dict[str, pa.Table]:
    """One table per contract topic of the recording, keyed by lake table name."""
    out: dict[str, pa.Table] = {}
    for topic in rec.rig.topics(rec.kind):
        batch = rec.topics[topic.name]
        cols = _base(rec, batch)
        f = batch.fields
        n = len(batch.stamp_ns)
        if topic.table in ("taxels", "twintac", "fsr"):
            cols["values"] = _fixed_list(f["values"], pa.float32())
        elif topic.table in ("hand_joints", "robot_joint_targets"):
            cols["position"] = _fixed_list(f["position"], pa.float32())
        elif topic.table == "robot_joint_states":
            width = f["position"].shape[1]  # the contract's array_len, checked when the recording was read
            for name in ("position", "velocity", "effort"):
                v = f[name] if f[name].shape[1] else np.full((n, width), np.nan)
                cols[name] = _fixed_list(v, pa.float32())
        elif topic.table == "hand_keypoints":
            xyz = f["poses"].reshape(n, -1, 7)[:, :, :3].reshape(n, -1)
            cols["xyz"] = _fixed_list(xyz, pa.float32())
        elif topic.table in ("wrist_pose", "object_pose"):
            cols.update({k: pa.array(v) for k, v in _pose_columns(f["pose"]).items()})
        elif topic.table == "time_map":
            cols["t_ref"] = pa.array(f["reference_time"][:, 0], pa.float64())
        else:
            raise KeyError(f"no row builder for table {topic.table!r}")
        out[topic.table] = pa.table(cols)
    return out
