"""LeRobot's Diffusion Policy trained on one LeRobot dataset, with LeRobot's own parts throughout:
``TrainPipelineConfig`` (policy presets: Adam + cosine schedule with warm-up), ``make_dataset``
(delta timestamps from the policy's observation/action indices, ImageNet image statistics),
``make_policy``, ``make_pre_post_processors``, ``EpisodeAwareSampler``, ``update_policy`` under an
``Accelerator``, and ``save_checkpoint`` / ``load_training_state`` for the checkpoints.

What this adds to ``lerobot-train``: a callback receiving the loss and learning rate (the stage
streams them to MLflow), and resumption from the output folder's last checkpoint without a
command-line dance, to the same weights as a training never stopped (lerobot-train 0.6.1 resumes
with another data order: huggingface/lerobot#4692). Table IX sets n_obs_steps, horizon,
n_action_steps, lr, weight decay, batch size and steps; ``pretrained_backbone_weights=None`` (a
ResNet-18 from scratch: no downloads); ``drop_n_last_frames`` follows LeRobot's formula for the
chosen horizon; everything else is LeRobot's default. ``lerobot_train_args`` gives the same run
as a ``lerobot-train`` command line.

One difference in loading: ``touch2robot.policy.reader.column_views`` makes the dataset read its
observation/action windows from single-column views (LeRobot PR #4314, unreleased in 0.6.1).
Without it every window row decodes both camera images, a third of a CPU update. And by default
(``PolicyConfig.loader = "frames"``) the batches come from ``touch2robot.policy.loader.FrameLoader``:
LeRobot's batches in the sampler's order from frames decoded once (bench/policy_loader.py), drawing
from torch's RNG as LeRobot's DataLoader does, so either loader trains the same weights.
"""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from touch2robot.policy.config import VIDEO_BACKEND, PolicyConfig

CHECKPOINTS = "checkpoints"
LAST = "last"
PRETRAINED = "pretrained_model"
LOSS_LOG = "loss_log.jsonl"


def diffusion_kwargs(cfg: PolicyConfig) -> dict:
    """The DiffusionConfig fields this project sets (the rest is LeRobot's default)."""
    from lerobot.configs.types import NormalizationMode
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig

    kw: dict = {
        "n_obs_steps": cfg.n_obs_steps,
        "horizon": cfg.horizon,
        "n_action_steps": cfg.n_action_steps,
        "drop_n_last_frames": cfg.horizon - cfg.n_action_steps - cfg.n_obs_steps + 1,
        "optimizer_lr": cfg.lr,
        "optimizer_weight_decay": cfg.weight_decay,
        "pretrained_backbone_weights": None,
        "push_to_hub": False,
    }
    if cfg.observation == "state":
        # LeRobot leaves ENV features unnormalised; its PushT-keypoints recipe min-max scales them as the state,
        # which puts the object's few centimetres of travel on the scale of the joints
        (default,) = (
            f.default_factory for f in dataclasses.fields(DiffusionConfig) if f.name == "normalization_mapping"
        )
        kw["normalization_mapping"] = {**default(), "ENV": NormalizationMode.MIN_MAX}  # pyright: ignore[reportCallIssue]
    if cfg.down_dims is not None:
        kw["down_dims"] = tuple(cfg.down_dims)
    if cfg.num_inference_steps is not None:
        kw["num_inference_steps"] = cfg.num_inference_steps
    if cfg.scheduler_warmup_steps is not None:
        kw["scheduler_warmup_steps"] = cfg.scheduler_warmup_steps
    if cfg.device is not None:
        kw["device"] = cfg.device
    return kw


def pipeline_config(dataset_root: Path, repo_id: str, cfg: PolicyConfig, output_dir: Path, steps: int | None = None):
    """LeRobot's ``TrainPipelineConfig`` of a run (no hub, no wandb, optimizer/scheduler presets)."""
    from lerobot.configs.default import DatasetConfig, WandBConfig
    from lerobot.configs.train import TrainPipelineConfig
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig

    policy = DiffusionConfig(**diffusion_kwargs(cfg))
    pipeline = TrainPipelineConfig(
        dataset=DatasetConfig(repo_id=repo_id, root=str(dataset_root), video_backend=VIDEO_BACKEND),
        policy=policy,
        output_dir=Path(output_dir),
        seed=cfg.seed,
        num_workers=cfg.num_workers,
        batch_size=cfg.batch_size,
        steps=steps or cfg.steps,
        log_freq=cfg.log_freq,
        save_freq=cfg.save_freq,
        wandb=WandBConfig(enable=False),
    )
    # what TrainPipelineConfig.validate() does for presets (validate also parses sys.argv)
    pipeline.optimizer = policy.get_optimizer_preset()
    pipeline.scheduler = policy.get_scheduler_preset()
    return pipeline


def lerobot_train_args(
    dataset_root: Path, repo_id: str, cfg: PolicyConfig, output_dir: Path, steps: int | None = None, save: bool = True
) -> list[str]:
    """Command-line arguments of ``lerobot-train`` for the same run as ``train``."""
    kw = diffusion_kwargs(cfg)
    args = [
        f"--dataset.repo_id={repo_id}",
        f"--dataset.root={dataset_root}",
        f"--dataset.video_backend={VIDEO_BACKEND}",
        "--policy.type=diffusion",
        f"--output_dir={output_dir}",
        f"--seed={cfg.seed}",
        f"--num_workers={cfg.num_workers}",
        f"--batch_size={cfg.batch_size}",
        f"--steps={steps or cfg.steps}",
        f"--log_freq={cfg.log_freq}",
        f"--save_freq={cfg.save_freq}",
        f"--save_checkpoint={str(save).lower()}",
        "--wandb.enable=false",
    ]
    for key, value in kw.items():
        if value is None:
            text = "null"
        elif isinstance(value, bool):
            text = str(value).lower()
        elif isinstance(value, tuple):
            text = "[" + ",".join(map(str, value)) + "]"
        elif isinstance(value, dict):
            text = json.dumps({k: getattr(v, "value", v) for k, v in value.items()})
        else:
            text = str(value)
        args.append(f"--policy.{key}={text}")
    return args


def last_checkpoint(output_dir: Path) -> Path | None:
    """The output folder's last complete checkpoint (LeRobot's ``checkpoints/last`` link)."""
    last = Path(output_dir) / CHECKPOINTS / LAST
    return last.resolve() if (last / PRETRAINED).is_dir() and (last / "training_state").is_dir() else None


def _prune_checkpoints(output_dir: Path, keep: int) -> None:
    """Delete all but the newest ``keep`` step checkpoints; the one ``last`` names always stays."""
    folder = Path(output_dir) / CHECKPOINTS
    last = last_checkpoint(output_dir)
    steps = sorted((p for p in folder.iterdir() if p.name.isdigit() and not p.is_symlink()), key=lambda p: int(p.name))
    for stale in steps[:-keep]:
        if stale != last:
            shutil.rmtree(stale)


def _loss_log(output_dir: Path, upto_step: int) -> list[dict]:
    """The logged windows of the training in ``output_dir`` up to ``upto_step`` (the resume point),
    rewritten without later ones: a crash after the last checkpoint leaves windows that the
    resumed run logs again."""
    path = Path(output_dir) / LOSS_LOG
    if not path.is_file():
        return []
    windows = [w for w in map(json.loads, path.read_text().splitlines()) if w["step"] <= upto_step]
    tmp = path.with_suffix(".tmp")
    tmp.write_text("".join(json.dumps(w) + "\n" for w in windows))
    tmp.replace(path)
    return windows


@dataclass(frozen=True)
class TrainResult:
    """What one ``train`` call did."""

    policy_dir: str  # the final LeRobot pretrained_model folder (config, weights, processors)
    steps: int  # updates done in total
    resumed_from: int  # the step the call started at (0 = fresh)
    first_loss: float  # mean loss over the training's first logging window (from its loss log)
    last_loss: float  # mean loss over its last logging window, whichever call did it
    samples_per_s: float  # training samples per second over the call (data loading included); NaN without updates
    seconds: float


def train(
    dataset_root: Path,
    repo_id: str,
    cfg: PolicyConfig,
    output_dir: Path,
    steps: int | None = None,
    on_log: Callable[[int, dict[str, float]], None] | None = None,
    max_seconds: float | None = None,
    should_stop: Callable[[], bool] | None = None,
) -> TrainResult:
    """Train (or resume from ``output_dir``'s last checkpoint) LeRobot's Diffusion Policy on a
    LeRobot dataset for ``steps`` updates in total (default ``cfg.steps``). Every ``cfg.log_freq``
    updates ``on_log(step, {"loss", "lr", "grad_norm", "samples_per_s", "data_s", "update_s"[, "gpu_mem_gb"]})``
    gets the window's means (seconds per update waiting for data and updating; peak GPU memory).
    ``max_seconds`` ends the call early, checkpointed, once that much time has passed (the learning
    rate keeps the schedule of ``steps`` updates; a later call resumes there), and so does
    ``should_stop()`` turning true (asked after every update). The windows also go
    to ``output_dir/loss_log.jsonl``, so a call on a finished folder (no updates left) still
    reports the training's first and last loss."""
    import torch
    from accelerate import Accelerator
    from lerobot.common.train_utils import (
        get_step_checkpoint_dir,
        load_training_state,
        save_checkpoint,
        update_last_checkpoint,
    )
    from lerobot.datasets import EpisodeAwareSampler, LeRobotDataset, compute_sampler_state
    from lerobot.datasets.factory import make_dataset
    from lerobot.optim.factory import make_optimizer_and_scheduler
    from lerobot.policies import make_policy, make_pre_post_processors
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
    from lerobot.scripts.lerobot_train import update_policy
    from lerobot.utils.logging_utils import AverageMeter, MetricsTracker
    from lerobot.utils.random_utils import get_rng_state, set_rng_state, set_seed
    from lerobot.utils.utils import cycle

    from touch2robot.policy.loader import FrameLoader
    from touch2robot.policy.reader import column_views

    output_dir = Path(output_dir)
    pipeline = pipeline_config(dataset_root, repo_id, cfg, output_dir, steps)
    # pipeline_config sets all three (LeRobot's config has them optional)
    policy_cfg, optimizer_cfg, seed = pipeline.policy, pipeline.optimizer, pipeline.seed
    assert isinstance(policy_cfg, DiffusionConfig) and optimizer_cfg is not None and seed is not None
    resume = last_checkpoint(output_dir)
    accelerator = Accelerator(step_scheduler_with_optimizer=False, cpu=policy_cfg.device == "cpu")
    # LeRobot annotates the accelerator of set_seed and MetricsTracker as a Callable; both take an Accelerator
    set_seed(seed, accelerator=accelerator)  # pyright: ignore[reportArgumentType]
    dataset = make_dataset(pipeline)
    assert isinstance(dataset, LeRobotDataset)  # one local dataset: neither several nor streamed
    column_views(dataset)
    if resume is not None:
        policy_cfg.pretrained_path = resume / PRETRAINED
    policy = make_policy(cfg=policy_cfg, ds_meta=dataset.meta)
    if resume is None:
        # LeRobot annotates dataset_stats as tensors; it takes the metadata's NumPy statistics (as lerobot-train)
        preprocessor, postprocessor = make_pre_post_processors(policy_cfg, dataset_stats=dataset.meta.stats)  # pyright: ignore[reportArgumentType]
    else:  # the checkpoint's processors carry the statistics the run started with
        preprocessor, postprocessor = make_pre_post_processors(
            policy_cfg,
            pretrained_path=str(resume / PRETRAINED),
            preprocessor_overrides={"device_processor": {"device": accelerator.device.type}},
        )
    optimizer, scheduler = make_optimizer_and_scheduler(pipeline, policy)
    step = 0
    if resume is not None:
        step, optimizer, scheduler = load_training_state(resume, optimizer, scheduler)
    start_step = step
    episodes = dataset.meta.episodes
    if episodes is None:  # LeRobot loads no episode table for a dataset without episodes
        raise ValueError(f"LeRobot dataset {repo_id} in {dataset_root} has no episodes to train on")
    sampler = EpisodeAwareSampler(
        episodes["dataset_from_index"],
        episodes["dataset_to_index"],
        episode_indices_to_use=dataset.episodes,
        drop_n_last_frames=policy_cfg.drop_n_last_frames,
        shuffle=True,
        seed=seed,
        absolute_to_relative_idx=dataset.absolute_to_relative_idx,
    )
    checkpoint_rng = None
    if step:  # continue the data order where the checkpoint left it
        position = compute_sampler_state(step, len(sampler), pipeline.batch_size, 1)
        sampler.load_state_dict(position)
        if position["start_index"]:
            # The first batch starts a data iterator, which draws a seed from torch's RNG: an
            # uninterrupted run drew it at the epoch's start, before the checkpoint's RNG state was
            # saved, so a mid-epoch resume puts that state back after its first batch
            checkpoint_rng = get_rng_state()
    if cfg.loader == "frames":
        # the same batches in the same order as LeRobot's DataLoader below, on the device already
        loader = FrameLoader(dataset, sampler, pipeline.batch_size, accelerator.device)
        policy, optimizer, scheduler = accelerator.prepare(policy, optimizer, scheduler)
    else:
        data_loader = torch.utils.data.DataLoader(
            dataset,
            batch_size=pipeline.batch_size,
            sampler=sampler,
            num_workers=pipeline.num_workers,
            pin_memory=accelerator.device.type == "cuda",
            drop_last=False,
            persistent_workers=pipeline.num_workers > 0,
            prefetch_factor=pipeline.prefetch_factor if pipeline.num_workers > 0 else None,
        )
        policy, optimizer, loader, scheduler = accelerator.prepare(policy, optimizer, data_loader, scheduler)
        if step:  # the prepared loader sets the sampler's epoch to its own count of epochs, from 0
            loader.set_epoch(position["epoch"])  # (huggingface/lerobot#4692)
    # update_policy also records the peak GPU memory (gpu_mem_gb) wherever CUDA is available
    meters = {
        name: AverageMeter(name) for name in ("loss", "grad_norm", "lr", "update_s", "dataloading_s", "gpu_mem_gb")
    }
    tracker = MetricsTracker(
        pipeline.batch_size,
        dataset.num_frames,
        dataset.num_episodes,
        meters,
        initial_step=step,
        accelerator=accelerator,  # pyright: ignore[reportArgumentType]
    )
    batches = cycle(loader)
    windows = _loss_log(output_dir, step)
    window_start = started = time.perf_counter()
    while step < pipeline.steps:
        t0 = time.perf_counter()
        batch = preprocessor(next(batches))
        if checkpoint_rng is not None:
            set_rng_state(checkpoint_rng)
            checkpoint_rng = None
        tracker.dataloading_s = time.perf_counter() - t0
        tracker, _ = update_policy(
            tracker,
            policy,
            batch,
            optimizer,
            optimizer_cfg.grad_clip_norm,
            accelerator=accelerator,
            lr_scheduler=scheduler,
        )
        step += 1
        tracker.step()
        ending = (max_seconds is not None and time.perf_counter() - started >= max_seconds) or (
            should_stop is not None and should_stop()
        )
        if step % pipeline.log_freq == 0 or step == pipeline.steps or ending:
            now = time.perf_counter()
            # the tracker's own meters (``meters``), typed where its attributes are not
            figures = {
                "loss": meters["loss"].avg,
                "lr": meters["lr"].val,
                "grad_norm": meters["grad_norm"].avg,
                "samples_per_s": meters["loss"].count * pipeline.batch_size / (now - window_start),
                # where an update's time goes: waiting for the loader's batch vs the update itself
                "data_s": meters["dataloading_s"].avg,
                "update_s": meters["update_s"].avg,
            }
            if meters["gpu_mem_gb"].count:
                figures["gpu_mem_gb"] = meters["gpu_mem_gb"].val
            windows.append({"step": step, **figures})
            output_dir.mkdir(parents=True, exist_ok=True)
            with open(output_dir / LOSS_LOG, "a") as log:
                log.write(json.dumps(windows[-1]) + "\n")
            if on_log is not None:
                on_log(step, figures)
            tracker.reset_averages()
            window_start = now
        if step % pipeline.save_freq == 0 or step == pipeline.steps or ending:
            ckpt = get_step_checkpoint_dir(output_dir, pipeline.steps, step)
            save_checkpoint(
                ckpt,
                step,
                pipeline,
                accelerator.unwrap_model(policy),
                optimizer,
                scheduler,
                preprocessor,
                postprocessor,
                num_processes=1,
                batch_size=pipeline.batch_size,
            )
            update_last_checkpoint(ckpt)
            _prune_checkpoints(output_dir, cfg.keep_checkpoints)
        if ending:
            break
    seconds = time.perf_counter() - started
    final = last_checkpoint(output_dir)
    assert final is not None
    return TrainResult(
        policy_dir=str(final / PRETRAINED),
        steps=step,
        resumed_from=start_step,
        first_loss=windows[0]["loss"] if windows else math.nan,
        last_loss=windows[-1]["loss"] if windows else math.nan,
        samples_per_s=(step - start_step) * pipeline.batch_size / seconds if step > start_step else math.nan,
        seconds=seconds,
    )
