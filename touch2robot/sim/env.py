"""N copies of a task scene stepped together in C by MuJoCo's multithreaded rollout.

One control step = ``substeps`` physics steps with the servo targets and the wrist's mocap
pose held. The state of every copy lives in one (N, nstate) array (MuJoCo's full physics
state), so resets, observations and rewards are numpy operations over the whole batch and
each copy's next state depends only on its own state and command: the same state gives
the same next state whatever N is.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from mujoco import rollout

from touch2robot.sim.config import SimConfig
from touch2robot.sim.scene import Scene

STATE_SPEC = mujoco.mjtState.mjSTATE_FULLPHYSICS
CONTROL_SPEC = mujoco.mjtState.mjSTATE_CTRL | mujoco.mjtState.mjSTATE_MOCAP_POS | mujoco.mjtState.mjSTATE_MOCAP_QUAT


@dataclass(frozen=True)
class StateLayout:
    """Column ranges of MuJoCo's full physics state vector (time, qpos, qvel, act, ...)."""

    nq: int
    nv: int

    @property
    def qpos(self) -> slice:
        return slice(1, 1 + self.nq)

    @property
    def qvel(self) -> slice:
        return slice(1 + self.nq, 1 + self.nq + self.nv)


class BatchEnv:
    """The physics of N copies of one scene (no rewards: objectives sit on top).

    ``step(joint_targets, wrist_pos, wrist_quat)`` advances every copy one control step;
    ``reset(ids, qpos)`` re-initialises some copies. Per-region contact forces (touch
    sensors over the eight tactile regions) and fingertip positions are read from the
    sensor data of the last physics substep.
    """

    def __init__(self, scene: Scene, cfg: SimConfig, n_envs: int | None = None) -> None:
        self.scene = scene
        self.cfg = cfg
        self.model = scene.model
        self.n = n_envs or cfg.n_envs
        self.layout = StateLayout(self.model.nq, self.model.nv)
        self.nstate = mujoco.mj_stateSize(self.model, STATE_SPEC)
        self._datas = [mujoco.MjData(self.model) for _ in range(cfg.threads)]
        self._rollout = rollout.Rollout(nthread=cfg.threads if cfg.threads > 1 else 0)
        home = mujoco.MjData(self.model)
        home.qpos[:] = scene.home_qpos
        home.ctrl[:] = scene.home_qpos[scene.hand_qpos]
        home.mocap_pos[0] = scene.home_wrist_pos
        home.mocap_quat[0] = scene.home_wrist_quat
        mujoco.mj_forward(self.model, home)
        self.home_state = np.empty(self.nstate)
        mujoco.mj_getState(self.model, home, self.home_state, STATE_SPEC)
        self.state = np.tile(self.home_state, (self.n, 1))
        self.joint_targets = np.tile(home.ctrl, (self.n, 1))
        self.wrist_pos = np.tile(scene.home_wrist_pos, (self.n, 1))
        self.wrist_quat = np.tile(scene.home_wrist_quat, (self.n, 1))
        self._control = np.empty((self.n, cfg.substeps, self.model.nu + 7))
        self._state_out = np.empty((self.n, cfg.substeps, self.nstate))
        self._sensor_out = np.empty((self.n, cfg.substeps, self.model.nsensordata))
        self.sensordata = np.zeros((self.n, self.model.nsensordata))
        self.time_step = np.zeros(self.n, dtype=np.int64)  # control steps since each copy's reset
        self.ctrl_low, self.ctrl_high = self.model.actuator_ctrlrange.T.copy()

    def close(self) -> None:
        self._rollout.close()

    # ------------------------------------------------------------------ stepping
    def step(self, joint_targets: np.ndarray, wrist_pos: np.ndarray | None = None, wrist_quat: np.ndarray | None = None) -> None:
        """Advance all copies by one control step. Targets are clipped to the joint ranges."""
        self.joint_targets = np.clip(np.asarray(joint_targets, dtype=np.float64), self.ctrl_low, self.ctrl_high)
        if wrist_pos is not None:
            self.wrist_pos = np.asarray(wrist_pos, dtype=np.float64)
        if wrist_quat is not None:
            q = np.asarray(wrist_quat, dtype=np.float64)
            self.wrist_quat = q / np.linalg.norm(q, axis=-1, keepdims=True)
        nu = self.model.nu
        self._control[:, :, :nu] = self.joint_targets[:, None, :]
        self._control[:, :, nu : nu + 3] = self.wrist_pos[:, None, :]
        self._control[:, :, nu + 3 :] = self.wrist_quat[:, None, :]
        self._rollout.rollout(
            self.model,
            self._datas,
            self.state,
            self._control,
            control_spec=CONTROL_SPEC,
            skip_checks=False,
            nstep=self.cfg.substeps,
            state=self._state_out,
            sensordata=self._sensor_out,
        )
        self.state = self._state_out[:, -1].copy()
        self.sensordata = self._sensor_out[:, -1].copy()
        self.time_step += 1

    def reset(self, ids: np.ndarray, qpos: np.ndarray | None = None, joint_targets: np.ndarray | None = None,
              wrist_pos: np.ndarray | None = None, wrist_quat: np.ndarray | None = None) -> None:  # fmt: skip
        """Put copies ``ids`` back to the home state, optionally with given qpos (len(ids), nq),
        servo targets and wrist pose; velocities are zeroed."""
        ids = np.asarray(ids)
        if ids.size == 0:
            return
        state = np.tile(self.home_state, (ids.size, 1))
        if qpos is not None:
            state[:, self.layout.qpos] = qpos
        self.state[ids] = state
        self.joint_targets[ids] = self.home_state[self.layout.qpos][self.scene.hand_qpos] if joint_targets is None else joint_targets
        self.wrist_pos[ids] = self.scene.home_wrist_pos if wrist_pos is None else wrist_pos
        self.wrist_quat[ids] = self.scene.home_wrist_quat if wrist_quat is None else wrist_quat
        if qpos is not None or wrist_pos is not None:
            # the free wrist starts where its mocap target is
            adr = self.scene.wrist_qpos
            self.state[ids, 1 + adr : 1 + adr + 3] = self.wrist_pos[ids]
            self.state[ids, 1 + adr + 3 : 1 + adr + 7] = self.wrist_quat[ids]
        self.sensordata[ids] = 0.0
        self.time_step[ids] = 0

    # ------------------------------------------------------------------ reading the batch
    @property
    def qpos(self) -> np.ndarray:
        return self.state[:, self.layout.qpos]

    @property
    def qvel(self) -> np.ndarray:
        return self.state[:, self.layout.qvel]

    @property
    def hand_qpos(self) -> np.ndarray:
        """(N, 16) joint angles in the reference joint order."""
        return self.qpos[:, self.scene.hand_qpos]

    @property
    def hand_qvel(self) -> np.ndarray:
        return self.qvel[:, self.scene.hand_dof]

    @property
    def object_pose(self) -> np.ndarray:
        """(N, 7) object position + quaternion; for the drawer (N, 1) slide opening."""
        adr = self.scene.object_qpos
        return self.qpos[:, adr : adr + (1 if self.scene.is_drawer else 7)]

    @property
    def region_force(self) -> np.ndarray:
        """(N, 8) summed normal force (N) on the tactile regions T1..T4, P1..P4."""
        return self.sensordata[:, self.scene.region_sensors]

    @property
    def region_contact(self) -> np.ndarray:
        """(N, 8) binary contact: region force above the configured threshold (0.5 N)."""
        return self.region_force > self.cfg.contact_threshold_n

    @property
    def fingertip_pos(self) -> np.ndarray:
        """(N, 4, 3) world positions of the thumb, index, middle and ring fingertip sites."""
        return self.sensordata[:, self.scene.tip_sensors]
