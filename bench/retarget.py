"""Kinematic retargeting throughput on one core: frames per second of ``Retargeter`` (Dex
Retargeting's vector optimiser on the LEAP URDF, SLSQP, warm start) over demonstrator glove
recordings of the four tasks, with the per-frame solve-time distribution and the residuals.

    uv run python bench/retarget.py [--tasks pick rotate wipe drawer] [--repeats 2]

Threads are pinned to one (OMP/MKL/OpenBLAS and torch, set before numpy and torch load) so the
figure is per core; run several recordings in parallel processes to use more cores.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from touch2robot.ingest import ingest_file
from touch2robot.retarget import LEAP_DEFAULT
from touch2robot.retarget.lake import load_hand_motion
from touch2robot.retarget.retargeter import Retargeter, retarget_motion
from touch2robot.synth.config import SynthConfig
from touch2robot.synth.generate import RecordingJob, write_recording


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=["pick", "rotate", "wipe", "drawer"])
    parser.add_argument("--repeats", type=int, default=2, help="passes over the recordings (the first warms caches)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        config = SynthConfig(tasks=tuple(args.tasks), subjects=1, demos_per_subject=1)
        motions = []
        for task in args.tasks:
            path = write_recording(config, RecordingJob(task, 1, 1), root / "rec", root / "gt")
            motions.append(load_hand_motion(root / "lake", ingest_file(path, root / "lake").recording_id))
    t0 = time.perf_counter()
    retargeter = Retargeter(LEAP_DEFAULT)
    build_s = time.perf_counter() - t0
    for rep in range(args.repeats):
        frames, solve, residual, failed = 0, [], [], 0
        t0 = time.perf_counter()
        for motion in motions:
            result = retarget_motion(motion, LEAP_DEFAULT, retargeter)
            frames += len(result.t)
            solve.append(result.solve_time)
            residual.append(result.residual)
            failed += int(result.failed.sum())
        wall = time.perf_counter() - t0
        s, r = np.concatenate(solve) * 1e3, np.concatenate(residual) * 1e3
        print(
            f"pass {rep + 1}: {frames} frames of {len(motions)} recordings in {wall:.2f} s = {frames / wall:.0f} "
            "frames/s on one core; "
            f"solve ms/frame mean {s.mean():.2f} p50 {np.median(s):.2f} p95 {np.percentile(s, 95):.2f} max "
            f"{s.max():.2f}; "
            f"fingertip residual mm mean {r.mean():.2f} p95 {np.percentile(r, 95):.2f}; failed frames {failed}"
        )
    print(f"model build (URDF -> Pinocchio, optimiser) {build_s * 1e3:.0f} ms; torch threads {torch.get_num_threads()}")


if __name__ == "__main__":
    main()
