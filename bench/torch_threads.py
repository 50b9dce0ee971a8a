"""Diffusion Policy training throughput against torch's intra-op thread count, for trainings side by
side (the policy stage runs ``training_runner.max_workers`` of them at once) and beside a busy
process of lower priority (a laptop's other work, a niced job).

    uv run python bench/torch_threads.py [--profile local] [--steps 30] [--warmup 10] [--window 10]
        [--data DIR] [--no-busy] [--no-oversubscribed]

Each case starts its trainings as fresh processes (``touch2robot.policy.train.train`` with
``torch.set_num_threads(threads)``), all at once, for ``warmup + steps`` updates. A training's
samples/s is the mean of its own per-window figures (``on_log``, every ``window`` updates) over
the ``steps`` after the warmup: start-up, and the first updates' one-off costs, stay out of it.
The baseline is torch's default thread count (one per core), measured in the same run; the ratio
is a case's total samples/s over the baseline case with the same trainings and competitor.
The dataset is built as in ``bench/diffusion.py`` (the first rollouts of ``--data``, or a
scripted grasp).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diffusion import ROOT, _dataset

TRAIN = (
    "import sys, torch; torch.set_num_threads(int(sys.argv[6])); from pathlib import Path; from touch2robot.config "
    "import load_profile; "
    "from touch2robot.policy.train import train; cfg = load_profile(sys.argv[1]).policy.model_copy(update={'log_freq': "
    "int(sys.argv[7]), 'save_freq': 10**6}); "
    "train(Path(sys.argv[2]), sys.argv[3], cfg, Path(sys.argv[4]), steps=int(sys.argv[5]), on_log=lambda step, m: "
    "print('RATE', step, m['samples_per_s'], flush=True))"
)
SPIN = "while True: pass"


def _rates(cmds: list[list[str]], after_step: int) -> list[float]:
    """Each command's mean samples/s over its windows that end after ``after_step``, all started at once."""
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"}
    env.pop("OMP_NUM_THREADS", None)
    procs = [
        subprocess.Popen(c, env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for c in cmds
    ]
    rates = []
    for p in procs:
        out, err = p.communicate()
        if p.returncode:
            raise RuntimeError(f"a training failed:\n{err[-3000:]}")
        windows = [
            float(r)
            for _, step, r in (line.split() for line in out.splitlines() if line.startswith("RATE "))
            if int(step) > after_step
        ]
        rates.append(statistics.fmean(windows) if windows else float("nan"))
    return rates


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--profile", default="local")
    parser.add_argument("--steps", type=int, default=30, help="timed updates")
    parser.add_argument("--warmup", type=int, default=10, help="updates first, untimed")
    parser.add_argument("--window", type=int, default=10, help="updates per logged samples/s figure (divides --warmup)")
    parser.add_argument("--data", type=Path, default=None, help="data folder with a rollouts table")
    parser.add_argument("--no-busy", action="store_true", help="skip the cases beside a busy process (the slow ones)")
    parser.add_argument(
        "--no-oversubscribed", action="store_true", help="skip the cases with more threads in all than cores (slow)"
    )
    args = parser.parse_args()
    if args.window < 1 or args.warmup % args.window:
        parser.error("--window must divide --warmup: a window across the warmup's end would mix untimed updates in")

    import torch

    from touch2robot.config import load_profile

    profile = load_profile(args.profile)
    cfg = profile.policy
    default = torch.get_num_threads()
    side_by_side = (
        profile.training_runner.max_workers or os.cpu_count() or 1
    )  # None: Prefect's default pool, a process per core
    cases = [
        (n, threads, busy)
        for busy in ((False,) if args.no_busy else (False, True))
        for n in sorted({1, side_by_side})
        for threads in sorted({default, max(1, default // n), 1}, reverse=True)
        if not (args.no_oversubscribed and n * threads > default)
    ]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        root, repo_id, _ = _dataset(args.data, cfg, tmp)
        rate: dict[tuple[int, int, bool], float] = {}
        for n, threads, busy in cases:
            spinner = subprocess.Popen(["nice", "-n", "19", sys.executable, "-c", SPIN]) if busy else None
            try:
                steps = args.warmup + args.steps
                cmds = [
                    [
                        sys.executable,
                        "-c",
                        TRAIN,
                        args.profile,
                        str(root),
                        repo_id,
                        str(tmp / f"{n}-{threads}-{busy}-{i}"),
                        str(steps),
                        str(threads),
                        str(args.window),
                    ]
                    for i in range(n)
                ]
                per = _rates(cmds, args.warmup)
            finally:
                if spinner is not None:
                    spinner.kill()
                    spinner.wait()
            rate[n, threads, busy] = sum(per)
            base = rate.get((n, default, busy), float("nan"))  # nan: the baseline case was skipped
            print(
                f"{n} training(s) x {threads} thread(s){' beside a niced busy process' if busy else '':>28}: "
                f"{' + '.join(f'{r:.2f}' for r in per)} = {rate[n, threads, busy]:.2f} samples/s, ratio "
                f"{rate[n, threads, busy] / base:.2f} "
                f"to {default} threads each"
            )
    print(
        f"({args.profile}: batch {cfg.batch_size}, {cfg.image_size} px, n_obs {cfg.n_obs_steps}, down_dims "
        f"{cfg.down_dims}; {os.cpu_count()} cores)"
    )


if __name__ == "__main__":
    main()
