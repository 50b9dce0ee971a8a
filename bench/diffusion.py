"""Diffusion Policy training throughput of the project's stage (``touch2robot.policy.train.train``)
against LeRobot's own ``lerobot-train`` on the same dataset and settings, in the same run (target
ratio >= 0.95), the dataset builder's rendering rate (camera images per second), and the time
to read one training sample through LeRobot's reader against ``column_views``.

    uv run python bench/diffusion.py [--profile smoke] [--steps 20] [--warmup 5] [--data DIR]

The dataset is the first task x method in ``<data>/lake/rollouts`` (``--data``), or else rollouts of
the tests' scripted grasp in real MuJoCo physics. Both trainers run as fresh processes twice, for
``warmup`` and ``warmup + steps`` updates; samples/s = steps x batch / (difference of wall times),
so start-up (imports, dataset load, model build) cancels out. Rounds alternate to share drift.
The stage reads its windows through ``touch2robot.policy.reader`` (LeRobot PR #4314, not in 0.6.1's
``lerobot-train``), so its ratio exceeds 1 by what that fix saves on image datasets.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OURS = (
    "import sys, torch; torch.set_num_threads(1); from pathlib import Path; from touch2robot.config import "
    "load_profile; "
    "from touch2robot.policy.train import train; cfg = load_profile(sys.argv[1]).policy; "
    "train(Path(sys.argv[2]), sys.argv[3], cfg, Path(sys.argv[4]), steps=int(sys.argv[5]))"
)


def _dataset(data: Path | None, cfg, out: Path) -> tuple[Path, str, float]:
    from touch2robot import datasets
    from touch2robot.policy.dataset import build_dataset, read_rollouts, sources
    from touch2robot.sim.config import SimConfig
    from touch2robot.sim.scene import build_scene

    lake = data / "lake" if data else out / "lake"
    if not data:
        sys.path.insert(0, str(ROOT / "tests"))
        from conftest import scripted_rollout_rows

        rows = scripted_rollout_rows("pick", "bench", 8, 40)
        datasets.ROLLOUTS.write(lake, datasets.rollouts_key("teacher", "pick", 0), rows, method="bench")
    src = sources(lake)[0]
    sim = SimConfig(threads=1)
    summary = build_dataset(
        out / "ds",
        src.task,
        src.method,
        read_rollouts(src.path, cfg.max_rollouts),
        build_scene(src.task, sim),
        sim,
        cfg,
    )
    print(
        f"dataset {src.method}-{src.task}: {summary.episodes} episodes, {summary.frames} frames, {cfg.image_size} px x "
        f"{len(cfg.cameras)} cameras: "
        f"rendering {summary.render_fps:.0f} images/s ({summary.render_fps / len(cfg.cameras):.0f} frames/s)"
    )
    return Path(summary.root), summary.repo_id, summary.render_fps


def _sample_reads(root: Path, repo_id: str, cfg, out: Path, samples: int = 64) -> None:
    """ms per training sample (observation and action windows) read through LeRobot's reader and
    through ``column_views``, on the same dataset and indices."""
    from lerobot.datasets.factory import make_dataset

    from touch2robot.policy.reader import column_views
    from touch2robot.policy.train import pipeline_config

    pipeline = pipeline_config(root, repo_id, cfg, out / "read")
    ms = {}
    for name in ("lerobot", "column views"):
        ds = make_dataset(pipeline)
        if name == "column views":
            column_views(ds)
        ds[0]
        idx = [(7919 * i) % len(ds) for i in range(samples)]
        start = time.perf_counter()
        for i in idx:
            ds[i]
        ms[name] = 1000 * (time.perf_counter() - start) / samples
    print(
        f"sample read: LeRobot 0.6.1 reader {ms['lerobot']:.1f} ms, column views {ms['column views']:.1f} ms, "
        f"ratio {ms['lerobot'] / ms['column views']:.1f}x"
    )


def _wall(cmd: list[str]) -> float:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"}
    start = time.perf_counter()
    done = subprocess.run(cmd, env=env, cwd=ROOT, capture_output=True, text=True)
    if done.returncode:
        raise RuntimeError(f"{cmd[:2]} failed:\n{done.stderr[-3000:]}")
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--profile", default="smoke")
    parser.add_argument("--steps", type=int, default=20, help="timed updates")
    parser.add_argument("--warmup", type=int, default=5, help="updates whose cost (with start-up) is subtracted")
    parser.add_argument("--rounds", type=int, default=1)
    parser.add_argument("--data", type=Path, default=None, help="data folder with a rollouts table")
    args = parser.parse_args()

    from touch2robot.config import load_profile
    from touch2robot.policy.train import lerobot_train_args

    cfg = load_profile(args.profile).policy.model_copy(update={"log_freq": 10**6, "save_freq": 10**6})
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        root, repo_id, _ = _dataset(args.data, cfg, tmp)
        _sample_reads(root, repo_id, cfg, tmp)
        rates: dict[str, list[float]] = {"ours": [], "lerobot-train": []}
        cli = str(Path(sys.executable).with_name("lerobot-train"))
        for r in range(args.rounds):
            for name in rates:
                walls = []
                for n in (args.warmup, args.warmup + args.steps):
                    out = tmp / f"{name}-{r}-{n}"
                    if name == "ours":
                        cmd = [sys.executable, "-c", OURS, args.profile, str(root), repo_id, str(out), str(n)]
                    else:
                        cmd = [cli, *lerobot_train_args(root, repo_id, cfg, out, steps=n, save=False)]
                    walls.append(_wall(cmd))
                rates[name].append(args.steps * cfg.batch_size / (walls[1] - walls[0]))
                print(f"round {r} {name:>13}: {rates[name][-1]:.2f} samples/s")
    ours, theirs = max(rates["ours"]), max(rates["lerobot-train"])
    print(
        f"training ({args.profile}: batch {cfg.batch_size}, {cfg.image_size} px, n_obs {cfg.n_obs_steps}, down_dims "
        f"{cfg.down_dims}): "
        f"ours {ours:.2f} samples/s, lerobot-train {theirs:.2f} samples/s, ratio {ours / theirs:.3f} (target >= 0.95)"
    )


if __name__ == "__main__":
    main()
