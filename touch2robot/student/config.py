"""Configuration of the student retargeter (defaults = the paper profile, Table VIII).

Table VIII fixes the history (16 steps), the geometry feature (32), the Transformer (4 layers,
8 heads), the tactile dropout (0.25) and the optimiser (AdamW, batch 128, lr 3e-4). What the
paper leaves open (model width, number of updates, loss weights, the held-out split) is named
here with the value used; the smoke and local profiles shrink sizes, never the recipe.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, model_validator

from schemas.vocabulary import Method


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Ablation(_Frozen):
    """Overrides of one ablation variant (None keeps the full model's value)."""

    use_tactile: bool | None = None
    use_geometry: bool | None = None
    tactile_dropout: float | None = Field(default=None, ge=0, le=1)


def default_ablations() -> dict[str, Ablation]:
    return {
        "no_tactile": Ablation(use_tactile=False),
        "no_geometry": Ablation(use_geometry=False),
        "no_dropout": Ablation(tactile_dropout=0.0),
    }


class StudentConfig(_Frozen):
    """Augmentation, model, distillation and reconstruction of the student."""

    # --- augmentation (paper: "a total of 400" training rollouts; read as 400 over all tasks,
    # balanced: augmented_rollouts / len(tasks) per task)
    teacher_method: str = Field(default=Method.TOUCH2ROBOT, description="whose teacher rollouts are distilled")
    augmented_rollouts: int = Field(
        default=400, ge=1, description="training rollouts in total, balanced over the tasks"
    )
    joint_noise_std: float = Field(
        default=0.1, ge=0, description="rad: N(0, std^2) per frame and joint, added to input and target alike"
    )
    # --- demonstrations: held out for reconstruction, and validation within the training ones
    held_out_fraction: float = Field(
        default=0.25, ge=0, lt=1, description="per task, demonstrations reconstructed and never trained on"
    )
    val_fraction: float = Field(
        default=0.2, ge=0, lt=1, description="per task, training demonstrations used for validation only"
    )
    # --- model (Table VIII: history, geometry, layers, heads)
    history: int = Field(default=16, ge=1, description="H: causal history in control steps")
    geometry_dim: int = Field(default=32, ge=1, description="PointNet feature of the object's surface points")
    pointnet_hidden: tuple[int, ...] = Field(default=(64, 128), min_length=1, description="shared per-point MLP widths")
    layers: int = Field(default=4, ge=1)
    heads: int = Field(default=8, ge=1)
    d_model: int = Field(default=128, ge=1, description="Transformer width (not given by the paper)")
    ff_dim: int = Field(default=256, ge=1, description="feed-forward width of each layer")
    dropout: float = Field(default=0.1, ge=0, lt=1, description="attention / feed-forward dropout")
    # --- inputs and ablation switches
    use_tactile: bool = Field(default=True, description="feed the human's tactile preference")
    use_geometry: bool = Field(default=True, description="feed the PointNet geometry feature")
    tactile_dropout: float = Field(
        default=0.25, ge=0, le=1, description="probability that a training window's whole preference is hidden"
    )
    ablations: dict[str, Ablation] = Field(
        default_factory=default_ablations, description="variants trained beside the full model"
    )
    # --- distillation (Table VIII: AdamW, batch 128, lr 3e-4)
    batch_size: int = Field(default=128, ge=1)
    lr: float = Field(default=3e-4, gt=0)
    weight_decay: float = Field(default=0.01, ge=0, description="AdamW (torch default)")
    steps: int = Field(default=20_000, ge=1, description="optimizer updates")
    joint_weight: float = Field(default=1.0, ge=0, description="loss weight of the joint-target MSE (rad^2)")
    wrist_weight: float = Field(
        default=1.0, ge=0, description="loss weight of the wrist-residual MSE (teacher action units)"
    )
    contact_weight: float = Field(default=0.1, ge=0, description="loss weight of the contact BCE")
    eval_interval: int = Field(default=500, ge=1, description="updates between validation passes (logged to MLflow)")
    checkpoint_interval: int = Field(default=1000, ge=1, description="updates between checkpoints (the resume point)")
    seed: int = 0

    @model_validator(mode="after")
    def _heads_divide_width(self) -> StudentConfig:
        if self.d_model % self.heads:
            raise ValueError(f"d_model={self.d_model} must be a multiple of heads={self.heads}")
        return self

    def variant(self, name: str) -> StudentConfig:
        """The configuration of ``"full"`` or of one ablation; a clear error for an unknown name."""
        if name == "full":
            return self
        if name not in self.ablations:
            raise KeyError(
                f"student variant {name!r} is neither 'full' nor in student.ablations (have {sorted(self.ablations)})"
            )
        return self.model_copy(update={k: v for k, v in self.ablations[name].model_dump().items() if v is not None})

    @property
    def variants(self) -> tuple[str, ...]:
        return ("full", *self.ablations)
