"""Student retargeter speed on one core: per-step streaming latency (target < 2 ms: live
feedback at 20 Hz with room to spare) and batched offline throughput, next to the kinematic
retargeter's frames/s measured in the same run on the same recordings (bench/retarget.py's
baseline: the student's input is that retargeting, so a recording costs both).

    uv run python bench/student.py [--profile paper] [--tasks pick rotate wipe drawer] [--repeats 2]

The model has the profile's ``student`` sizes and random weights (speed does not depend on them).
Streaming is measured twice: through the eager modules (the baseline) and through the frozen
TorchScript trace that ``StreamingStudent`` runs by default.
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

from touch2robot.config import load_profile
from touch2robot.ingest import ingest_file
from touch2robot.retarget import LEAP_DEFAULT
from touch2robot.retarget.lake import load_hand_motion
from touch2robot.retarget.retargeter import Retargeter, retarget_motion
from touch2robot.sim.scene import build_scene
from touch2robot.student.features import step_inputs
from touch2robot.student.infer import StreamingStudent, predict_recording
from touch2robot.student.model import StudentNet
from touch2robot.synth.config import SynthConfig
from touch2robot.synth.generate import RecordingJob, write_recording


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--profile", default="paper", help="whose student sizes (default the paper's)")
    parser.add_argument("--tasks", nargs="+", default=["pick", "rotate", "wipe", "drawer"])
    parser.add_argument("--repeats", type=int, default=2, help="passes (the first warms caches)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    cfg = load_profile(args.profile).student
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        synth = SynthConfig(tasks=tuple(args.tasks), subjects=1, demos_per_subject=1)
        motions = []
        for task in args.tasks:
            path = write_recording(synth, RecordingJob(task, 1, 1), root / "rec", root / "gt")
            motions.append((task, load_hand_motion(root / "lake", ingest_file(path, root / "lake").recording_id)))
    retargeter = Retargeter(LEAP_DEFAULT)
    torch.manual_seed(0)
    net = StudentNet(cfg).eval()
    print(
        f"student ({args.profile}): d_model {cfg.d_model}, {cfg.layers} layers x {cfg.heads} heads, history "
        f"{cfg.history}, "
        f"{sum(p.numel() for p in net.parameters()) / 1e3:.0f}k parameters; torch threads {torch.get_num_threads()}"
    )
    for rep in range(args.repeats):
        frames, kin_s, batch_s = 0, 0.0, 0.0
        stream: dict[bool, list[float]] = {False: [], True: []}
        for task, motion in motions:
            t0 = time.perf_counter()
            result = retarget_motion(motion, LEAP_DEFAULT, retargeter)
            kin_s += time.perf_counter() - t0
            n = len(result.t)
            wrist = np.concatenate([result.wrist_pos, result.wrist_quat], axis=1)
            # the object pose and preference do not change the cost; the wrist stands in for them
            inputs = step_inputs(result.joints, wrist, wrist, np.zeros((n, 8)))
            points = build_scene(task).point_cloud
            t0 = time.perf_counter()
            predict_recording(net, inputs, points)
            batch_s += time.perf_counter() - t0
            for compiled in (False, True):
                streaming = StreamingStudent(net, points, compiled=compiled)
                for x in inputs:
                    t0 = time.perf_counter()
                    streaming.step(x)
                    stream[compiled].append(time.perf_counter() - t0)
            frames += n
        kin_fps, batch_fps = frames / kin_s, frames / batch_s
        print(
            f"pass {rep + 1}: {frames} frames of {len(motions)} recordings | kinematic retargeting {kin_fps:.0f} "
            "frames/s | "
            f"student batched {batch_fps:.0f} steps/s ({batch_fps / kin_fps:.1f}x the retargeter)"
        )
        eager = np.median(stream[False])
        for compiled, label in ((False, "eager modules"), (True, "frozen trace (default)")):
            ms = np.array(stream[compiled]) * 1e3
            print(
                f"  streaming, {label:22s}: ms/step mean {ms.mean():.2f} p50 {np.median(ms):.2f} p95 "
                f"{np.percentile(ms, 95):.2f} "
                f"max {ms.max():.2f} ({1e3 / ms.mean():.0f} steps/s; p50 {eager / np.median(stream[compiled]):.2f}x "
                "the eager path; "
                f"target < 2 ms: {'met' if np.percentile(ms, 95) < 2 else 'NOT met'} at p95)"
            )


if __name__ == "__main__":
    main()
