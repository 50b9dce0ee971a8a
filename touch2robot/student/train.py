"""Distillation of the student (Table VIII): AdamW on windows of ``history`` steps drawn from the
augmented training rollouts, loss = joint MSE (rad^2) + wrist-residual MSE + contact BCE with the
configured weights, every position of a window supervised (a causal model: each prefix is a
sample), padding positions excluded.

Tactile dropout (``tactile_dropout``): per training window, with that probability the whole
preference of all its steps is hidden (preference channels and the availability flag set to 0),
so the same model also runs without a glove. Validation uses whole validation demonstrations
(never trained on), all windows, preference as given.

A checkpoint (model, optimizer, sampling generator and RNG states, curves) is written every
``checkpoint_interval`` updates by temp file + rename; ``train`` continues from it when present.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import torch
import torch.nn.functional as F

from touch2robot.student.config import StudentConfig
from touch2robot.student.features import TACTILE, WRIST_UNITS, step_inputs, wrist_residual
from touch2robot.student.model import StudentNet, split_outputs
from touch2robot.teachers.rollouts import column

CHECKPOINT = "checkpoint.pt"
VAL_WINDOWS = 8192  # validation windows at most (evenly spaced), to bound each pass on a CPU


@dataclass
class Windows:
    """Sequences flattened, each left-padded with ``history`` - 1 copies of its first step;
    window w covers rows ``starts[w]`` .. ``starts[w] + history - 1`` and ends at a real step."""

    inputs: torch.Tensor  # (N, INPUT_DIM)
    joints: torch.Tensor  # (N, 16) target
    wrist: torch.Tensor  # (N, 6) target, WRIST_UNITS
    contact: torch.Tensor  # (N, 8) float target
    valid: torch.Tensor  # (N,) bool: not padding
    cloud: torch.Tensor  # (N,) index of the object's point cloud
    starts: torch.Tensor  # (W,)
    history: int

    def __len__(self) -> int:
        return len(self.starts)

    def batch(self, which: torch.Tensor) -> dict[str, torch.Tensor]:
        rows = self.starts[which][:, None] + torch.arange(self.history)
        return {
            "inputs": self.inputs[rows],
            "joints": self.joints[rows],
            "wrist": self.wrist[rows],
            "contact": self.contact[rows],
            "valid": self.valid[rows],
            "cloud": self.cloud[rows[:, -1]],
        }


def windows_from_table(table: pa.Table, tasks: list[str], history: int) -> Windows:
    """``student_dataset`` rows (any tasks and splits, sorted by sample and step) as windows;
    ``tasks[i]`` is the object of point cloud i."""
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("inputs", "joints", "wrist", "contact", "valid", "cloud")}
    starts, offset = [], 0
    ids = table["sample_id"].to_numpy(zero_copy_only=False)
    bounds = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1], True]) if len(ids) else np.array([0])
    for a, b in itertools.pairwise(bounds):
        rows = table.slice(a, b - a)
        wrist = column(rows, "wrist_pose")
        arrays = {
            "inputs": step_inputs(
                column(rows, "kinematic_joints"), wrist, column(rows, "object_pose"), column(rows, "preference")
            ),
            "joints": column(rows, "target_joints"),
            "wrist": wrist_residual(wrist, column(rows, "target_wrist")) / WRIST_UNITS,
            "contact": column(rows, "contact"),
            "valid": np.ones(b - a, dtype=bool),
            "cloud": np.full(b - a, tasks.index(rows["task"][0].as_py())),
        }
        for k, v in arrays.items():
            pad = np.repeat(v[:1], history - 1, axis=0)
            if k == "valid":
                pad = np.zeros_like(pad)
            parts[k].append(np.concatenate([pad, v]))
        starts.append(offset + np.arange(b - a))
        offset += b - a + history - 1
    cat = {k: np.concatenate(v) if v else np.zeros((0,)) for k, v in parts.items()}
    as_float = lambda k: torch.as_tensor(cat[k], dtype=torch.float32)  # noqa: E731
    return Windows(
        inputs=as_float("inputs"),
        joints=as_float("joints"),
        wrist=as_float("wrist"),
        contact=as_float("contact"),
        valid=torch.as_tensor(cat["valid"], dtype=torch.bool),
        cloud=torch.as_tensor(cat["cloud"], dtype=torch.long),
        starts=torch.as_tensor(np.concatenate(starts) if starts else np.zeros(0), dtype=torch.long),
        history=history,
    )


def hide_tactile(inputs: torch.Tensor, hidden: torch.Tensor) -> torch.Tensor:
    """Zero the preference and its flag of the windows where ``hidden`` (B,) is set."""
    keep = torch.ones_like(inputs)
    keep[..., TACTILE] = (~hidden).float()[:, None, None]
    return inputs * keep


def losses(
    net: StudentNet, batch: dict[str, torch.Tensor], geometry: torch.Tensor, cfg: StudentConfig
) -> dict[str, torch.Tensor]:
    out = net(batch["inputs"], geometry[batch["cloud"]])
    joints, wrist, logits = split_outputs(out)
    valid = batch["valid"]
    terms = {
        "joint": F.mse_loss(joints[valid], batch["joints"][valid]),
        "wrist": F.mse_loss(wrist[valid], batch["wrist"][valid]),
        "contact": F.binary_cross_entropy_with_logits(logits[valid], batch["contact"][valid]),
    }
    terms["loss"] = (
        cfg.joint_weight * terms["joint"] + cfg.wrist_weight * terms["wrist"] + cfg.contact_weight * terms["contact"]
    )
    return terms


@torch.inference_mode()
def validate(
    net: StudentNet, val: Windows, clouds: torch.Tensor, cfg: StudentConfig, batch: int = 1024
) -> dict[str, float]:
    """Mean loss terms over the validation windows (NaN when there are none)."""
    if len(val) == 0:
        return {"loss": math.nan, "joint": math.nan, "wrist": math.nan, "contact": math.nan}
    net.eval()
    which = torch.linspace(0, len(val) - 1, min(len(val), VAL_WINDOWS)).round().long().unique()
    geometry = net.geometry(clouds)
    sums: dict[str, float] = {}
    for part in which.split(batch):
        for k, v in losses(net, val.batch(part), geometry, cfg).items():
            sums[k] = sums.get(k, 0.0) + float(v) * len(part)
    return {k: v / len(which) for k, v in sums.items()}


@dataclass
class TrainResult:
    net: StudentNet
    steps: int
    initial_val: dict[str, float]
    final_val: dict[str, float]
    resumed_from: int
    curve: list[dict[str, float]] = field(default_factory=list)  # validation passes: {"step", "loss", ...}


def _save(path: Path, state: dict) -> None:
    tmp = path.with_suffix(".tmp")
    torch.save(state, tmp)
    tmp.replace(path)


def train(
    train_set: Windows,
    val_set: Windows,
    clouds: torch.Tensor,
    cfg: StudentConfig,
    folder: Path,
    on_log: Callable[[int, dict[str, float]], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
) -> TrainResult:
    """Distil the student on ``train_set`` (``clouds`` (K, P, 3): the objects' surface points),
    validating on ``val_set``; resumes from ``folder``/checkpoint.pt when present. ``should_stop()``
    (asked after every update) turning true ends the call early, checkpointed where it is: the
    checkpoint holds every RNG and the unlogged loss sums, so a resumed training is the one that
    never stopped."""
    if len(train_set) == 0:
        raise ValueError("no training windows: the student dataset has no training rows")
    folder.mkdir(parents=True, exist_ok=True)
    log = on_log or (lambda step, metrics: None)
    torch.manual_seed(cfg.seed)
    net = StudentNet(cfg)
    net.set_normalisation(train_set.inputs[train_set.valid])
    optimizer = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    generator = torch.Generator().manual_seed(cfg.seed)
    path = folder / CHECKPOINT
    if path.is_file():
        state = torch.load(path, weights_only=False)
        net.load_state_dict(state["net"])
        optimizer.load_state_dict(state["optimizer"])
        generator.set_state(state["generator"])
        torch.set_rng_state(state["torch_rng"])
        step, initial, curve = state["step"], state["initial_val"], state["curve"]
        running = state.get("running", {})
        resumed_from = step
    else:
        step, resumed_from = 0, 0
        initial = validate(net, val_set, clouds, cfg)
        curve = [{"step": 0, **initial}]
        log(0, {f"val/{k}": v for k, v in initial.items()})
        running: dict[str, float] = {}
    while step < cfg.steps:
        net.train()
        which = torch.randint(len(train_set), (cfg.batch_size,), generator=generator)
        batch = train_set.batch(which)
        hidden = torch.rand(cfg.batch_size, generator=generator) < cfg.tactile_dropout
        batch["inputs"] = hide_tactile(batch["inputs"], hidden)
        terms = losses(net, batch, net.geometry(clouds), cfg)
        optimizer.zero_grad(set_to_none=True)
        terms["loss"].backward()
        optimizer.step()
        step += 1
        for k, v in terms.items():
            running[k] = running.get(k, 0.0) + v.item()
        if step % cfg.eval_interval == 0 or step == cfg.steps:
            n = step - (curve[-1]["step"] if curve else 0)
            val = validate(net, val_set, clouds, cfg)
            curve.append({"step": step, **val})
            log(
                step,
                {
                    **{f"train/{k}": v / max(n, 1) for k, v in running.items()},
                    **{f"val/{k}": v for k, v in val.items()},
                },
            )
            running = {}
        stopping = should_stop is not None and should_stop()
        if step % cfg.checkpoint_interval == 0 or step == cfg.steps or stopping:
            _save(
                path,
                {
                    "net": net.state_dict(),
                    "optimizer": optimizer.state_dict(),
                    "generator": generator.get_state(),
                    "torch_rng": torch.get_rng_state(),
                    "step": step,
                    "initial_val": initial,
                    "curve": curve,
                    "running": running,
                },
            )
        if stopping:
            break
    net.eval()
    return TrainResult(net, step, initial, curve[-1], resumed_from, curve)


def load_net(folder: Path, cfg: StudentConfig) -> StudentNet:
    """The trained student saved in ``folder`` (its last checkpoint)."""
    net = StudentNet(cfg)
    net.load_state_dict(torch.load(folder / CHECKPOINT, weights_only=False)["net"])
    return net.eval()
