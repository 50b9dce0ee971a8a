"""The student network: a PointNet-style encoder of the object's surface points (shared
per-point MLP + symmetric max pool -> ``geometry_dim``) and a causal Transformer over the last
``history`` steps of inputs (``touch2robot.student.features``) with the geometry feature fed to
every step. Per step it outputs 16 absolute joint targets (a residual added to the kinematic
joints of the step: input and target share the augmentation noise, the residual does not),
the 6-d wrist residual (``features.WRIST_UNITS``) and 8 contact logits.

Input normalisation (mean / std of the training inputs) is part of the module, so a saved
model is self-contained. ``ServingStudent`` is the single-tensor form logged to MLflow.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from touch2robot.student.config import StudentConfig
from touch2robot.student.features import INPUT_DIM, JOINTS, NUM_JOINTS, OUTPUT_DIM, TACTILE, WRIST_DIM


class PointNetEncoder(nn.Module):
    """Shared per-point MLP, max pool over the points, linear projection."""

    def __init__(self, hidden: tuple[int, ...], out_dim: int) -> None:
        super().__init__()
        layers, width = [], 3
        for h in hidden:
            layers += [nn.Linear(width, h), nn.ReLU()]
            width = h
        self.mlp = nn.Sequential(*layers)
        self.out = nn.Linear(width, out_dim)

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        """(K, P, 3) -> (K, out_dim)."""
        return self.out(self.mlp(points).max(dim=1).values)


class StudentNet(nn.Module):
    # registered buffers: saved with the weights, not trained
    input_mean: torch.Tensor
    input_std: torch.Tensor
    causal_mask: torch.Tensor

    def __init__(self, cfg: StudentConfig) -> None:
        super().__init__()
        self.history = cfg.history
        self.use_tactile = cfg.use_tactile
        self.use_geometry = cfg.use_geometry
        self.geometry_dim = cfg.geometry_dim
        self.register_buffer("input_mean", torch.zeros(INPUT_DIM))
        self.register_buffer("input_std", torch.ones(INPUT_DIM))
        self.register_buffer(
            "causal_mask", torch.triu(torch.ones(cfg.history, cfg.history, dtype=torch.bool), diagonal=1)
        )
        self.pointnet = PointNetEncoder(cfg.pointnet_hidden, cfg.geometry_dim)
        self.embed = nn.Linear(INPUT_DIM + cfg.geometry_dim, cfg.d_model)
        self.position = nn.Parameter(0.02 * torch.randn(cfg.history, cfg.d_model))
        layer = nn.TransformerEncoderLayer(
            cfg.d_model, cfg.heads, cfg.ff_dim, cfg.dropout, batch_first=True, norm_first=True
        )
        self.encoder = nn.TransformerEncoder(layer, cfg.layers, enable_nested_tensor=False)
        self.norm = nn.LayerNorm(cfg.d_model)
        self.head = nn.Linear(cfg.d_model, OUTPUT_DIM)
        nn.init.zeros_(self.head.bias)
        nn.init.normal_(self.head.weight, std=1e-3)  # start at "copy the kinematic joints"

    def set_normalisation(self, inputs: torch.Tensor) -> None:
        """Input statistics from the training inputs (N, INPUT_DIM); the binary tactile channels
        keep mean 0 / std 1 so that hidden (all zero) stays zero."""
        mean, std = inputs.mean(dim=0), inputs.std(dim=0).clamp_min(1e-3)
        mean[TACTILE], std[TACTILE] = 0.0, 1.0
        self.input_mean.copy_(mean)
        self.input_std.copy_(std)

    def geometry(self, points: torch.Tensor) -> torch.Tensor:
        """(K, P, 3) object-frame surface points -> (K, geometry_dim); zeros without geometry."""
        if not self.use_geometry:
            return points.new_zeros(points.shape[0], self.geometry_dim)
        return self.pointnet(points)

    def forward(self, window: torch.Tensor, geometry: torch.Tensor) -> torch.Tensor:
        """(B, L, INPUT_DIM) inputs (L <= history, oldest first) and (B, geometry_dim) features
        -> (B, L, OUTPUT_DIM): joint targets (rad), wrist residual, contact logits."""
        if not self.use_tactile:
            window = torch.cat([window[..., : TACTILE.start], torch.zeros_like(window[..., TACTILE])], dim=-1)
        B, L, _ = window.shape
        x = (window - self.input_mean) / self.input_std
        x = torch.cat([x, geometry[:, None, :].expand(B, L, -1)], dim=-1)
        h = self.embed(x) + self.position[:L]
        h = self.norm(self.encoder(h, mask=self.causal_mask[:L, :L], is_causal=True))
        out = self.head(h)
        joints = window[..., JOINTS] + out[..., :NUM_JOINTS]
        return torch.cat([joints, out[..., NUM_JOINTS:]], dim=-1)


def split_outputs[T: (torch.Tensor, np.ndarray)](out: T) -> tuple[T, T, T]:
    """(..., OUTPUT_DIM) -> joints (..., 16), wrist residual (..., 6), contact logits (..., 8)."""
    return out[..., :NUM_JOINTS], out[..., NUM_JOINTS : NUM_JOINTS + WRIST_DIM], out[..., NUM_JOINTS + WRIST_DIM :]


class ServingStudent(nn.Module):
    """One float32 row per query: the last ``history`` input steps (oldest first, flattened)
    followed by the object's ``points`` surface points (object frame, flattened) -> the newest
    step's outputs (OUTPUT_DIM): what MLflow's pyfunc serves (a single tensor in and out)."""

    def __init__(self, net: StudentNet, points: int) -> None:
        super().__init__()
        self.net = net
        self.points = points

    def forward(self, packed: torch.Tensor) -> torch.Tensor:
        H = self.net.history
        window = packed[:, : H * INPUT_DIM].reshape(-1, H, INPUT_DIM)
        cloud = packed[:, H * INPUT_DIM :].reshape(-1, self.points, 3)
        return self.net(window, self.net.geometry(cloud))[:, -1]
