"""N copies of a task scene stepped together in C by MuJoCo's multithreaded rollout.

One control step = ``substeps`` physics steps with the servo targets and the wrist's mocap
pose held. The state of every copy lives in one (N, nstate) array (MuJoCo's full physics
state), so resets, observations and rewards are numpy operations over the whole batch and
each copy's next state depends only on its own state and command: the same state gives
the same next state whatever N is. (Rollout starts every call from a zero solver warm start
rather than whatever a worker thread's MjData last held, which is what makes this exact.)
A step that loses physics in any copy (full contact or constraint buffer, unstable or non-finite
state, arena nearly full) raises ``LostPhysicsError`` naming the copy (``touch2robot.sim.guard``).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from mujoco import rollout

from touch2robot.sim.config import SimConfig
from touch2robot.sim.guard import LostPhysicsError, arena_over_budget, replay_copy
from touch2robot.sim.scene import Scene
from touch2robot.sim.success import SuccessTracker

STATE_SPEC = mujoco.mjtState.mjSTATE_FULLPHYSICS
# control vector per substep, in MuJoCo's component order: ctrl (nu), qfrc_applied (nv), mocap pos (3), quat (4)
CONTROL_SPEC = (
    mujoco.mjtState.mjSTATE_CTRL
    | mujoco.mjtState.mjSTATE_QFRC_APPLIED
    | mujoco.mjtState.mjSTATE_MOCAP_POS
    | mujoco.mjtState.mjSTATE_MOCAP_QUAT
)


@dataclass(frozen=True)
class StateLayout:
    """Column ranges of MuJoCo's full physics state vector (time, qpos, qvel, act, ...)."""

    nq: int
    nv: int

    @property
    def qpos(self) -> slice:
        """Columns of qpos (after the time column)."""
        return slice(1, 1 + self.nq)

    @property
    def qvel(self) -> slice:
        """Columns of qvel (after qpos)."""
        return slice(1 + self.nq, 1 + self.nq + self.nv)


class BatchEnv:
    """The physics of N copies of one scene (no rewards: objectives sit on top).

    ``step(joint_targets, wrist_pos, wrist_quat)`` advances every copy one control step;
    ``reset(ids, qpos)`` re-initialises some copies. A step that loses physics raises
    ``LostPhysicsError`` (``lost_physics`` counts them) and leaves ``state`` as it was before it.
    Per-region contact forces (touch sensors over the eight tactile regions) and fingertip
    positions are read from the sensor data of the last physics substep (MuJoCo evaluates
    sensors at the start of a step, so they describe the state one substep before ``state``).
    Task success is tracked per copy from the object state (``success``, ``progress``).
    """

    def __init__(self, scene: Scene, cfg: SimConfig, n_envs: int | None = None) -> None:
        self.scene = scene
        self.cfg = cfg
        self.model = scene.model
        self.n = n_envs or cfg.n_envs
        self.layout = StateLayout(self.model.nq, self.model.nv)
        self.nstate = mujoco.mj_stateSize(self.model, STATE_SPEC)
        self._datas = [mujoco.MjData(self.model) for _ in range(cfg.threads)]
        # skip_checks wants one model per copy (references to the same MjModel)
        self._models = [self.model] * self.n
        self._rollout = rollout.Rollout(nthread=cfg.threads if cfg.threads > 1 else 0)
        self._warmstart = np.zeros((self.n, self.model.nv))
        home = mujoco.MjData(self.model)
        home.qpos[:] = scene.home_qpos
        home.ctrl[:] = scene.home_qpos[scene.hand_qpos]
        home.mocap_pos[0] = scene.home_wrist_pos
        home.mocap_quat[0] = scene.home_wrist_quat
        mujoco.mj_forward(self.model, home)
        self.home_state = np.empty(self.nstate)
        mujoco.mj_getState(self.model, home, self.home_state, STATE_SPEC)
        self.home_sensordata = home.sensordata.copy()
        self._scratch = home
        self.state = np.tile(self.home_state, (self.n, 1))
        self.joint_targets = np.tile(home.ctrl, (self.n, 1))
        self.wrist_pos = np.tile(scene.home_wrist_pos, (self.n, 1))
        self.wrist_quat = np.tile(scene.home_wrist_quat, (self.n, 1))
        self._control = np.zeros((self.n, cfg.substeps, self.model.nu + self.model.nv + 7))
        self._state_out = np.empty((self.n, cfg.substeps, self.nstate))
        self._sensor_out = np.empty((self.n, cfg.substeps, self.model.nsensordata))
        self.sensordata = np.tile(self.home_sensordata, (self.n, 1))
        self.time_step = np.zeros(self.n, dtype=np.int64)  # control steps since each copy's reset
        self.ctrl_low, self.ctrl_high = self.model.actuator_ctrlrange.T.copy()
        slide = scene.spec.slide
        self._slide_axis = np.zeros(3) if slide is None else np.asarray(slide.axis, dtype=np.float64)
        self.tracker = SuccessTracker(scene.spec, self.n)
        self.tracker.reset(np.arange(self.n), self.object_pos, self.object_quat)
        self.lost_physics = 0  # steps that raised LostPhysicsError

    def close(self) -> None:
        """Stop the rollout worker threads."""
        self._rollout.close()

    # ------------------------------------------------------------------ stepping
    def step(
        self,
        joint_targets: np.ndarray,
        wrist_pos: np.ndarray | None = None,
        wrist_quat: np.ndarray | None = None,
        object_force: np.ndarray | None = None,
    ) -> None:
        """Advance all copies by one control step. Targets are clipped to the joint ranges.
        ``object_force`` (N, 6) for a free object (world force, then torque in the object's
        frame) or (N, 1) for the drawer slide is a generalised force on the object's joint,
        held over the step (DexMachina's virtual object assistance); None = no force."""
        self.joint_targets = np.clip(np.asarray(joint_targets, dtype=np.float64), self.ctrl_low, self.ctrl_high)
        if wrist_pos is not None:
            self.wrist_pos = np.asarray(wrist_pos, dtype=np.float64)
        if wrist_quat is not None:
            q = np.asarray(wrist_quat, dtype=np.float64)
            self.wrist_quat = q / np.linalg.norm(q, axis=-1, keepdims=True)
        nu, nv = self.model.nu, self.model.nv
        self._control[:, :, :nu] = self.joint_targets[:, None, :]
        dof = self.scene.object_dof
        width = 1 if self.scene.is_drawer else 6
        self._control[:, :, nu + dof : nu + dof + width] = (
            0.0 if object_force is None else np.asarray(object_force)[:, None, :]
        )
        self._control[:, :, nu + nv : nu + nv + 3] = self.wrist_pos[:, None, :]
        self._control[:, :, nu + nv + 3 :] = self.wrist_quat[:, None, :]
        try:
            self._rollout_step()
        except mujoco.FatalError as error:  # one thread only: in a worker thread MuJoCo exits the process
            self._raise_lost_physics(str(error).splitlines()[0])
        if self._physics_lost():
            self._raise_lost_physics()
        self.state[:] = self._state_out[:, -1]
        self.sensordata[:] = self._sensor_out[:, -1]
        self.time_step += 1
        self.tracker.update(self.object_pos, self.object_quat, self.drawer_opening)

    def _rollout_step(self) -> None:
        self._rollout.rollout(
            self._models,
            self._datas,
            self.state,
            self._control,
            control_spec=CONTROL_SPEC,
            skip_checks=True,  # shapes are fixed at construction; the checks cost ~10% at N = 200
            nstep=self.cfg.substeps,
            initial_warmstart=self._warmstart,
            state=self._state_out,
            sensordata=self._sensor_out,
        )

    def _suspects(self) -> np.ndarray:
        """(N,) bool: copies whose clock did not advance by the control step in the last rollout (it
        stops stepping a copy at its first warning; MuJoCo's resets restart the clock) or whose state
        is non-finite."""
        dt = self.model.opt.timestep
        stalled = np.abs(self._state_out[:, -1, 0] - self.state[:, 0] - self.cfg.substeps * dt) > 0.5 * dt
        return stalled | ~np.isfinite(self._state_out[:, -1]).all(axis=1)

    def _physics_lost(self) -> bool:
        """Cheap signs that the last rollout lost physics somewhere: a suspect copy, warnings left on a
        thread's data (its last copy's, from any substep), or a thread's arena use over budget."""
        return bool(
            self._suspects().any()
            or any(d.warning.number.any() or arena_over_budget(d, self.model) for d in self._datas)
        )

    def _raise_lost_physics(self, fatal: str | None = None) -> None:
        """Find the copy that lost physics by replaying copies one at a time from their states before
        the step (``state`` is not yet overwritten), suspects first, and raise for the first found.
        ``fatal``: MuJoCo's error that cut the rollout short (its outputs then mean nothing)."""
        self.lost_physics += 1
        task = self.scene.spec.name
        suspects = np.zeros(self.n, dtype=bool) if fatal else self._suspects()
        scratch = mujoco.MjData(self.model)
        for i in np.concatenate([np.flatnonzero(suspects), np.flatnonzero(~suspects)]):
            found = replay_copy(self.model, scratch, self.state[i], self._control[i], STATE_SPEC, CONTROL_SPEC)
            if found is not None:
                substep, cause = found
                time_s = (self.time_step[i] * self.cfg.substeps + substep + 1) * self.model.opt.timestep
                raise LostPhysicsError(task, int(i), float(time_s), cause)
        if suspects.any():  # no replay reproduced it: name the first suspect by what the rollout left
            i = int(np.flatnonzero(suspects)[0])
            finite = np.isfinite(self._state_out[i, -1]).all()
            cause = "the rollout stopped stepping it" if finite else "non-finite state"
            raise LostPhysicsError(task, i, float((self.time_step[i] + 1) * self.cfg.control_dt), cause)
        raise LostPhysicsError(
            task, None, None, fatal or "a thread's data shows lost physics that no replay reproduces"
        )

    def reset(
        self,
        ids: np.ndarray,
        qpos: np.ndarray | None = None,
        joint_targets: np.ndarray | None = None,
        wrist_pos: np.ndarray | None = None,
        wrist_quat: np.ndarray | None = None,
    ) -> None:
        """Put copies ``ids`` back to the home state, optionally with given qpos (len(ids), nq),
        servo targets and wrist pose; velocities are zeroed."""
        ids = np.asarray(ids)
        if ids.size == 0:
            return
        state = np.tile(self.home_state, (ids.size, 1))
        if qpos is not None:
            state[:, self.layout.qpos] = qpos
        self.state[ids] = state
        self.joint_targets[ids] = (
            self.home_state[self.layout.qpos][self.scene.hand_qpos] if joint_targets is None else joint_targets
        )
        self.wrist_pos[ids] = self.scene.home_wrist_pos if wrist_pos is None else wrist_pos
        self.wrist_quat[ids] = self.scene.home_wrist_quat if wrist_quat is None else wrist_quat
        if qpos is None and wrist_pos is None and wrist_quat is None:
            self.sensordata[ids] = self.home_sensordata
        else:
            # the free wrist starts where its mocap target is
            adr = 1 + self.scene.wrist_qpos
            self.state[ids, adr : adr + 3] = self.wrist_pos[ids]
            self.state[ids, adr + 3 : adr + 7] = self.wrist_quat[ids]
            # sensors of a new configuration need its contacts: one forward pass per reset copy
            for i in ids:
                mujoco.mj_setState(self.model, self._scratch, self.state[i], STATE_SPEC)
                self._scratch.mocap_pos[0], self._scratch.mocap_quat[0] = self.wrist_pos[i], self.wrist_quat[i]
                self._scratch.ctrl[:] = self.joint_targets[i]
                mujoco.mj_forward(self.model, self._scratch)
                self.sensordata[i] = self._scratch.sensordata
        self.time_step[ids] = 0
        self.tracker.reset(ids, self.object_pos[ids], self.object_quat[ids])

    def reset_pose(
        self,
        ids: np.ndarray,
        joints: np.ndarray,
        wrist_pose: np.ndarray,
        object_pose: np.ndarray,
        drawer_opening: np.ndarray,
    ) -> None:
        """Reset copies ``ids`` at rest to a recorded configuration: hand joints (k, 16) with the
        servos holding them, wrist body and mocap target at ``wrist_pose`` (k, 7: pos, quat), the
        object at ``object_pose`` (k, 7), or the drawer at ``drawer_opening`` (k,)."""
        ids = np.asarray(ids)
        qpos = np.tile(self.scene.home_qpos, (ids.size, 1))
        qpos[:, self.scene.hand_qpos] = joints
        adr = self.scene.object_qpos
        if self.scene.is_drawer:
            qpos[:, adr] = drawer_opening
        else:
            qpos[:, adr : adr + 7] = object_pose
        wrist_pose = np.asarray(wrist_pose)
        self.reset(ids, qpos=qpos, joint_targets=joints, wrist_pos=wrist_pose[:, :3], wrist_quat=wrist_pose[:, 3:])

    # ------------------------------------------------------------------ reading the batch
    @property
    def qpos(self) -> np.ndarray:
        """(N, nq) generalised positions (a view into ``state``)."""
        return self.state[:, self.layout.qpos]

    @property
    def qvel(self) -> np.ndarray:
        """(N, nv) generalised velocities (a view into ``state``)."""
        return self.state[:, self.layout.qvel]

    @property
    def hand_qpos(self) -> np.ndarray:
        """(N, 16) joint angles in the reference joint order."""
        return self.qpos[:, self.scene.hand_qpos]

    @property
    def hand_qvel(self) -> np.ndarray:
        """(N, 16) joint velocities in the reference joint order."""
        return self.qvel[:, self.scene.hand_dof]

    @property
    def wrist_pose(self) -> np.ndarray:
        """(N, 7) world position + quaternion of the (welded, compliant) wrist frame."""
        adr = self.scene.wrist_qpos
        return self.qpos[:, adr : adr + 7]

    @property
    def drawer_opening(self) -> np.ndarray:
        """(N,) the drawer's travel along its slide (m); zeros for free objects."""
        if not self.scene.is_drawer:
            return np.zeros(self.n)
        return self.qpos[:, self.scene.object_qpos]

    @property
    def object_pos(self) -> np.ndarray:
        """(N, 3) world position of the object's body frame (the drawer's moves along its slide)."""
        if self.scene.is_drawer:
            return np.asarray(self.scene.spec.object.init_pos) + self.drawer_opening[:, None] * self._slide_axis
        adr = self.scene.object_qpos
        return self.qpos[:, adr : adr + 3]

    @property
    def object_quat(self) -> np.ndarray:
        """(N, 4) world orientation of the object's body frame."""
        if self.scene.is_drawer:
            return np.tile(self.scene.spec.object.init_quat, (self.n, 1))
        adr = self.scene.object_qpos
        q = self.qpos[:, adr + 3 : adr + 7]
        return q / np.linalg.norm(q, axis=1, keepdims=True)

    def object_points(self) -> np.ndarray:
        """(N, P, 3) the object's surface point cloud in the world, at each copy's object pose."""
        quat = self.object_quat
        w, v = quat[:, None, :1], quat[:, None, 1:]
        p = self.scene.point_cloud[None].astype(np.float64)
        # rotate p by q: p + 2 w (v x p) + 2 v x (v x p)
        t = 2.0 * np.cross(v, p)
        return p + w * t + np.cross(v, t) + self.object_pos[:, None, :]

    @property
    def success(self) -> np.ndarray:
        """(N,) bool: the task's success criterion holds for the episode so far."""
        return self.tracker.success

    @property
    def progress(self) -> np.ndarray:
        """(N,) task progress in [0, 1] (distance to goal, angle, coverage or opening)."""
        return self.tracker.progress

    @property
    def object_pose(self) -> np.ndarray:
        """Raw object coordinates: (N, 7) free-joint qpos, or (N, 1) slide position."""
        return self.qpos[:, self.scene.object_qpos : self.scene.object_qpos + (1 if self.scene.is_drawer else 7)]

    @property
    def region_force(self) -> np.ndarray:
        """(N, 8) summed normal force (N) on the tactile regions T1..T4, P1..P4."""
        return self.sensordata[:, self.scene.region_sensors]

    @property
    def region_contact(self) -> np.ndarray:
        """(N, 8) binary contact: region force above the configured threshold (0.5 N)."""
        return self.region_force > self.cfg.contact_threshold_n

    @property
    def region_pos(self) -> np.ndarray:
        """(N, 8, 3) world positions of the centres of the tactile regions T1..T4, P1..P4."""
        return self.sensordata[:, self.scene.region_pos_sensors]

    @property
    def object_vel(self) -> np.ndarray:
        """(N, 6) free object: world linear velocity, then angular velocity in its frame; (N, 1) drawer slide speed."""
        dof = self.scene.object_dof
        return self.qvel[:, dof : dof + (1 if self.scene.is_drawer else 6)]

    @property
    def fingertip_pos(self) -> np.ndarray:
        """(N, 4, 3) world positions of the thumb, index, middle and ring fingertip sites."""
        return self.sensordata[:, self.scene.tip_sensors]
