"""rsl-rl's VecEnv over a BatchEnv, with the task-specific parts behind an ``Objective``:
what an action commands, what the policy and critic observe, the named reward terms, when
an episode ends early, and how a copy is reset. Teachers plug their objectives in here."""

from __future__ import annotations

from typing import Protocol

import numpy as np
import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from touch2robot.sim.config import SimConfig
from touch2robot.sim.env import BatchEnv
from touch2robot.sim.scene import build_scene


class Objective(Protocol):
    """The task-specific side of an RL environment, vectorised over the batch."""

    num_actions: int

    def reset(self, env: BatchEnv, ids: np.ndarray, rng: np.random.Generator) -> None:
        """Reset copies ``ids`` (env.reset plus the objective's own per-copy state)."""
        ...

    def command(
        self, env: BatchEnv, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
        """Policy actions (N, num_actions) -> the arguments of ``BatchEnv.step``: joint targets
        (N, 16), wrist pos, wrist quat, object force (None = unchanged / none)."""
        ...

    def observe(self, env: BatchEnv) -> dict[str, np.ndarray]:
        """Observation groups, e.g. {"actor": (N, d_a), "critic": (N, d_c)}."""
        ...

    def reward(self, env: BatchEnv, actions: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Total reward (N,) and its weighted named terms (each (N,))."""
        ...

    def terminated(self, env: BatchEnv) -> np.ndarray:
        """(N,) bool: episodes that end early (e.g. tracking lost)."""
        ...

    def truncated(self, env: BatchEnv) -> np.ndarray:
        """(N,) bool: episodes cut by time (their reference ends); PPO bootstraps these."""
        ...

    def episode_end(self, env: BatchEnv, ids: np.ndarray) -> dict[str, float]:
        """Called with the copies whose episodes end, before their reset; figures to log."""
        ...


class RslVecEnv[O: Objective](VecEnv):
    """The VecEnv rsl-rl's OnPolicyRunner drives. Copies that finish are reset inside
    ``step`` (rsl-rl has no reset call); ``extras["time_outs"]`` marks truncations so that
    PPO bootstraps them, and ``extras["log"]`` carries the mean of each reward term."""

    def __init__(
        self, env: BatchEnv, objective: O, max_episode_length: int, seed: int = 0, device: str | None = None
    ) -> None:
        self.env = env
        self.objective = objective
        self.num_envs = env.n
        self.num_actions = objective.num_actions
        self.max_episode_length = max_episode_length
        self.device: str = device or env.cfg.device
        self.cfg = {"sim": env.cfg.model_dump(), "task": env.scene.spec.name, "objective": type(objective).__name__}
        self.rng = np.random.default_rng(seed)
        self.episode_length_buf = torch.zeros(self.num_envs, dtype=torch.long, device=device)
        objective.reset(env, np.arange(self.num_envs), self.rng)

    def _obs(self) -> TensorDict:
        groups = self.objective.observe(self.env)
        return TensorDict(
            {k: torch.as_tensor(v, dtype=torch.float32, device=self.device) for k, v in groups.items()},
            batch_size=[self.num_envs],
            device=self.device,
        )

    def get_observations(self) -> TensorDict:
        """The current observation groups as a TensorDict (batch size num_envs)."""
        return self._obs()

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        a = actions.detach().cpu().numpy().astype(np.float64)
        self.env.step(*self.objective.command(self.env, a))
        self.episode_length_buf += 1
        reward, terms = self.objective.reward(self.env, a)
        terminated = self.objective.terminated(self.env)
        time_outs = (self.episode_length_buf >= self.max_episode_length).cpu().numpy() | self.objective.truncated(
            self.env
        )
        done = terminated | time_outs
        log = {f"reward/{k}": float(np.mean(v)) for k, v in terms.items()}
        log["contact/any_region"] = float(self.env.region_contact.any(axis=1).mean())
        ids = np.flatnonzero(done)
        if ids.size:  # task outcome of the episodes that end here, read before their reset
            log["task/success"] = float(self.env.success[ids].mean())
            log["task/progress"] = float(self.env.progress[ids].mean())
            log.update(self.objective.episode_end(self.env, ids))
            self.objective.reset(self.env, ids, self.rng)
            self.episode_length_buf[torch.as_tensor(ids, device=self.device)] = 0
        extras = {"time_outs": torch.as_tensor(time_outs & ~terminated, device=self.device), "log": log}
        return (
            self._obs(),
            torch.as_tensor(reward, dtype=torch.float32, device=self.device),
            torch.as_tensor(done, dtype=torch.long, device=self.device),
            extras,
        )


def episode_steps(env: BatchEnv) -> int:
    """Control steps per episode: the config's ``episode_s`` if set, else the task spec's."""
    seconds = env.cfg.episode_s or env.scene.spec.episode_s
    return max(1, round(seconds / env.cfg.control_dt))


def make_vec_env[O: Objective](
    task: str, objective: O, cfg: SimConfig | None = None, max_episode_length: int | None = None
) -> RslVecEnv[O]:
    """An rsl-rl VecEnv of ``cfg.n_envs`` copies of a task scene driven by ``objective``."""
    cfg = cfg or SimConfig()
    env = BatchEnv(build_scene(task, cfg), cfg)
    return RslVecEnv(env, objective, max_episode_length or episode_steps(env), seed=cfg.seed)


class JointTracking:
    """A simple objective to prove the loop: track a reference joint trajectory (sinusoids
    around the home pose) with residual actions; reward exp(-|q - q_ref|^2 / sigma)."""

    num_actions = 16

    def __init__(
        self, amplitude: float = 0.35, frequency_hz: float = 0.8, action_scale: float = 0.3, sigma: float = 0.5
    ) -> None:
        self.amplitude, self.frequency, self.action_scale, self.sigma = amplitude, frequency_hz, action_scale, sigma
        self.phase = np.zeros((0, 16))

    def _reference(self, env: BatchEnv, step_offset: int = 0) -> np.ndarray:
        """(N, 16) reference joint angles ``step_offset`` control steps after the current one."""
        t = (env.time_step + step_offset)[:, None] * env.cfg.control_dt
        home = env.home_state[env.layout.qpos][env.scene.hand_qpos]
        ref = home + self.amplitude * np.sin(2 * np.pi * self.frequency * t + self.phase)
        return np.clip(ref, env.ctrl_low, env.ctrl_high)

    def reset(self, env: BatchEnv, ids: np.ndarray, rng: np.random.Generator) -> None:
        """Home state and a fresh random phase per joint for copies ``ids``."""
        if self.phase.shape[0] != env.n:
            self.phase = np.zeros((env.n, 16))
        self.phase[ids] = rng.uniform(0, 2 * np.pi, (ids.size, 16))
        env.reset(ids)

    def command(self, env: BatchEnv, actions: np.ndarray) -> tuple[np.ndarray, None, None, None]:
        """Next reference plus a bounded residual; the wrist stays where it is."""
        return self._reference(env, 1) + self.action_scale * np.clip(actions, -1.0, 1.0), None, None, None

    def observe(self, env: BatchEnv) -> dict[str, np.ndarray]:
        """Joint state and the next two reference frames, the same for actor and critic."""
        obs = np.concatenate(
            [env.hand_qpos, 0.1 * env.hand_qvel, self._reference(env, 1), self._reference(env, 2)], axis=1
        )
        return {"actor": obs, "critic": obs}

    def reward(self, env: BatchEnv, actions: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Gaussian tracking kernel minus a small action penalty."""
        err = np.sum((env.hand_qpos - self._reference(env)) ** 2, axis=1)
        terms = {"tracking": np.exp(-err / self.sigma), "action_rate": -0.01 * np.sum(actions**2, axis=1)}
        return terms["tracking"] + terms["action_rate"], terms

    def terminated(self, env: BatchEnv) -> np.ndarray:
        """Tracking never ends early: episodes only time out."""
        return np.zeros(env.n, dtype=bool)

    def truncated(self, env: BatchEnv) -> np.ndarray:
        """No reference end: the env's max episode length cuts episodes."""
        return np.zeros(env.n, dtype=bool)

    def episode_end(self, env: BatchEnv, ids: np.ndarray) -> dict[str, float]:
        """Nothing to update between episodes."""
        return {}
