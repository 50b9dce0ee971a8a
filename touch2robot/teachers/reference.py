"""What a teacher tracks: one human demonstration resampled onto the 20 Hz control grid.

From the lake rows of one ingested glove session: the kinematic retargeting (LEAP joints and the
robot wrist pose, table ``retargeted``), the object trajectory (``object_pose``), the human's
aligned tactile preference over the eight robot-paired regions (``contacts``, source human) and,
for ConTrack / DexMachina, contact references derived from geometry alone (``hand_keypoints``
against the object's surface; see ``geometric_contacts``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from schemas.glove import KEYPOINT_NAMES
from schemas.tables import ROBOT_REGIONS
from schemas.vocabulary import Source
from touch2robot import lake as lake_io
from touch2robot import scenes
from touch2robot.geometry import body_sdf, inverse_transform_points


class ReferenceError(ValueError):
    """A demonstration that cannot be tracked; the message names the recording and the table."""


@dataclass(frozen=True)
class DemoReference:
    """A demonstration on the control grid: frame k is at ``t_ref[k]`` (reference clock)."""

    recording_id: str
    task: str
    subject: str
    t_ref: np.ndarray  # (T,) s on the glove recording's clock
    joints: np.ndarray  # (T, 16) kinematic retargeting, LEAP_JOINT_NAMES order
    wrist_pos: np.ndarray  # (T, 3) robot wrist (mocap) target in the world
    wrist_quat: np.ndarray  # (T, 4)
    object_pos: np.ndarray  # (T, 3) object body in the world
    object_quat: np.ndarray  # (T, 4)
    drawer_opening: np.ndarray  # (T,) slide travel (m); zeros for free objects
    preference: np.ndarray  # (T, 8) bool: the human's aligned contact per robot region (ROBOT_REGIONS)
    geo_contact: np.ndarray  # (T, 8) bool: geometry-derived contact per region (ConTrack)
    geo_point: np.ndarray  # (T, 8, 3) closest object-surface point in the object frame (NaN where no contact)

    @property
    def length(self) -> int:
        return len(self.t_ref)


def _read(lake: Path, table: str, recording_id: str, partition: dict[str, str] | None = None) -> pa.Table:
    path = lake_io.file_path(lake, table, recording_id, partition)
    if not path.is_file():
        raise ReferenceError(f"recording {recording_id}: no rows in table {table!r} ({path})")
    return pq.read_table(path)


def _matrix(table, column: str) -> np.ndarray:
    col = table[column].combine_chunks()
    return col.flatten().to_numpy(zero_copy_only=False).reshape(len(col), -1).astype(np.float64)


def _pose(table) -> tuple[np.ndarray, np.ndarray]:
    pos = np.stack([table[c].to_numpy() for c in ("px", "py", "pz")], axis=1)
    quat = np.stack([table[c].to_numpy() for c in ("qw", "qx", "qy", "qz")], axis=1)
    return pos.astype(np.float64), quat.astype(np.float64)


def _interp(t: np.ndarray, ts: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Linear interpolation of each column of ``values`` (len(ts), d) at times ``t``."""
    return np.stack([np.interp(t, ts, values[:, j]) for j in range(values.shape[1])], axis=1)


def _interp_quat(t: np.ndarray, ts: np.ndarray, quat: np.ndarray) -> np.ndarray:
    """Normalised linear interpolation after making neighbouring quaternions share a hemisphere
    (indistinguishable from slerp between samples at the tracker's rates)."""
    q = quat.copy()
    flip = np.cumprod(np.where(np.sum(q[1:] * q[:-1], axis=1) < 0, -1.0, 1.0))
    q[1:] *= flip[:, None]
    out = _interp(t, ts, q)
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def _asof(t: np.ndarray, ts: np.ndarray, values: np.ndarray) -> np.ndarray:
    """The last sample at or before each ``t`` (the metrics' backward ASOF alignment)."""
    idx = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, len(ts) - 1)
    return values[idx]


# Human hand points standing for each robot region (MediaPipe keypoint names): fingertip regions
# are the distal segments; palm regions are the palm's four quadrants, spanned by the knuckles
# and the wrist (P1 below index/middle, P2 below ring/little, P3 thenar, P4 hypothenar).
REGION_SEGMENTS: dict[str, tuple[str, str]] = {
    "T1": ("thumb_ip", "thumb_tip"),
    "T2": ("index_dip", "index_tip"),
    "T3": ("middle_dip", "middle_tip"),
    "T4": ("ring_dip", "ring_tip"),
    "P1": ("index_mcp", "middle_mcp"),
    "P2": ("ring_mcp", "little_mcp"),
    "P3": ("thumb_cmc", "wrist"),
    "P4": ("little_mcp", "wrist"),
}
# Half-thickness of the human finger / palm around the keypoint axis (m): a segment touches the
# object when its axis comes within this plus the 5 mm margin of the surface.
SEGMENT_RADIUS_M = {"T": 0.008, "P": 0.012}
SEGMENT_SAMPLES = 5


def geometric_contacts(
    task: str, keypoints: np.ndarray, object_pos: np.ndarray, object_quat: np.ndarray, margin_m: float = 0.005
) -> tuple[np.ndarray, np.ndarray]:
    """ConTrack's contact references from geometry alone: per frame and region, whether the human
    hand segment of that region lies inside or within ``margin_m`` of the object surface, and the
    closest object-surface point to it in the object frame (NaN where no contact).

    ``keypoints`` (T, 21, 3) world, ``object_pos`` (T, 3), ``object_quat`` (T, 4).
    Palm segments are shifted to the palmar skin (the keypoints are joint centres): by the palm's
    half thickness along the palm normal, estimated per frame from wrist and knuckles."""
    spec = scenes.get(task)
    names = list(KEYPOINT_NAMES)
    T = len(keypoints)
    s = np.linspace(0.0, 1.0, SEGMENT_SAMPLES)
    # palm normal (palmar side) from the wrist -> index knuckle and wrist -> little knuckle vectors
    wrist, index_mcp, pinky_mcp = (keypoints[:, names.index(n)] for n in ("wrist", "index_mcp", "little_mcp"))
    normal = np.cross(index_mcp - wrist, pinky_mcp - wrist)  # right hand: out of the palm (palmar side)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True) + 1e-12
    contact = np.zeros((T, len(ROBOT_REGIONS)), dtype=bool)
    point = np.full((T, len(ROBOT_REGIONS), 3), np.nan)
    for r, region in enumerate(ROBOT_REGIONS):
        a, b = (keypoints[:, names.index(n)] for n in REGION_SEGMENTS[region])
        pts = a[:, None, :] + s[None, :, None] * (b - a)[:, None, :]  # (T, S, 3)
        radius = SEGMENT_RADIUS_M[region[0]]
        if region.startswith("P"):
            pts = pts + radius * normal[:, None, :]
            radius = 0.0  # now on the skin
        local = inverse_transform_points(pts, object_pos, object_quat)
        d = body_sdf(spec.object.geoms, local.reshape(-1, 3)).reshape(T, SEGMENT_SAMPLES) - radius
        best = np.argmin(d, axis=1)
        hit = d[np.arange(T), best] <= margin_m
        contact[:, r] = hit
        if hit.any():
            p = local[np.arange(T), best][hit]
            point[hit, r] = _project_to_surface(spec.object.geoms, p)
    return contact, point


def _project_to_surface(geoms, p: np.ndarray, eps: float = 1e-4, iterations: int = 4) -> np.ndarray:
    """The closest surface point to each point: repeated p - sdf(p) grad sdf(p) steps (central
    differences; a few steps settle points near edges and corners, where the gradient jumps)."""
    for _ in range(iterations):
        grad = np.zeros_like(p)
        for i in range(3):
            e = np.zeros(3)
            e[i] = eps
            grad[:, i] = (body_sdf(geoms, p + e) - body_sdf(geoms, p - e)) / (2 * eps)
        grad /= np.linalg.norm(grad, axis=1, keepdims=True) + 1e-12
        p = p - body_sdf(geoms, p)[:, None] * grad
    return p


def load_reference(
    lake: Path, recording: dict, control_hz: float = 20.0, contact_margin_m: float = 0.005
) -> DemoReference:
    """One ingested glove session as a teacher reference on the control grid (``control_hz``),
    from its first to its last frame that every stream covers. Frames whose retargeting failed
    hold the previous solution (the retargeter's own rule)."""
    lake = Path(lake)
    rid, task = recording["recording_id"], recording["task"]
    if task not in scenes.REGISTRY:
        raise ReferenceError(f"recording {rid}: unknown task {task!r}")
    ret = _read(lake, "retargeted", rid)
    obj = _read(lake, "object_pose", rid)
    kp = _read(lake, "hand_keypoints", rid)
    human = _read(lake, "contacts", rid, {"source": Source.HUMAN, "task": task})
    t_ret, t_obj, t_kp = ret["t"].to_numpy(), obj["t"].to_numpy(), kp["t"].to_numpy()
    t_con = np.unique(human["t"].to_numpy())
    for name, ts in (("retargeted", t_ret), ("object_pose", t_obj), ("hand_keypoints", t_kp), ("contacts", t_con)):
        if len(ts) < 2:
            raise ReferenceError(f"recording {rid}: table {name!r} has {len(ts)} rows, need at least 2")
    start = max(t_ret[0], t_obj[0], t_kp[0], t_con[0])
    end = min(t_ret[-1], t_obj[-1], t_kp[-1], t_con[-1])
    if end - start < 2.0 / control_hz:
        raise ReferenceError(f"recording {rid}: the streams overlap for {max(end - start, 0):.3f} s only")
    t = start + np.arange(int(np.floor((end - start) * control_hz)) + 1) / control_hz

    joints = _interp(t, t_ret, _matrix(ret, "position"))
    wrist_pos, wrist_quat = _pose(ret)
    opos, oquat = _pose(obj)
    object_pos, object_quat = _interp(t, t_obj, opos), _interp_quat(t, t_obj, oquat)
    for name, values in (
        ("retargeted.position", joints),
        ("object_pose", object_pos),
        ("object_pose quaternion", object_quat),
    ):
        if not np.isfinite(values).all():
            raise ReferenceError(f"recording {rid}: non-finite values in {name}")

    # human preference: long rows (t, region, contact) -> (len(t_con), 8), then ASOF onto the grid
    pref = np.zeros((len(t_con), len(ROBOT_REGIONS)), dtype=bool)
    rows_t = np.searchsorted(t_con, human["t"].to_numpy())
    region_idx = {r: i for i, r in enumerate(ROBOT_REGIONS)}
    cols = np.array([region_idx.get(r, -1) for r in human["region"].to_pylist()])
    ok = cols >= 0
    pref[rows_t[ok], cols[ok]] = human["contact"].to_numpy(zero_copy_only=False)[ok]

    spec = scenes.get(task)
    if spec.slide is not None:
        axis = np.asarray(spec.slide.axis, dtype=np.float64)
        opening = np.clip((object_pos - np.asarray(spec.object.init_pos)) @ axis, *spec.slide.range)
    else:
        opening = np.zeros(len(t))

    keypoints = _interp(t, t_kp, _matrix(kp, "xyz")).reshape(len(t), len(KEYPOINT_NAMES), 3)
    geo_contact, geo_point = geometric_contacts(task, keypoints, object_pos, object_quat, contact_margin_m)
    return DemoReference(
        recording_id=rid,
        task=task,
        subject=str(recording.get("subject") or ""),
        t_ref=t,
        joints=joints,
        wrist_pos=_interp(t, t_ret, wrist_pos),
        wrist_quat=_interp_quat(t, t_ret, wrist_quat),
        object_pos=object_pos,
        object_quat=object_quat,
        drawer_opening=opening,
        preference=_asof(t, t_con, pref),
        geo_contact=geo_contact,
        geo_point=geo_point,
    )
