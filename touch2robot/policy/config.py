"""Configuration of the policy stage (defaults = the paper profile, Table IX).

Robot demonstrations as LeRobot datasets (20 Hz, two RGB views), LeRobot's Diffusion Policy
trained on them, and its closed-loop evaluation in the batched MuJoCo env. Everything not named
here is LeRobot's own default (``DiffusionConfig``, ``TrainPipelineConfig``)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from schemas.vocabulary import Origin

# The datasets hold images, not video, so no decoder is needed; naming one stops LeRobot probing
# torchcodec, which fails without system FFmpeg libraries and logs a traceback per FFmpeg version.
VIDEO_BACKEND = "pyav"


class PolicyConfig(BaseModel):
    """Dataset, Diffusion Policy training (Table IX) and closed-loop evaluation settings."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    # --- datasets
    tasks: tuple[str, ...] | None = Field(default=None, description="tasks to learn; None = every task with rollouts")
    methods: tuple[str, ...] | None = Field(
        default=None, description="data-collection methods to compare; None = every method with rollouts"
    )
    origins: tuple[str, ...] = Field(
        default=(Origin.STUDENT, Origin.TEACHER, Origin.KINEMATIC),
        min_length=1,
        description="rollout origins a method's dataset may come from, most preferred first "
        "(e.g. [teacher, kinematic] compares every method on its teacher's rollouts)",
    )
    same_demonstrations: bool = Field(
        default=True,
        description="one episode per human demonstration (the first rollout following it), and only the demonstrations "
        "every compared method of the task has: datasets that differ only in how each method turned the same human "
        "demonstrations into robot ones; false = every rollout of each method's file",
    )
    observation: Literal["images", "state"] = Field(
        default="images",
        description="what the policy sees: 'images' = both camera views (Table IX), the robot state and the tactile "
        "forces; 'state' = no cameras: the robot state, and the tactile forces with the object's pose and the drawer's "
        "opening as observation.environment_state (no rendering and no image encoder: a CPU-sized policy)",
    )
    # ResNet-18 (BatchNorm) needs feature maps larger than 1x1: below about 40 px training fails
    image_size: int = Field(default=224, ge=40, description="square RGB image side (px) of both camera views")
    cameras: tuple[str, ...] = Field(
        default=("cam_left", "cam_right"), min_length=1, description="scene cameras recorded"
    )
    max_rollouts: int | None = Field(
        default=None, ge=1, description="rollouts per task x method put in a dataset; None = all"
    )
    replay_batch: int = Field(
        default=16, ge=1, description="rollouts replayed (and rendered) together as copies of one BatchEnv"
    )
    # --- Diffusion Policy (Table IX); None = LeRobot's default
    n_obs_steps: int = Field(default=5, ge=1, description="observation steps the policy conditions on")
    horizon: int = Field(default=24, ge=1, description="action steps predicted per inference")
    n_action_steps: int = Field(default=16, ge=1, description="predicted steps executed before replanning")
    lr: float = Field(default=1e-4, gt=0, description="Adam learning rate")
    weight_decay: float = Field(default=1e-6, ge=0, description="Adam weight decay")
    batch_size: int = Field(default=64, ge=1)
    steps: int = Field(default=50_000, ge=1, description="optimizer updates")
    down_dims: tuple[int, ...] | None = Field(
        default=None, min_length=1, description="UNet widths (small profiles shrink it)"
    )
    num_inference_steps: int | None = Field(default=None, ge=1, description="reverse diffusion steps at inference")
    scheduler_warmup_steps: int | None = Field(default=None, ge=0, description="LR warm-up updates")
    # --- training loop
    save_freq: int = Field(default=10_000, ge=1, description="LeRobot checkpoint every N updates (the resume point)")
    keep_checkpoints: int = Field(
        default=1,
        ge=1,
        description="newest checkpoints kept in a training folder (older ones are deleted once a newer one is "
        "complete): each holds the model and its Adam state, 277 MB at the smoke profile's size",
    )
    log_freq: int = Field(default=100, ge=1, description="loss and learning rate to MLflow every N updates")
    num_workers: int = Field(default=4, ge=0, description="data-loader worker processes (loader 'lerobot' only)")
    loader: Literal["lerobot", "frames"] = Field(
        default="frames",
        description="where training batches come from: 'frames' = touch2robot.policy.loader.FrameLoader (every frame "
        "decoded once into a cached memory map, batches gathered by index, images made float on the device; the same "
        "batches in the same order, bench/policy_loader.py: many times LeRobot's rate), 'lerobot' = LeRobot's "
        "DataLoader (PNG decodes per sample, num_workers processes)",
    )
    device: str | None = Field(default=None, description="torch device; None = CUDA when available, else CPU")
    seed: int = Field(default=1000, description="training seed (LeRobot's default)")
    # --- closed-loop evaluation
    eval_episodes: int = Field(default=50, ge=1, description="seeded episodes per task x method")
    eval_batch: int = Field(default=25, ge=1, description="episodes run together as copies of one BatchEnv")
    eval_seed: int = Field(default=0)
    object_noise_m: float = Field(default=0.005, ge=0, description="std of the object's start-position noise (x, y)")
    video_episodes: int = Field(default=3, ge=0, description="episodes recorded as MLflow video artefacts")

    @model_validator(mode="after")
    def _consistent_horizon(self) -> PolicyConfig:
        # LeRobot executes actions from the current observation on: n_obs - 1 + n_action <= horizon
        if self.n_action_steps > self.horizon - self.n_obs_steps + 1:
            raise ValueError(
                f"n_action_steps={self.n_action_steps} exceeds horizon - n_obs_steps + 1 = "
                f"{self.horizon - self.n_obs_steps + 1}"
            )
        levels = len(self.down_dims) if self.down_dims is not None else 3
        if self.horizon % 2**levels:
            raise ValueError(f"horizon={self.horizon} must be a multiple of 2^len(down_dims) = {2**levels}")
        return self
