"""The paper profile's Diffusion Policy (Table IX) on one task x method within a time budget: its
LeRobot dataset at the profile's image size, training at the profile's sizes (full UNet, 5
observation steps, batch 64, lr 1e-4 on the cosine schedule of all 50,000 updates) for at most
``--train-seconds``, then the reached policy's closed-loop success and open-loop fit. It prints the
steady update rate and what the profile's whole training would take on this machine, so a GPU's hours can
be planned before the `policy` flow commits them (the flow resumes from the checkpoint left here
only if ``--out`` is its training folder; by default it is a folder of its own).

    uv run python bench/paper_policy.py --data DIR --task wipe --method touch2robot \\
        [--profile paper] [--sim-profile local] [--train-seconds 300] [--eval-episodes 10] [--out DIR]

``--data`` holds the rollouts (``lake/rollouts``, e.g. a local-profile run's); ``--sim-profile`` is
the profile whose teacher physics recorded them (replay and evaluation must use the same). The
demonstrations are chosen as the flow chooses them (``policy.same_demonstrations``: those every
method of the task in the lake follows). No Prefect, no MLflow: one JSON summary is printed and
written with the loss curve to ``<out>/summary.json``. It measures; it sets no target.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

# the GL backend is chosen when this is imported, before mujoco: keep it first
from touch2robot.sim import render as _render  # noqa: F401


def _steady_rate(curve: list[dict], batch_size: int, first_step: int) -> float | None:
    """Updates/s over the logging windows after the first (which holds CUDA start-up, cuDNN's
    algorithm search and the loader workers' start); None with fewer than two windows."""
    steps = [first_step] + [c["step"] for c in curve]
    later = [(steps[i + 1] - steps[i], c["samples_per_s"]) for i, c in enumerate(curve)][1:]
    seconds = sum(n * batch_size / sps for n, sps in later)
    return sum(n for n, _ in later) / seconds if later and seconds else None


def _steady_mean(curve: list[dict], key: str) -> float | None:
    """Mean of a per-window figure over the windows after the first (or the first alone)."""
    windows = curve[1:] or curve
    return round(float(np.mean([c[key] for c in windows])), 4) if windows else None


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="data folder with a rollouts table (lake/rollouts)")
    parser.add_argument("--task", required=True)
    parser.add_argument("--method", required=True)
    parser.add_argument("--profile", default="paper", help="profile of the dataset, training and evaluation settings")
    parser.add_argument("--sim-profile", default="local", help="profile whose teacher physics recorded the rollouts")
    parser.add_argument("--train-seconds", type=float, default=300.0, help="training time budget (s)")
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--out", type=Path, default=Path("paper-policy"), help="dataset, checkpoints and summary.json")
    args = parser.parse_args()

    import torch

    from touch2robot.config import load_profile
    from touch2robot.policy.dataset import build_dataset, chosen_sources, read_rollouts
    from touch2robot.policy.evaluate import evaluate
    from touch2robot.policy.train import train
    from touch2robot.sim.scene import build_scene

    cfg = load_profile(args.profile).policy.model_copy(update={"eval_episodes": args.eval_episodes})
    sim = load_profile(args.sim_profile).teacher.sim
    lake = args.data / "lake"
    every = chosen_sources(lake, cfg, [args.task])
    chosen = [(s, refs) for s, refs in every if s.method == args.method]
    if not chosen or chosen[0][1] == []:
        raise SystemExit(
            f"{lake / 'rollouts'}: no rollouts of {args.task} x {args.method} to learn from (have "
            f"{[s.method for s, _ in every]})"
        )
    src, references = chosen[0]
    rollouts = read_rollouts(src.path, cfg.max_rollouts, references)
    scene = build_scene(args.task, sim)
    device = cfg.device or ("cuda" if torch.cuda.is_available() else "cpu")
    summary: dict = {
        "task": args.task,
        "method": args.method,
        "origin": src.origin,
        "profile": args.profile,
        "device": device,
        "gpu": torch.cuda.get_device_name() if device == "cuda" else None,
    }

    ds = build_dataset(args.out / "dataset", args.task, args.method, rollouts, scene, sim, cfg)
    summary["dataset"] = {
        "episodes": ds.episodes,
        "frames": ds.frames,
        "image_size": cfg.image_size,
        "render_images_per_s": round(ds.render_fps, 1),
        "build_s": round(ds.build_s, 1),
        "replay_max_joint_error_rad": ds.replay_max_joint_error_rad,
    }
    print(
        f"dataset: {ds.episodes} episodes, {ds.frames} frames at {cfg.image_size} px, {ds.render_fps:.0f} images/s, "
        f"built in {ds.build_s:.0f} s",
        flush=True,
    )

    curve: list[dict] = []

    def log(step: int, figures: dict[str, float]) -> None:
        curve.append({"step": step, **figures})
        print(
            f"step {step:>6}: loss {figures['loss']:.4f}, lr {figures['lr']:.2e}, {figures['samples_per_s']:.1f} "
            "samples/s "
            f"(per update: {figures['data_s']:.3f} s waiting for data, {figures['update_s']:.3f} s updating)",
            flush=True,
        )

    result = train(Path(ds.root), ds.repo_id, cfg, args.out / "train", on_log=log, max_seconds=args.train_seconds)
    rate = (
        _steady_rate(curve, cfg.batch_size, result.resumed_from)
        or (result.steps - result.resumed_from) / result.seconds
    )
    summary["train"] = {
        "steps": result.steps,
        "of_steps": cfg.steps,
        "resumed_from": result.resumed_from,
        "seconds": round(result.seconds, 1),
        "updates_per_s": round(rate, 3),
        "samples_per_s_with_start_up": round(result.samples_per_s, 1),
        "hours_for_all_steps": round(cfg.steps / rate / 3600, 2) if rate else None,
        # a loader-bound training (data wait >> update) gains from more policy.num_workers, not a faster GPU
        "data_s_per_update": _steady_mean(curve, "data_s"),
        "update_s_per_update": _steady_mean(curve, "update_s"),
        "first_loss": result.first_loss,
        "last_loss": result.last_loss,
        "peak_gpu_memory_gib": round(torch.cuda.max_memory_allocated() / 2**30, 2) if device == "cuda" else None,
    }

    start = time.perf_counter()
    outcome = evaluate(Path(result.policy_dir), Path(ds.root), ds.repo_id, scene, sim, rollouts, cfg)
    closed, fit, replay = outcome.closed_loop, outcome.fit, outcome.replay
    low, high = closed.wilson
    summary["eval"] = {
        "episodes": len(closed.success),
        "successes": int(closed.success.sum()),
        "ci_low": low,
        "ci_high": high,
        "mean_progress": float(closed.progress.mean()),
        "replay_successes": int(replay.success.sum()),
        "fit_wrist_err_mm": fit.wrist_err_mm,
        "hold_wrist_err_mm": fit.hold_wrist_err_mm,
        "fit_joint_err_rad": fit.joint_err_rad,
        "hold_joint_err_rad": fit.hold_joint_err_rad,
        "replans_per_episode": closed.replans,
        "seconds": round(time.perf_counter() - start, 1),
    }
    summary["loss_curve"] = curve
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "summary.json").write_text(json.dumps(summary, indent=2))
    print(json.dumps({k: v for k, v in summary.items() if k != "loss_curve"}, indent=2))
    print(
        f"{args.task} x {args.method} ({args.profile}, {device}): {result.steps}/{cfg.steps} updates in "
        f"{result.seconds:.0f} s "
        f"({rate:.2f}/s: all {cfg.steps} would take {summary['train']['hours_for_all_steps']} h), loss "
        f"{result.first_loss:.3f} -> {result.last_loss:.3f}; "
        f"success {summary['eval']['successes']}/{summary['eval']['episodes']}, replayed demonstrations "
        f"{summary['eval']['replay_successes']}, "
        f"open-loop wrist error {fit.wrist_err_mm:.1f} mm (holding still {fit.hold_wrist_err_mm:.1f})"
    )


if __name__ == "__main__":
    main()
