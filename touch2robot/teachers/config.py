"""Configuration of the teachers: PPO (Table VII), the reward terms, and the method variants.

Every method shares one objective (``touch2robot.teachers.objective.DemoTracking``); a method is a
set of reward weights plus at most one switch of its own (ConTrack's adaptive trade-off,
DexMachina's virtual object assistance). The paper values are the defaults.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from schemas.vocabulary import TEACHER_METHODS, Method
from touch2robot.scenes import TASKS
from touch2robot.sim.config import SimConfig


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class PPOConfig(_Frozen):
    """rsl-rl-lib's OnPolicyRunner / PPO settings (Table VII)."""

    num_steps_per_env: int = Field(default=512, ge=1, description="rollout length per env per iteration")
    max_iterations: int = Field(default=1500, ge=1, description="PPO iterations per teacher")
    num_mini_batches: int = Field(default=4, ge=1)
    num_learning_epochs: int = Field(default=5, ge=1)
    hidden_dims: tuple[int, ...] = (1024, 1024, 512)
    activation: str = "elu"
    learning_rate: float = Field(default=3e-4, gt=0)
    clip_param: float = Field(default=0.2, gt=0)
    max_grad_norm: float = Field(default=1.0, gt=0)
    gamma: float = Field(default=0.96, gt=0, le=1)
    lam: float = Field(default=0.95, gt=0, le=1)
    init_noise_std: float = Field(default=0.8, gt=0)
    desired_kl: float = Field(default=0.016, gt=0)
    entropy_coef: float = Field(default=0.0, ge=0)
    value_loss_coef: float = Field(default=1.0, ge=0)
    schedule: Literal["adaptive", "fixed"] = "adaptive"
    save_interval: int = Field(
        default=50, ge=1, description="iterations between checkpoints (each one an MLflow artefact)"
    )
    # None follows sim.threads: the update runs while the physics threads sit idle. The count is fixed
    # (not the machine's cores) because sums split over another number of threads round differently.
    update_threads: int | None = Field(
        default=None, ge=1, description="torch threads in the PPO update (collection: 1); None = sim.threads"
    )


class RewardWeights(_Frozen):
    """Weights of the named reward terms (0 switches a term off). Each term is logged alone."""

    object_pos: float = 1.0  # exp(-|p - p_ref| / sigma_pos); drawer: opening error instead
    object_rot: float = 0.5  # exp(-angle(q, q_ref) / sigma_rot); not for the drawer
    imitation: float = 0.5  # exp(-|q_hand - q_ref|^2 / sigma_joint)
    tactile: float = 0.0  # touch2robot: per-step F1 of the 8 sim contacts vs the human preference
    contact: float = 0.0  # contrack / dexmachina: regions reach their geometric contact points
    action_rate: float = 0.05  # -mean (a_t - a_(t-1))^2 over the 22 action components
    energy: float = 0.002  # -sum |servo torque x joint speed|
    termination: float = 2.0  # one-off penalty when tracking is lost


class ContrackConfig(_Frozen):
    """ConTrack's adaptive task-style trade-off: maximise style (imitation + contact) subject to an
    object-tracking return >= ``alpha`` x the best return so far on the clip, by dual ascent on a
    per-clip multiplier (reward = (style + lambda task) / (1 + lambda))."""

    enabled: bool = False
    alpha: float = Field(default=0.9, gt=0, le=1)
    dual_lr: float = Field(default=0.5, gt=0, description="step of lambda per unit of relative constraint violation")
    lambda_init: float = Field(default=1.0, ge=0)
    lambda_max: float = Field(default=20.0, gt=0)


class AssistanceConfig(_Frozen):
    """DexMachina's virtual object assistance: a PD controller (plus gravity compensation) pulls
    the object towards its reference pose; the gain factor starts at 1 and is multiplied by
    ``decay`` whenever the mean task reward of recently finished episodes exceeds ``threshold``
    (of its maximum), until it falls below ``min_gain`` and the object is on its own."""

    enabled: bool = False
    frequency_hz: float = Field(
        default=2.0, gt=0, description="natural frequency of the PD pull at gain 1 (mass-scaled)"
    )
    damping_ratio: float = Field(default=1.0, gt=0)
    gravity_compensation: bool = True
    threshold: float = Field(
        default=0.6, gt=0, le=1, description="task reward per step (fraction of its max) that triggers a decay"
    )
    decay: float = Field(default=0.8, gt=0, lt=1)
    min_gain: float = Field(default=0.05, gt=0)
    window_episodes: int = Field(default=50, ge=1, description="finished episodes averaged before each decision")


class MethodConfig(_Frozen):
    """One method variant: reward weights plus its own switch."""

    rewards: RewardWeights = RewardWeights()
    contrack: ContrackConfig = ContrackConfig()
    assistance: AssistanceConfig = AssistanceConfig()


def default_methods() -> dict[str, MethodConfig]:
    """The three teacher variants. Only the contact signal and each method's own mechanism differ."""
    return {
        Method.TOUCH2ROBOT: MethodConfig(rewards=RewardWeights(tactile=1.0)),
        Method.CONTRACK: MethodConfig(rewards=RewardWeights(contact=1.0), contrack=ContrackConfig(enabled=True)),
        Method.DEXMACHINA: MethodConfig(rewards=RewardWeights(contact=0.5), assistance=AssistanceConfig(enabled=True)),
    }


class TeacherConfig(_Frozen):
    """Teachers per task and method, and the rollouts they produce."""

    tasks: tuple[str, ...] = TASKS
    methods: tuple[Method, ...] = TEACHER_METHODS
    sim: SimConfig = SimConfig()
    ppo: PPOConfig = PPOConfig()
    variants: dict[str, MethodConfig] = Field(default_factory=default_methods)
    # Residual ranges: with Table VII's initial noise (std 0.8 per unit action) a wider range
    # (0.25 rad, 4 cm, 0.3 rad) let local-profile teachers trade the object for contacts (Rotate:
    # every deterministic rollout lost the object at 7.7 of 9.4 s, success 0 after 240
    # iterations); these keep it (Rotate 0.88, Wipe 1.0 after 80 iterations).
    action_scale: float = Field(
        default=0.15, gt=0, description="rad: joint target = kinematic reference + scale x clip(action, -1, 1)"
    )
    wrist_pos_scale_m: float = Field(
        default=0.02, ge=0, description="m: wrist position residual per unit action (0 = the kinematic wrist)"
    )
    wrist_rot_scale_rad: float = Field(default=0.15, ge=0, description="rad: wrist rotation residual per unit action")
    sigma_pos: float = Field(default=0.02, gt=0, description="m, object position kernel")
    sigma_rot: float = Field(default=0.3, gt=0, description="rad, object orientation kernel")
    sigma_joint: float = Field(default=0.5, gt=0, description="rad^2, hand imitation kernel")
    sigma_contact: float = Field(default=0.02, gt=0, description="m, contact point kernel")
    lost_pos_m: float = Field(default=0.06, gt=0, description="object (or drawer opening) error that ends an episode")
    lost_rot_rad: float = Field(default=1.2, gt=0, description="object orientation error that ends an episode")
    grace_steps: int = Field(default=5, ge=0, description="steps after reset before tracking can be lost")
    contact_margin_m: float = Field(
        default=0.005, ge=0, description="ConTrack: hand segment within this of the surface = contact"
    )
    rollouts_per_task: int = Field(default=30, ge=1, description="deterministic teacher rollouts per task and method")
    seed: int = 0

    @field_validator("methods")
    @classmethod
    def _only_teacher_methods(cls, methods: tuple[Method, ...]) -> tuple[Method, ...]:
        others = [m for m in methods if m not in TEACHER_METHODS]
        if others:
            raise ValueError(f"{', '.join(others)} has no PPO teacher; teacher methods: {', '.join(TEACHER_METHODS)}")
        return methods

    def method(self, name: str) -> MethodConfig:
        """The variant of a method; a clear error for an unknown one."""
        if name not in self.variants:
            raise KeyError(f"teacher method {name!r} has no variant in teacher.variants (have {sorted(self.variants)})")
        return self.variants[name]
