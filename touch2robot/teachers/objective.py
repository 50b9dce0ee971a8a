"""The teachers' objective: follow one human demonstration per episode, for every method.

Each copy of the batched env samples a demonstration of the task and starts from its first frame
(hand at the kinematic retargeting, object at its recorded pose). Per control step:

- **Action** (22): residuals around the kinematic reference, all in [-1, 1]: 16 joint targets,
  q = q_ref(k+1) + ``action_scale`` x a[:16], and the wrist (the mocap arm) shifted by
  ``wrist_pos_scale_m`` x a[16:19] (world) and turned by ``wrist_rot_scale_rad`` x a[19:22] (axis x
  angle in the wrist frame). The wrist residual closes the embodiment gap the kinematic retargeting
  leaves (the LEAP hand is larger than a human hand, so at the human's wrist pose its fingertips
  land beyond the object); the teacher learns where to put the hand, not just how to close it.
- **Observation** (actor = critic): hand state, the next two reference frames relative to it, the
  object's pose and its next reference, the eight region forces, the contact reference of the method
  (the human's tactile preference for touch2robot; geometric contact flags and the offsets from each
  region to its contact point for ConTrack and DexMachina), the previous action and the phase.
- **Reward**: named weighted terms (``RewardWeights``), each logged alone; early termination when
  the object's tracking is lost. ConTrack rescales task and style by its per-clip dual variable;
  DexMachina adds the virtual object assistance (a decaying PD pull on the object).
"""

from __future__ import annotations

from collections import deque
from pathlib import Path
from typing import NamedTuple

import numpy as np

from touch2robot.geometry import quat_angle, quat_conj, quat_from_rotvec, quat_mul, quat_to_mat, rotvec
from touch2robot.sim.env import BatchEnv
from touch2robot.teachers.config import MethodConfig, TeacherConfig
from touch2robot.teachers.reference import DemoReference, load_reference

GRAVITY = 9.81
JOINT_ACTIONS = slice(0, 16)
WRIST_POS_ACTIONS = slice(16, 19)
WRIST_ROT_ACTIONS = slice(19, 22)
NUM_ACTIONS = 22


class References(NamedTuple):
    """All demonstrations of a task stacked and padded to the longest (padding repeats the last frame)."""

    ids: tuple[str, ...]
    subjects: tuple[str, ...]
    length: np.ndarray  # (D,)
    t_ref: np.ndarray  # (D, T)
    joints: np.ndarray  # (D, T, 16)
    wrist_pos: np.ndarray  # (D, T, 3)
    wrist_quat: np.ndarray  # (D, T, 4)
    object_pos: np.ndarray  # (D, T, 3)
    object_quat: np.ndarray  # (D, T, 4)
    opening: np.ndarray  # (D, T)
    preference: np.ndarray  # (D, T, 8) bool
    geo_contact: np.ndarray  # (D, T, 8) bool
    geo_point: np.ndarray  # (D, T, 8, 3) object frame, 0 where no contact


def stack_references(refs: list[DemoReference]) -> References:
    """Pad and stack a task's demonstrations (all of the same task)."""
    if not refs:
        raise ValueError("no demonstrations to track")
    tasks = {r.task for r in refs}
    if len(tasks) != 1:
        raise ValueError(f"demonstrations of several tasks given together: {sorted(tasks)}")
    T = max(r.length for r in refs)

    def pad(get) -> np.ndarray:
        arrays = [get(r) for r in refs]
        return np.stack([np.concatenate([a, np.repeat(a[-1:], T - len(a), axis=0)]) for a in arrays])

    return References(
        ids=tuple(r.recording_id for r in refs),
        subjects=tuple(r.subject for r in refs),
        length=np.array([r.length for r in refs]),
        t_ref=pad(lambda r: r.t_ref),
        joints=pad(lambda r: r.joints),
        wrist_pos=pad(lambda r: r.wrist_pos),
        wrist_quat=pad(lambda r: r.wrist_quat),
        object_pos=pad(lambda r: r.object_pos),
        object_quat=pad(lambda r: r.object_quat),
        opening=pad(lambda r: r.drawer_opening),
        preference=pad(lambda r: r.preference),
        geo_contact=pad(lambda r: r.geo_contact),
        geo_point=pad(lambda r: np.nan_to_num(r.geo_point)),
    )


def load_references(lake: Path, recordings: list[dict], config: TeacherConfig) -> References:
    """The demonstrations ``recordings`` (``recordings`` rows of one task) on the control grid of
    ``config.sim``, stacked as the teachers track them."""
    hz = config.sim.control_hz
    return stack_references([load_reference(lake, r, hz, config.contact_margin_m) for r in recordings])


def step_f1(sim: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """(N,) F1 of the 8 sim contacts against the reference at one step; 1 when both are empty."""
    tp = np.sum(sim & ref, axis=1)
    wrong = np.sum(sim ^ ref, axis=1)
    return np.where(tp + wrong == 0, 1.0, 2.0 * tp / np.maximum(2.0 * tp + wrong, 1))


class DemoTracking:
    """The rsl-rl Objective of a teacher of one task and method (see the module docstring)."""

    num_actions = NUM_ACTIONS

    def __init__(self, refs: References, config: TeacherConfig, method: str) -> None:
        self.refs = refs
        self.cfg = config
        self.method_name = method
        self.method: MethodConfig = config.method(method)
        self.w = self.method.rewards
        self.demo = np.zeros(0, dtype=np.int64)
        self.prev_action = np.zeros((0, NUM_ACTIONS))
        self.task_return = np.zeros(0)
        # ConTrack: per-clip best task return and dual variable
        self.best_task = np.full(len(refs.ids), -np.inf)
        self.dual = np.full(len(refs.ids), self.method.contrack.lambda_init)
        # DexMachina: gain of the virtual object assistance and the recent episodes' task reward
        self.assist_gain = 1.0 if self.method.assistance.enabled else 0.0
        self._recent_task: deque[float] = deque(maxlen=self.method.assistance.window_episodes)
        self.eval_demos: np.ndarray | None = None  # rollouts: which demonstration each copy follows
        self._kp: np.ndarray | None = None
        self._last_terms: dict[str, np.ndarray] = {}

    @property
    def uses_preference(self) -> bool:
        """Whether the contact reference observed is the human's tactile preference (touch2robot)
        rather than the geometric contacts (contrack, dexmachina)."""
        return self.w.tactile > 0 or self.w.contact == 0

    # ------------------------------------------------------------------ reference lookups
    def frame(self, env: BatchEnv, offset: int = 0) -> np.ndarray:
        """(N,) reference frame index ``offset`` steps after each copy's current step (clamped)."""
        return np.minimum(env.time_step + offset, self.refs.length[self.demo] - 1)

    def _ref(self, name: str, env: BatchEnv, offset: int = 0) -> np.ndarray:
        return getattr(self.refs, name)[self.demo, self.frame(env, offset)]

    # ------------------------------------------------------------------ Objective protocol
    def reset(self, env: BatchEnv, ids: np.ndarray, rng: np.random.Generator) -> None:
        """Copies ``ids`` start a (sampled, or in rollouts prescribed) demonstration at its first frame."""
        if self.demo.shape[0] != env.n:
            self.demo = np.zeros(env.n, dtype=np.int64)
            self.prev_action = np.zeros((env.n, NUM_ACTIONS))
            self.task_return = np.zeros(env.n)
        ids = np.asarray(ids)
        if self.eval_demos is not None:
            self.demo[ids] = self.eval_demos[ids]
        else:
            self.demo[ids] = rng.integers(0, len(self.refs.ids), ids.size)
        d = self.demo[ids]
        r = self.refs
        wrist = np.concatenate([r.wrist_pos[d, 0], r.wrist_quat[d, 0]], axis=1)
        env.reset_pose(
            ids,
            r.joints[d, 0],
            wrist,
            np.concatenate([r.object_pos[d, 0], r.object_quat[d, 0]], axis=1),
            r.opening[d, 0],
        )
        self.prev_action[ids] = 0.0
        self.task_return[ids] = 0.0

    def command(
        self, env: BatchEnv, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """Reference-plus-residual joint targets and wrist pose, and (DexMachina) the assistance
        force on the object, all for the next frame."""
        a = np.clip(actions, -1.0, 1.0)
        targets = self._ref("joints", env, 1) + self.cfg.action_scale * a[:, JOINT_ACTIONS]
        wrist_pos = self._ref("wrist_pos", env, 1) + self.cfg.wrist_pos_scale_m * a[:, WRIST_POS_ACTIONS]
        wrist_quat = quat_mul(
            self._ref("wrist_quat", env, 1), quat_from_rotvec(self.cfg.wrist_rot_scale_rad * a[:, WRIST_ROT_ACTIONS])
        )
        force = self.assistance_force(env) if self.assist_gain > 0 else None
        return targets, wrist_pos, wrist_quat, force

    def assistance_force(self, env: BatchEnv) -> np.ndarray:
        """DexMachina's virtual object controller: a mass-scaled PD pull (plus gravity
        compensation) towards the next reference pose, times the current gain."""
        a = self.method.assistance
        omega = 2.0 * np.pi * a.frequency_hz
        m, inertia = env.scene.object_mass, env.scene.object_inertia
        kp, kd = m * omega**2, 2.0 * a.damping_ratio * m * omega
        vel = env.object_vel
        if env.scene.is_drawer:
            force = kp * (self._ref("opening", env, 1) - env.drawer_opening)[:, None] - kd * vel
        else:
            lin = kp * (self._ref("object_pos", env, 1) - env.object_pos) - kd * vel[:, :3]
            if a.gravity_compensation:
                lin[:, 2] += m * GRAVITY
            err = rotvec(quat_mul(quat_conj(env.object_quat), self._ref("object_quat", env, 1)))  # object frame
            ang = inertia * omega**2 * err - 2.0 * a.damping_ratio * inertia * omega * vel[:, 3:]
            force = np.concatenate([lin, ang], axis=1)
        return self.assist_gain * force

    def contact_targets(self, env: BatchEnv, offset: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Geometric contact flags (N, 8) and their points carried by the simulated object (N, 8, 3)."""
        flags = self._ref("geo_contact", env, offset)
        local = self._ref("geo_point", env, offset)
        world = np.einsum("nij,nrj->nri", quat_to_mat(env.object_quat), local) + env.object_pos[:, None, :]
        return flags, world

    def observe(self, env: BatchEnv) -> dict[str, np.ndarray]:
        q = env.hand_qpos
        obj_pos, obj_quat = env.object_pos, env.object_quat
        if self.uses_preference:
            flags, offsets = self._ref("preference", env, 1).astype(np.float64), np.zeros((env.n, 24))
        else:
            flags, points = self.contact_targets(env, 1)
            offsets = np.where(flags[:, :, None], points - env.region_pos, 0.0).reshape(env.n, 24)
            flags = flags.astype(np.float64)
        k = self.frame(env)
        obs = np.concatenate(
            [
                q,
                0.1 * env.hand_qvel,
                self._ref("joints", env, 1) - q,
                self._ref("joints", env, 2) - q,
                obj_pos - env.wrist_pose[:, :3],
                obj_quat,
                self._ref("object_pos", env, 1) - obj_pos,
                self._ref("object_quat", env, 1),
                env.drawer_opening[:, None],
                (self._ref("opening", env, 1) - env.drawer_opening)[:, None],
                np.tanh(env.region_force / 2.0),
                flags,
                10.0 * offsets,
                self.prev_action,
                (k / np.maximum(self.refs.length[self.demo] - 1, 1))[:, None],
            ],
            axis=1,
        )
        return {"actor": obs, "critic": obs}

    def tracking_errors(self, env: BatchEnv) -> tuple[np.ndarray, np.ndarray]:
        """(N,) object position (drawer: opening) and orientation distances to the current reference frame."""
        if env.scene.is_drawer:
            return np.abs(env.drawer_opening - self._ref("opening", env)), np.zeros(env.n)
        return np.linalg.norm(env.object_pos - self._ref("object_pos", env), axis=1), quat_angle(
            env.object_quat, self._ref("object_quat", env)
        )

    def reward(self, env: BatchEnv, actions: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        w, cfg = self.w, self.cfg
        pos_err, rot_err = self.tracking_errors(env)
        terms: dict[str, np.ndarray] = {}
        terms["object_pos"] = w.object_pos * np.exp(-pos_err / cfg.sigma_pos)
        terms["object_rot"] = (0.0 if env.scene.is_drawer else w.object_rot) * np.exp(-rot_err / cfg.sigma_rot)
        terms["imitation"] = w.imitation * np.exp(
            -np.sum((env.hand_qpos - self._ref("joints", env)) ** 2, axis=1) / cfg.sigma_joint
        )
        if w.tactile:
            terms["tactile"] = w.tactile * step_f1(env.region_contact, self._ref("preference", env))
        if w.contact:
            flags, points = self.contact_targets(env)
            closeness = np.exp(-np.linalg.norm(env.region_pos - points, axis=2) / cfg.sigma_contact)
            terms["contact"] = w.contact * np.sum(flags * closeness, axis=1) / np.maximum(flags.sum(axis=1), 1)
        a = np.clip(actions, -1.0, 1.0)
        terms["action_rate"] = -w.action_rate * np.mean((a - self.prev_action) ** 2, axis=1)
        if self._kp is None:
            self._kp = np.array(env.model.actuator_gainprm[:, 0])  # a copy
        torque = self._kp * (env.joint_targets - env.hand_qpos)
        terms["energy"] = -w.energy * np.sum(np.abs(torque * env.hand_qvel), axis=1)
        lost = self._lost(env, pos_err, rot_err)
        terms["termination"] = -w.termination * lost
        self.prev_action = a

        task_max = w.object_pos + (0.0 if env.scene.is_drawer else w.object_rot)
        task = (terms["object_pos"] + terms["object_rot"]) / max(task_max, 1e-9)
        self.task_return += task
        style = terms["imitation"] + terms.get("contact", 0.0) + terms.get("tactile", 0.0)
        shaping = terms["action_rate"] + terms["energy"] + terms["termination"]
        if self.method.contrack.enabled:
            lam = self.dual[self.demo]
            total = (style + lam * task_max * task) / (1.0 + lam) + shaping
        else:
            total = task_max * task + style + shaping
        self._last_terms = terms
        return total, terms

    def _lost(self, env: BatchEnv, pos_err: np.ndarray, rot_err: np.ndarray) -> np.ndarray:
        past_grace = env.time_step > self.cfg.grace_steps
        return past_grace & ((pos_err > self.cfg.lost_pos_m) | (rot_err > self.cfg.lost_rot_rad))

    def terminated(self, env: BatchEnv) -> np.ndarray:
        pos_err, rot_err = self.tracking_errors(env)
        return self._lost(env, pos_err, rot_err)

    def truncated(self, env: BatchEnv) -> np.ndarray:
        """The demonstration's last frame is reached."""
        return env.time_step >= self.refs.length[self.demo] - 1

    def episode_end(self, env: BatchEnv, ids: np.ndarray) -> dict[str, float]:
        """Bookkeeping of finished episodes (before their reset): ConTrack's dual ascent and
        DexMachina's assistance schedule. Returns figures to log."""
        # task reward per step of the whole demonstration: an episode cut short by lost tracking
        # scores its missing steps as zero
        full = self.refs.length[self.demo[ids]] - 1
        mean_task = self.task_return[ids] / np.maximum(full, 1)
        log = {"task/tracking_return": float(mean_task.mean())}
        c = self.method.contrack
        if c.enabled:
            for d, r in zip(self.demo[ids], mean_task, strict=True):
                self.best_task[d] = max(self.best_task[d], r)
                violation = (c.alpha * self.best_task[d] - r) / max(abs(self.best_task[d]), 1e-3)
                self.dual[d] = np.clip(self.dual[d] + c.dual_lr * violation, 0.0, c.lambda_max)
            log["contrack/lambda"] = float(self.dual.mean())
        a = self.method.assistance
        if a.enabled and self.assist_gain > 0:
            self._recent_task.extend(mean_task.tolist())
            if len(self._recent_task) >= a.window_episodes and np.mean(self._recent_task) > a.threshold:
                self.assist_gain *= a.decay
                self._recent_task.clear()
                if self.assist_gain < a.min_gain:
                    self.assist_gain = 0.0
            log["dexmachina/assist_gain"] = self.assist_gain
        return log
