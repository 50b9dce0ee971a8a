"""Closed-loop evaluation of a trained Diffusion Policy in the batched MuJoCo env.

Episodes start from the reset states of the dataset's rollouts (seeded choice, seeded Gaussian
noise on the object's start x, y) and last the task's episode length. Every ``n_action_steps``
control steps the policy sees the last ``n_obs_steps`` observations (the first one repeated at the
start, as LeRobot does), predicts ``horizon`` actions and the ``n_action_steps`` from the current
step on are executed (Table IX: 24 predicted, 16 executed, then replan). Success is the task's
criterion at the episode's end; a Wilson interval bounds the success rate.

Two references put a success rate in context: the demonstrations' own commands replayed open loop
from the same starts (``replay_demonstrations``: what exact imitation would reach, given the start
jitter), and the policy's open-loop fit to its dataset against holding still (``action_fit``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from touch2robot.comparison.statistics import wilson_interval
from touch2robot.policy.config import VIDEO_BACKEND, PolicyConfig
from touch2robot.policy.dataset import (
    FPS,
    TACTILE_KEY,
    CameraRenderer,
    Rollout,
    environment_state,
    observation_state,
    recorded_commands,
    reset_to_first_rows,
    tactile_state,
)

# the GL backend is chosen when this is imported, before mujoco: keep it first
from touch2robot.sim import render as _render  # noqa: F401
from touch2robot.sim.config import SimConfig
from touch2robot.sim.env import BatchEnv
from touch2robot.sim.rsl_env import episode_steps
from touch2robot.sim.scene import Scene


@dataclass(frozen=True)
class EpisodeStarts:
    """Initial states of evaluation episodes: the rollouts each start is drawn from, and the
    (jittered) object poses."""

    rollouts: list[Rollout]
    object_pose: np.ndarray  # (E, 7)

    @property
    def source(self) -> list[str]:
        """The rollout id each start was drawn from."""
        return [r.rollout_id for r in self.rollouts]


def episode_starts(
    scene: Scene, rollouts: list[Rollout], episodes: int, seed: int, object_noise_m: float
) -> EpisodeStarts:
    """``episodes`` starts drawn (seeded, with replacement) from the rollouts' reset rows, the
    object's start x, y jittered by N(0, object_noise_m^2) (not the drawer: it sits in its slide)."""
    rng = np.random.default_rng(seed)
    chosen = [rollouts[i] for i in rng.integers(0, len(rollouts), episodes)]
    obj = np.stack([r.object_pose[0] for r in chosen])
    if not scene.is_drawer:
        obj[:, :2] += rng.normal(0.0, object_noise_m, (episodes, 2))
    return EpisodeStarts(chosen, obj)


@dataclass
class EvalResult:
    """Outcome of the evaluated episodes."""

    success: np.ndarray  # (E,) bool
    progress: np.ndarray  # (E,) final task progress
    steps: int  # control steps per episode
    replans: int  # policy inferences per episode
    videos: list[np.ndarray] = field(default_factory=list)  # per recorded episode (T, H, 2W, 3) uint8

    @property
    def success_rate(self) -> float:
        return float(self.success.mean())

    @property
    def wilson(self) -> tuple[float, float]:
        return wilson_interval(int(self.success.sum()), len(self.success))


def load_policy(policy_dir: Path, device: str | None = None):
    """A trained LeRobot Diffusion Policy folder -> (policy in eval mode, preprocessor, postprocessor)."""
    from lerobot.policies import make_pre_post_processors
    from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy

    overrides: dict[str, Any] = {"device": device} if device else {}
    policy = DiffusionPolicy.from_pretrained(str(policy_dir), **overrides)
    policy.eval()
    overrides = {"device_processor": {"device": policy.config.device}}
    pre, post = make_pre_post_processors(
        policy.config, pretrained_path=str(policy_dir), preprocessor_overrides=overrides
    )
    return policy, pre, post


def _observation(env: BatchEnv, renderer: CameraRenderer, observation: str) -> dict[str, np.ndarray]:
    images = renderer.render(env)
    obs = {f"observation.images.{cam}": img for cam, img in images.items()}
    obs["observation.state"] = observation_state(env).astype(np.float32)
    obs["observation.environment_state"] = environment_state(env, observation).astype(np.float32)
    obs[TACTILE_KEY] = tactile_state(env).astype(np.float32)
    return obs


def rollout_policy(
    policy,
    preprocessor,
    postprocessor,
    scene: Scene,
    sim: SimConfig,
    starts: EpisodeStarts,
    cfg: PolicyConfig,
    video_episodes: int = 0,
    steps: int | None = None,
) -> EvalResult:
    """Run the episodes of ``starts`` closed loop, ``cfg.eval_batch`` at a time as BatchEnv copies.
    ``steps`` defaults to the task's episode length. The first ``video_episodes`` are recorded
    (both cameras side by side). The diffusion noise is seeded with ``cfg.eval_seed``, so a re-run
    gives the same episodes (on the same hardware)."""
    import torch

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(cfg.eval_seed)
        return _rollout_policy(policy, preprocessor, postprocessor, scene, sim, starts, cfg, video_episodes, steps)


def _rollout_policy(
    policy,
    preprocessor,
    postprocessor,
    scene: Scene,
    sim: SimConfig,
    starts: EpisodeStarts,
    cfg: PolicyConfig,
    video_episodes: int,
    steps: int | None,
) -> EvalResult:
    n_obs, n_act = policy.config.n_obs_steps, policy.config.n_action_steps
    seen = tuple(k.removeprefix("observation.images.") for k in policy.config.image_features)
    renderer = CameraRenderer(scene, seen, cfg.image_size)
    # a state-only policy's episodes are filmed by the profile's cameras, for the videos alone
    filming = CameraRenderer(scene, cfg.cameras if video_episodes and not seen else (), cfg.image_size)
    successes, progress, videos = [], [], []
    replans = 0
    try:
        for first in range(0, len(starts.rollouts), cfg.eval_batch):
            ids = slice(first, first + cfg.eval_batch)
            env = BatchEnv(scene, sim, n_envs=len(starts.rollouts[ids]))
            try:
                reset_to_first_rows(env, starts.rollouts[ids], starts.object_pose[ids])
                horizon = steps or episode_steps(env)
                history: list[dict[str, np.ndarray]] = []
                frames: list[np.ndarray] = []
                record = max(0, min(video_episodes - first, env.n))
                replans = 0
                chunk = np.empty((env.n, 0, 23))
                for t in range(horizon):
                    obs = _observation(env, renderer, cfg.observation)
                    history = (history or [obs] * n_obs)[1:] + [obs]  # the first observation fills the window
                    if record:
                        views = filming.render(env, np.arange(record)) if not seen else {}
                        cams = [obs[k][:record] for k in obs if k.startswith("observation.images.")]
                        frames.append(np.concatenate(cams or list(views.values()), axis=2))
                    if t % n_act == 0:
                        chunk = _predict(policy, preprocessor, postprocessor, history)
                        replans += 1
                    action = chunk[:, t % n_act].astype(np.float64)
                    env.step(action[:, :16], action[:, 16:19], action[:, 19:23])
                successes.append(env.success.copy())
                progress.append(env.progress.copy())
                if record:
                    clip = np.stack(frames)
                    videos.extend(clip[:, i] for i in range(record))
            finally:
                env.close()
    finally:
        renderer.close()
        filming.close()
    return EvalResult(np.concatenate(successes), np.concatenate(progress), horizon, replans, videos)


def replay_demonstrations(
    scene: Scene, sim: SimConfig, starts: EpisodeStarts, cfg: PolicyConfig, steps: int | None = None
) -> EvalResult:
    """The ceiling of a policy that reproduces its demonstrations exactly: each start's rollout
    commands (the dataset's actions) executed open loop from that start, object jitter included,
    for the same episode length (a rollout that has ended holds its last command)."""
    successes, progress = [], []
    for first in range(0, len(starts.rollouts), cfg.eval_batch):
        ids = slice(first, first + cfg.eval_batch)
        batch = starts.rollouts[ids]
        env = BatchEnv(scene, sim, n_envs=len(batch))
        try:
            reset_to_first_rows(env, batch, starts.object_pose[ids])
            horizon = steps or episode_steps(env)
            for t in range(horizon):
                targets, wrist = recorded_commands(batch, t)
                env.step(targets, wrist[:, :3], wrist[:, 3:])
            successes.append(env.success.copy())
            progress.append(env.progress.copy())
        finally:
            env.close()
    return EvalResult(np.concatenate(successes), np.concatenate(progress), horizon, replans=0)


def _predict(policy, preprocessor, postprocessor, history: list[dict[str, np.ndarray]]) -> np.ndarray:
    """(N, n_action_steps, 23) actions from a window of observations (oldest first)."""
    import torch

    batch = {}
    for key in history[0]:
        stacked = torch.from_numpy(np.stack([h[key] for h in history], axis=1))  # (N, n_obs, ...)
        if key.startswith("observation.images."):
            stacked = (
                stacked.permute(0, 1, 4, 2, 3).float() / 255.0
            )  # (N, n_obs, 3, H, W) in [0, 1], as the dataset gives
        batch[key] = stacked
    return _predict_batch(policy, preprocessor, postprocessor, batch)


def _predict_batch(policy, preprocessor, postprocessor, batch: dict) -> np.ndarray:
    """(N, n_action_steps, 23) actions from observation windows as the dataset gives them."""
    import torch

    batch = preprocessor(batch)
    with torch.no_grad():
        policy.reset()  # empty queues: predict from this window, not from cached observations
        actions = policy.predict_action_chunk(batch)  # normalised (N, n_action_steps, 23)
    return postprocessor(actions).cpu().numpy()


@dataclass(frozen=True)
class ActionFit:
    """Open-loop fit of a policy to its own dataset: for sampled frames, the actions it would
    execute (``n_action_steps`` from the frame on) against the recorded ones, as mean absolute
    errors; and the same for *holding* the frame's state (joint positions, wrist pose) as the
    command. A policy no better than holding still has not learned its demonstrations, whatever
    its loss says: closed-loop failures can then be put on training, not on the task."""

    frames: int
    joint_err_rad: float
    wrist_err_mm: float  # wrist position
    hold_joint_err_rad: float
    hold_wrist_err_mm: float


def action_fit(
    policy,
    preprocessor,
    postprocessor,
    dataset_root: Path,
    repo_id: str,
    frames: int = 64,
    seed: int = 0,
    batch_size: int = 16,
) -> ActionFit:
    """``ActionFit`` of ``policy`` on ``frames`` frames of a LeRobot dataset (drawn without
    replacement; frames and diffusion noise seeded by ``seed``); action steps past an episode's end
    (LeRobot's padding) are left out."""
    import torch

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        return _action_fit(policy, preprocessor, postprocessor, dataset_root, repo_id, frames, seed, batch_size)


def _action_fit(
    policy, preprocessor, postprocessor, dataset_root: Path, repo_id: str, frames: int, seed: int, batch_size: int
) -> ActionFit:
    import torch
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    c = policy.config
    keys = (*c.image_features, "observation.state", *(["observation.environment_state"] if c.env_state_feature else []))
    windows = {
        **{k: [i / FPS for i in c.observation_delta_indices] for k in keys},
        "action": [i / FPS for i in c.action_delta_indices],
    }
    dataset = LeRobotDataset(repo_id, root=dataset_root, delta_timestamps=windows, video_backend=VIDEO_BACKEND)
    rng = np.random.default_rng(seed)
    chosen = np.sort(rng.choice(len(dataset), min(frames, len(dataset)), replace=False))
    now = c.n_obs_steps - 1  # the frame's own step in the action window
    executed = slice(now, now + c.n_action_steps)
    errors, holds, valid = [], [], []
    for part in np.array_split(chosen, max(1, -(-len(chosen) // batch_size))):
        items: list[dict] = [dataset[int(i)] for i in part]  # pyright: ignore[reportAssignmentType]  an int index gives one frame
        stacked = {k: torch.stack([it[k] for it in items]) for k in (*keys, "action", "action_is_pad")}
        predicted = _predict_batch(policy, preprocessor, postprocessor, {k: stacked[k] for k in keys})
        recorded = stacked["action"][:, executed].numpy()
        state = stacked["observation.state"][:, -1].numpy()[:, None]  # (k, 1, 23): the frame's state
        errors.append(np.abs(predicted - recorded))
        holds.append(np.abs(state - recorded))
        valid.append(~stacked["action_is_pad"][:, executed].numpy())
    err, hold, ok = np.concatenate(errors), np.concatenate(holds), np.concatenate(valid)
    joint = lambda e: float(e[ok][:, :16].mean())  # noqa: E731
    wrist = lambda e: float(1000.0 * e[ok][:, 16:19].mean())  # noqa: E731
    return ActionFit(len(chosen), joint(err), wrist(err), joint(hold), wrist(hold))


@dataclass(frozen=True)
class PolicyEvaluation:
    """A trained policy's closed-loop episodes, its open-loop fit, and its demonstrations replayed
    from the same starts (the ceiling of exact imitation)."""

    closed_loop: EvalResult
    fit: ActionFit
    replay: EvalResult


def evaluate(
    policy_dir: Path,
    dataset_root: Path,
    repo_id: str,
    scene: Scene,
    sim: SimConfig,
    rollouts: list[Rollout],
    cfg: PolicyConfig,
    video_episodes: int = 0,
) -> PolicyEvaluation:
    """``cfg.eval_episodes`` seeded episodes of the policy in ``policy_dir`` started from
    ``rollouts``' reset rows, its fit to its dataset, and the replay ceiling from the same starts."""
    starts = episode_starts(scene, rollouts, cfg.eval_episodes, cfg.eval_seed, cfg.object_noise_m)
    policy, pre, post = load_policy(Path(policy_dir), cfg.device)
    closed = rollout_policy(policy, pre, post, scene, sim, starts, cfg, video_episodes=video_episodes)
    fit = action_fit(policy, pre, post, Path(dataset_root), repo_id, seed=cfg.eval_seed)
    return PolicyEvaluation(closed, fit, replay_demonstrations(scene, sim, starts, cfg, steps=closed.steps))


def write_video(frames: np.ndarray, path: Path, fps: int = 20) -> Path:
    """(T, H, W, 3) uint8 frames -> H.264 MP4 (PyAV)."""
    import av

    path.parent.mkdir(parents=True, exist_ok=True)
    h, w = frames.shape[1:3]
    with av.open(str(path), mode="w") as container:
        stream = container.add_stream("libx264", rate=fps)
        stream.width, stream.height = w - w % 2, h - h % 2
        stream.pix_fmt = "yuv420p"
        for frame in frames:
            packet = stream.encode(
                av.VideoFrame.from_ndarray(np.ascontiguousarray(frame[: stream.height, : stream.width]), format="rgb24")
            )
            container.mux(packet)
        container.mux(stream.encode())
    return path
