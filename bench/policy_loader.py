"""Paper-size training batches per second (batch 64, 5 observation steps, 2 x 224 px views, horizon
24) from the project's ``FrameLoader`` and from LeRobot's own ``DataLoader`` over the same dataset
and the same ``EpisodeAwareSampler`` order, in the same run (target ratio >= 5x).

    uv run python bench/policy_loader.py [--episodes 6] [--frames 60] [--batches 8] [--workers N]

The dataset is built with the project's own ``build_dataset`` from the tests' scripted grasp
rollouts (real MuJoCo physics) at the paper profile's settings; its build and the frame cache's
one-off decode are timed apart, outside the rates. Each loader first yields two batches (worker
start-up, first decode), then ``--batches`` timed ones. The loaders compared:

- ``lerobot``: LeRobot 0.6.1's ``DataLoader`` as ``lerobot-train`` builds it (``--workers`` processes,
  default the paper profile's ``num_workers`` capped at this machine's cores);
- ``lerobot+column views``: the same with ``touch2robot.policy.reader.column_views`` (the stage's
  loader before ``FrameLoader``);
- ``frames``: ``FrameLoader`` on this machine's training device, its images float32 on that device
  (CPU here when no GPU: the uint8 -> float conversion is then part of its time); and its host-side
  gather alone (uint8 images), the part a GPU training waits for.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _dataset(out: Path, cfg, episodes: int, frames: int) -> tuple[Path, str]:
    from touch2robot import datasets
    from touch2robot.policy.dataset import build_dataset, read_rollouts, sources
    from touch2robot.sim.config import SimConfig
    from touch2robot.sim.scene import build_scene

    sys.path.insert(0, str(ROOT / "tests"))
    from conftest import scripted_rollout_rows

    lake = out / "lake"
    rows = scripted_rollout_rows("pick", "bench", episodes, frames)
    datasets.ROLLOUTS.write(lake, datasets.rollouts_key("teacher", "pick", 0), rows, method="bench")
    sim = SimConfig(threads=1)
    summary = build_dataset(
        out / "ds", "pick", "bench", read_rollouts(sources(lake)[0].path), build_scene("pick", sim), sim, cfg
    )
    print(
        f"dataset: {summary.episodes} episodes, {summary.frames} frames, {len(cfg.cameras)} x {cfg.image_size} px, "
        f"built in {summary.build_s:.0f} s (not timed below)"
    )
    return Path(summary.root), summary.repo_id


def _sampler(dataset, cfg):
    from lerobot.datasets import EpisodeAwareSampler

    from touch2robot.policy.train import diffusion_kwargs

    episodes = dataset.meta.episodes
    return EpisodeAwareSampler(
        episodes["dataset_from_index"],
        episodes["dataset_to_index"],
        drop_n_last_frames=diffusion_kwargs(cfg)["drop_n_last_frames"],
        shuffle=True,
        seed=cfg.seed,
    )


def _rate(loader, batches: int, device) -> float:
    """Batches per second over ``batches`` batches after two untimed ones."""
    import torch
    from lerobot.utils.utils import cycle

    stream = cycle(loader)
    for _ in range(2):
        next(stream)
    start = time.perf_counter()
    for _ in range(batches):
        batch = next(stream)
        if device.type == "cuda":  # LeRobot's batches reach the device in the training loop too
            batch = {k: v.to(device, non_blocking=True) if isinstance(v, torch.Tensor) else v for k, v in batch.items()}
            torch.cuda.synchronize()
    return batches / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--episodes", type=int, default=6)
    parser.add_argument("--frames", type=int, default=60, help="frames per episode")
    parser.add_argument("--batches", type=int, default=8, help="timed batches per loader")
    parser.add_argument("--workers", type=int, default=None, help="LeRobot DataLoader worker processes")
    args = parser.parse_args()

    # picks MuJoCo's headless GL backend: before anything imports mujoco
    from touch2robot.sim import render as _render  # noqa: F401

    # isort: split
    import torch
    from lerobot.datasets.factory import make_dataset

    from touch2robot.config import load_profile
    from touch2robot.policy.loader import FrameLoader
    from touch2robot.policy.reader import column_views
    from touch2robot.policy.train import pipeline_config

    cfg = load_profile("paper").policy
    workers = args.workers if args.workers is not None else min(cfg.num_workers, os.cpu_count() or 1)
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        root, repo_id = _dataset(tmp, cfg, args.episodes, args.frames)
        pipeline = pipeline_config(root, repo_id, cfg, tmp / "out")
        rates: dict[str, float] = {}
        for name in ("lerobot", "lerobot+column views"):
            dataset = make_dataset(pipeline)
            if name != "lerobot":
                column_views(dataset)
            loader = torch.utils.data.DataLoader(
                dataset,
                batch_size=cfg.batch_size,
                sampler=_sampler(dataset, cfg),
                num_workers=workers,
                pin_memory=device.type == "cuda",
                persistent_workers=workers > 0,
            )
            rates[name] = _rate(loader, args.batches, device)
            print(f"{name:>22}: {rates[name]:.2f} batches/s ({workers} workers)")
        dataset = make_dataset(pipeline)
        start = time.perf_counter()
        frames = FrameLoader(dataset, _sampler(dataset, cfg), cfg.batch_size, device)
        print(f"frame cache: decoded once in {time.perf_counter() - start:.1f} s (not timed below)")
        rates["frames"] = _rate(frames, 4 * args.batches, device)
        print(f"{'frames':>22}: {rates['frames']:.2f} batches/s (on {device.type})")
        # what a GPU's training waits for: the host's gather, images still uint8 (the float conversion on the GPU)
        order = list(iter(frames.sampler))
        starts = [(i * cfg.batch_size) % max(1, len(order) - cfg.batch_size) for i in range(4 * args.batches)]
        start = time.perf_counter()
        for first in starts:
            frames.host_batch(order[first : first + cfg.batch_size])
        host = len(starts) / (time.perf_counter() - start)
        print(f"{'frames, host gather':>22}: {host:.2f} batches/s (uint8 images, before the device)")
    print(
        f"paper batches (batch {cfg.batch_size}, n_obs {cfg.n_obs_steps}, horizon {cfg.horizon}, "
        f"{len(cfg.cameras)} x {cfg.image_size} px) on {os.cpu_count()} cores: frames {rates['frames']:.2f}/s, "
        f"LeRobot {rates['lerobot']:.2f}/s, ratio {rates['frames'] / rates['lerobot']:.1f}x (target >= 5x); "
        f"vs LeRobot + column views {rates['lerobot+column views']:.2f}/s: "
        f"{rates['frames'] / rates['lerobot+column views']:.1f}x"
    )


if __name__ == "__main__":
    main()
