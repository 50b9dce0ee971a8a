"""Kinematic retargeting with the Dex Retargeting library: human wrist pose + keypoints -> LEAP
joint trajectories, one constrained optimisation per frame.

Frames. The human wrist frame (``schemas.glove.WRIST_FRAME``: +x to the fingers, +y to the thumb,
-z palmar) has the LEAP palm frame's axes. The robot is placed so that its palm frame takes the
human wrist frame's orientation and its wrist frame (the URDF root ``base``, dex-urdf's convention,
origin on the wrist edge of the palm) sits at the human wrist position. The robot palm origin (near
the index MCP) is therefore at ``PALM_IN_HUMAN_WRIST`` = (+0.098, +0.038, 0) m in the human wrist
frame: 98 mm towards the fingers and 38 mm towards the thumb (the base origin is mid-width of the
palm's wrist edge, at the palm frame's z = 0; the palm spans z -0.035..0.012). The robot wrist pose reported with
every frame is the world pose of that ``base`` frame, which is also the MJCF hand's ``wrist`` body
(``touch2robot.leap.mjcf``): the teachers' mocap target as it is.

Per frame: the human vectors (config: origin keypoint -> task keypoint, in the wrist frame) are
the targets of Dex Retargeting's ``VectorOptimizer`` (robot link vectors in the ``base`` frame,
Huber loss, ``scaling``, ``regulariser`` x |q - q_prev|^2, NLopt SLSQP, joint limits as bounds),
warm-started from the previous frame's solution (the first frame from the middle of the joint
ranges, re-solved until it settles). What this module adds around the library: exact joint-limit
bounds (the library widens them by 1e-3 rad), a per-frame status instead of the library's
print-and-continue on solver errors, the residual check, a time-aware low-pass filter, the
per-recording scaling from the measured hand length, and input validation.
"""

from __future__ import annotations

import math
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from touch2robot.geometry import quat_mul, quat_to_mat
from touch2robot.leap import JOINT_NAMES, hand_urdf
from touch2robot.leap import description as hd
from touch2robot.retarget.config import (
    FINGERTIP_KEYPOINTS,
    FINGERTIP_LINKS,
    LEAP_DEFAULT,
    N_KEYPOINTS,
    WRIST_KEYPOINT,
    RetargetConfig,
)

try:
    import nlopt
    from dex_retargeting.optimizer import VectorOptimizer
    from dex_retargeting.robot_wrapper import RobotWrapper
except ImportError as e:  # the library is the optional extra "retarget"
    raise ImportError(
        f"kinematic retargeting needs the 'retarget' extra (dex-retargeting): uv sync --all-extras ({e})"
    ) from e

# Per-frame status codes; every code but OK means the frame holds the previous solution.
OK, SOLVER_ERROR, NON_FINITE, RESIDUAL, INVALID_INPUT = 0, 1, 2, 3, 4
STATUS_NAMES: tuple[str, ...] = ("ok", "solver_error", "non_finite", "residual", "invalid_input")

# First-frame settling: re-solves until no joint moves more than SETTLE_TOL rad.
SETTLE_ROUNDS, SETTLE_TOL = 20, 1e-3

# Rotation taking palm-frame (= human wrist frame) coordinates to the robot base frame.
BASE_FROM_PALM = quat_to_mat(np.asarray(hd.PALM_IN_WRIST_QUAT))
_BASE_IN_PALM_QUAT = np.asarray(hd.PALM_IN_WRIST_QUAT) * np.array([1.0, -1.0, -1.0, -1.0])  # conjugate
PALM_IN_HUMAN_WRIST: np.ndarray = BASE_FROM_PALM.T @ np.asarray(hd.PALM_IN_WRIST_POS)
"""Robot palm origin in the human wrist frame (m): (0.098, 0.038, 0)."""

# Robot skeleton for drawings: the links of each finger from the palm to the tip.
SKELETON: dict[str, tuple[str, ...]] = {
    "thumb": ("palm", "th_mp", "th_bs", "th_px", "th_ds", "th_tip"),
    **{
        name: ("palm", f"{f}_bs", f"{f}_px", f"{f}_md", f"{f}_ds", f"{f}_tip")
        for name, f in (("index", "if"), ("middle", "mf"), ("ring", "rf"))
    },
}


class HandMotionError(ValueError):
    """Hand-motion input that cannot be retargeted; the message names the recording."""


@dataclass(frozen=True)
class HandMotion:
    """One recording's hand motion: ``t`` (T,) s, strictly increasing; ``keypoints`` (T, 21, 3)
    world, MediaPipe order; wrist pose ``wrist_pos`` (T, 3), ``wrist_quat`` (T, 4) (w, x, y, z)."""

    recording_id: str
    t: np.ndarray
    keypoints: np.ndarray
    wrist_pos: np.ndarray
    wrist_quat: np.ndarray


@dataclass(frozen=True)
class RetargetResult:
    """Per-frame output: ``joints`` (T, 16) rad in ``JOINT_NAMES`` order, ``status`` (T,) int8
    (``STATUS_NAMES``), ``residual`` (T, 4) m, distance of each robot fingertip (thumb, index,
    middle, ring) from its scaled human target in the wrist frame, ``wrist_pos``/``wrist_quat``
    the robot wrist (``base``) pose in the world, ``solve_time`` (T,) s, ``scaling`` the factor."""

    recording_id: str
    t: np.ndarray
    joints: np.ndarray
    status: np.ndarray
    residual: np.ndarray
    wrist_pos: np.ndarray
    wrist_quat: np.ndarray
    solve_time: np.ndarray
    scaling: float  # the human -> robot factor used for this recording

    @property
    def failed(self) -> np.ndarray:
        """Frames that hold the previous solution (status other than ok)."""
        return self.status != OK


def validate_hand_motion(
    recording_id: str,
    t: np.ndarray,
    keypoints: np.ndarray,
    wrist_pose: np.ndarray,
    max_gap_s: float = LEAP_DEFAULT.max_gap_s,
) -> HandMotion:
    """Check and shape raw hand-motion arrays: ``keypoints`` (T, 21, 3) or (T, 63), ``wrist_pose``
    (T, 7) as px, py, pz, qw, qx, qy, qz. Raises ``HandMotionError`` naming the recording."""

    def fail(why: str) -> HandMotionError:
        return HandMotionError(f"recording {recording_id}: {why}")

    t = np.asarray(t, dtype=np.float64)
    kp = np.asarray(keypoints, dtype=np.float64)
    pose = np.asarray(wrist_pose, dtype=np.float64)
    if t.ndim != 1 or t.size == 0:
        raise fail(f"no hand-motion frames (time stamps of shape {t.shape})")
    if kp.ndim == 2 and kp.shape[1] % 3 == 0:
        kp = kp.reshape(kp.shape[0], -1, 3)
    if kp.ndim != 3 or kp.shape[1:] != (N_KEYPOINTS, 3):
        raise fail(f"expected {N_KEYPOINTS} keypoints x 3 per frame, got keypoint array of shape {np.shape(keypoints)}")
    if pose.ndim != 2 or pose.shape[1] != 7:
        raise fail(f"expected a wrist pose (px, py, pz, qw, qx, qy, qz) per frame, got shape {pose.shape}")
    if not len(t) == len(kp) == len(pose):
        raise fail(f"frame counts differ: {len(t)} time stamps, {len(kp)} keypoint frames, {len(pose)} wrist poses")
    for name, arr in (("time", t), ("keypoints", kp), ("wrist pose", pose)):
        bad = ~np.isfinite(arr.reshape(len(arr), -1)).all(axis=1)
        if bad.any():
            i = int(np.argmax(bad))
            raise fail(f"non-finite {name} at frame {i} (t = {t[i]:.4f} s)")
    dt = np.diff(t)
    if (dt <= 0).any():
        i = int(np.argmax(dt <= 0))
        raise fail(f"time is not strictly increasing at frame {i + 1} (t = {t[i]:.4f} s then {t[i + 1]:.4f} s)")
    if (dt > max_gap_s).any():
        i = int(np.argmax(dt > max_gap_s))
        raise fail(f"missing frames: {dt[i]:.3f} s gap after t = {t[i]:.4f} s (more than {max_gap_s} s)")
    norm = np.linalg.norm(pose[:, 3:], axis=1)
    if (np.abs(norm - 1.0) > 0.05).any():
        i = int(np.argmax(np.abs(norm - 1.0) > 0.05))
        raise fail(f"wrist orientation at frame {i} is not a unit quaternion (norm {norm[i]:.3f})")
    return HandMotion(recording_id, t, kp, pose[:, :3], pose[:, 3:] / norm[:, None])


# The chain that measures hand length: wrist -> middle MCP -> PIP -> DIP -> tip (bone lengths do not
# change with the pose, so the median over frames is the tracker's estimate of the subject's hand).
HAND_LENGTH_CHAIN = (0, 9, 10, 11, 12)
PLAUSIBLE_HAND_LENGTH = (0.08, 0.35)  # m: outside, the keypoints are not in metres or not a hand


def hand_length(motion: HandMotion) -> float:
    """The subject's hand length (m): wrist to middle fingertip along the bones, median over frames."""
    chain = motion.keypoints[:, list(HAND_LENGTH_CHAIN)]
    length = float(np.median(np.linalg.norm(np.diff(chain, axis=1), axis=-1).sum(axis=1)))
    lo, hi = PLAUSIBLE_HAND_LENGTH
    if not lo <= length <= hi:
        raise HandMotionError(
            f"recording {motion.recording_id}: hand length {length:.3f} m from the keypoints is outside {lo}..{hi} m"
        )
    return length


def motion_scaling(motion: HandMotion, config: RetargetConfig) -> float:
    """The human -> robot factor for one recording (``config.scaling``, adjusted to the hand's size)."""
    if config.reference_hand_length is None:
        return config.scaling
    return config.scaling * config.reference_hand_length / hand_length(motion)


def keypoints_in_wrist(keypoints: np.ndarray, wrist_pos: np.ndarray, wrist_quat: np.ndarray) -> np.ndarray:
    """World keypoints (T, K, 3) in the human wrist frame of each frame."""
    rot = quat_to_mat(wrist_quat)
    return np.einsum("tji,tkj->tki", rot, keypoints - wrist_pos[:, None, :])


def robot_wrist_pose(wrist_pos: np.ndarray, wrist_quat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World pose of the robot wrist (``base``) frame for human wrist poses (T, 3), (T, 4): same
    origin, orientation such that the robot palm frame takes the human wrist frame's axes."""
    quat = quat_mul(np.asarray(wrist_quat), _BASE_IN_PALM_QUAT)
    return np.asarray(wrist_pos, dtype=np.float64).copy(), quat / np.linalg.norm(quat, axis=-1, keepdims=True)


class LeapKinematics:
    """The LEAP Hand URDF (``touch2robot.leap.hand_urdf``) loaded in Pinocchio through Dex
    Retargeting's ``RobotWrapper``. One per retargeter: Pinocchio's data is not thread-safe."""

    def __init__(self) -> None:
        # Pinocchio reads URDFs from files; the model needs the file only while loading.
        with tempfile.TemporaryDirectory(prefix="touch2robot-leap-") as tmp:
            path = Path(tmp) / "leap_hand_right.urdf"
            path.write_text(hand_urdf())
            self.robot = RobotWrapper(str(path))
        if tuple(self.robot.dof_joint_names) != JOINT_NAMES:
            raise RuntimeError(f"URDF joint order {self.robot.dof_joint_names} differs from {JOINT_NAMES}")
        self.lower, self.upper = self.robot.joint_limits.T.copy()
        self._tips = [self.robot.get_link_index(n) for n in FINGERTIP_LINKS]

    def link_positions(self, q: np.ndarray, links: list[int]) -> np.ndarray:
        """Positions (n, 3) of link frames in the base frame at joint angles ``q``."""
        self.robot.compute_forward_kinematics(np.asarray(q, dtype=np.float64))
        return np.stack([self.robot.get_link_pose(i)[:3, 3] for i in links])

    def tip_positions(self, q: np.ndarray) -> np.ndarray:
        """Fingertip positions (4, 3) in the base frame (thumb, index, middle, ring)."""
        return self.link_positions(q, self._tips)

    def skeleton(self, q: np.ndarray) -> dict[str, np.ndarray]:
        """Per finger, the link-frame positions (n, 3) from the palm to the tip, base frame."""
        return {
            f: self.link_positions(q, [self.robot.get_link_index(n) for n in names]) for f, names in SKELETON.items()
        }


class Retargeter:
    """Frame-by-frame retargeting with state: the previous solution is the next warm start."""

    def __init__(self, config: RetargetConfig = LEAP_DEFAULT) -> None:
        self.config = config
        self.kinematics = LeapKinematics()
        self.optimizer = VectorOptimizer(
            self.kinematics.robot,
            list(JOINT_NAMES),
            target_origin_link_names=list(config.origin_links),
            target_task_link_names=list(config.task_links),
            target_link_human_indices=np.array([config.origin_keypoints, config.task_keypoints]),
            huber_delta=config.huber_delta,
            norm_delta=config.regulariser,
            scaling=config.scaling,
        )
        opt = self.optimizer.opt
        opt.set_lower_bounds(self.kinematics.lower.tolist())
        opt.set_upper_bounds(self.kinematics.upper.tolist())
        opt.set_ftol_abs(config.ftol_abs)
        opt.set_maxeval(config.max_evaluations)
        self._origin = np.asarray(config.origin_keypoints)
        self._task = np.asarray(config.task_keypoints)
        self.reset()

    @property
    def middle(self) -> np.ndarray:
        """The middle of the joint ranges: the first frame's warm start."""
        return 0.5 * (self.kinematics.lower + self.kinematics.upper)

    @property
    def scaling(self) -> float:
        """The human -> robot factor of the current sequence."""
        return float(self.optimizer.scaling)

    def reset(self, scaling: float | None = None) -> None:
        """Forget the previous frames (start of a new sequence), with the sequence's factor
        (default ``config.scaling``)."""
        self.optimizer.scaling = self.config.scaling if scaling is None else scaling
        self._last = self.middle  # previous accepted (unfiltered) solution
        self._output: np.ndarray | None = None  # previous output (filtered)
        self._t: float | None = None

    def _solve(self, targets: np.ndarray) -> tuple[np.ndarray | None, int]:
        objective = self.optimizer.get_objective_function(targets, np.array([]), self._last.astype(np.float32))
        self.optimizer.opt.set_min_objective(objective)
        try:
            x = np.asarray(self.optimizer.opt.optimize(self._last.tolist()))
        except (RuntimeError, ValueError, nlopt.RoundoffLimited, nlopt.ForcedStop):
            return None, SOLVER_ERROR
        if not np.isfinite(x).all() or not math.isfinite(self.optimizer.opt.last_optimum_value()):
            return None, NON_FINITE
        # SLSQP may step a hair past a bound; the limits are hard
        return np.clip(x, self.kinematics.lower, self.kinematics.upper), OK

    def _settle(self, q: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """Re-solve the first frame from its own solution until it stops moving: from the middle
        of the ranges the regulariser holds the first solve back, and the rest of the way would
        otherwise show up as a start-up transient over the next frames. The re-solves only refine
        an accepted solution: one that fails ends the settling, keeping the last good solution."""
        for _ in range(SETTLE_ROUNDS):
            self._last = q
            nxt, _ = self._solve(targets)
            if nxt is None:
                break
            moved = np.abs(nxt - q).max()
            q = nxt
            if moved < SETTLE_TOL:
                break
        return q

    def step(self, keypoints_wrist: np.ndarray, t: float) -> tuple[np.ndarray, int, np.ndarray, float]:
        """Retarget one frame from keypoints (21, 3) in the human wrist frame at time ``t`` (s).
        Returns (joints (16,), status, fingertip residuals (4,) m, solve time s). A frame whose
        solve fails (bad input, solver error, non-finite result, residual above ``max_residual``)
        holds the previous output and carries the failure status."""
        tic = time.perf_counter()
        kp = np.asarray(keypoints_wrist, dtype=np.float64) @ BASE_FROM_PALM.T  # into base-frame axes
        tips_target = self.scaling * (kp[list(FINGERTIP_KEYPOINTS)] - kp[WRIST_KEYPOINT])
        targets = kp[self._task] - kp[self._origin]
        q, status = (None, INVALID_INPUT) if not np.isfinite(kp).all() else self._solve(targets)
        if q is not None and self._output is None:
            q = self._settle(q, targets)
        if (
            q is not None
            and np.linalg.norm(self.kinematics.tip_positions(q) - tips_target, axis=1).max() > self.config.max_residual
        ):
            q, status = None, RESIDUAL
        if q is not None:
            self._last = q
            out = self._filter(q, t)
        else:
            out = self._output if self._output is not None else self._last
        self._output, self._t = out, t
        residual = np.linalg.norm(self.kinematics.tip_positions(out) - tips_target, axis=1)
        return out.copy(), status, residual, time.perf_counter() - tic

    def _filter(self, q: np.ndarray, t: float) -> np.ndarray:
        cutoff = self.config.lowpass_cutoff_hz
        if cutoff is None or self._output is None or self._t is None:
            return q
        # first-order low-pass, exact for the actual frame interval (hand-tracker stamps jitter)
        alpha = 1.0 - math.exp(-2.0 * math.pi * cutoff * max(t - self._t, 0.0))
        return self._output + alpha * (q - self._output)


def retarget_motion(
    motion: HandMotion, config: RetargetConfig = LEAP_DEFAULT, retargeter: Retargeter | None = None
) -> RetargetResult:
    """Retarget a validated hand motion from its first frame. A given ``retargeter`` is reset and
    its own config is used (it saves loading the model per recording)."""
    rt = retargeter or Retargeter(config)
    scaling = motion_scaling(motion, rt.config)
    rt.reset(scaling)  # a new sequence starts from the middle of the joint ranges
    local = keypoints_in_wrist(motion.keypoints, motion.wrist_pos, motion.wrist_quat)
    n = len(motion.t)
    joints, residual = np.empty((n, len(JOINT_NAMES))), np.empty((n, len(FINGERTIP_LINKS)))
    status, solve_time = np.empty(n, dtype=np.int8), np.empty(n)
    for i in range(n):
        joints[i], status[i], residual[i], solve_time[i] = rt.step(local[i], float(motion.t[i]))
    pos, quat = robot_wrist_pose(motion.wrist_pos, motion.wrist_quat)
    return RetargetResult(
        motion.recording_id, motion.t.copy(), joints, status, residual, pos, quat, solve_time, scaling
    )


def retarget_sequence(
    keypoints: np.ndarray,
    wrist_pose: np.ndarray,
    t: np.ndarray,
    *,
    recording_id: str = "<arrays>",
    config: RetargetConfig | None = None,
    retargeter: Retargeter | None = None,
) -> RetargetResult:
    """Retarget one recording's hand motion: ``keypoints`` (T, 21, 3) or (T, 63) in the world,
    ``wrist_pose`` (T, 7) px, py, pz, qw, qx, qy, qz (human wrist frame in the world), ``t`` (T,)
    s. Bad input raises ``HandMotionError`` naming ``recording_id``. Pass a ``retargeter`` to
    reuse its loaded model across recordings (it is reset first; its config is the one used)."""
    if retargeter is not None and config is not None and retargeter.config != config:
        raise ValueError("retarget_sequence: the retargeter was built with a different config")
    config = retargeter.config if retargeter is not None else config or LEAP_DEFAULT
    motion = validate_hand_motion(recording_id, t, keypoints, wrist_pose, config.max_gap_s)  # before loading the model
    return retarget_motion(motion, config, retargeter)
