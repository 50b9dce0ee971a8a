"""Running a trained student: streaming (one step at a time, the last ``history`` steps kept,
what a live-feedback interface needs) and batched offline inference over a whole recording.

Both compute step j from the same window: inputs j - H + 1 .. j, where steps before the first
are the first step repeated (the hand is still before a recording starts), and take the
window's last output. So they agree to float rounding (tests/test_student.py checks it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from touch2robot.student.features import INPUT_DIM, WRIST_UNITS
from touch2robot.student.model import StudentNet, split_outputs


@dataclass(frozen=True)
class StudentOutput:
    """Per step of a recording: absolute joint targets (T, 16) rad, the wrist residual around the
    kinematic wrist (T, 6) in m and rad (``features.wrist_residual``), contact logits (T, 8)."""

    joints: np.ndarray
    wrist_residual: np.ndarray
    contact_logits: np.ndarray

    @classmethod
    def from_raw(cls, out: np.ndarray) -> StudentOutput:
        joints, wrist, logits = split_outputs(out)
        return cls(joints.astype(np.float64), wrist.astype(np.float64) * WRIST_UNITS, logits.astype(np.float64))


def padded_windows(inputs: torch.Tensor, history: int) -> torch.Tensor:
    """(T, D) -> (T, history, D): window j ends at step j, left-padded with step 0."""
    padded = torch.cat([inputs[:1].expand(history - 1, -1), inputs], dim=0)
    return padded.unfold(0, history, 1).permute(0, 2, 1)


@torch.inference_mode()
def predict_recording(net: StudentNet, inputs: np.ndarray, points: np.ndarray, batch: int = 512) -> StudentOutput:
    """Batched offline inference: every step of a recording's (T, INPUT_DIM) inputs, with the
    object's (P, 3) surface points."""
    net.eval()
    x = torch.as_tensor(inputs, dtype=torch.float32)
    windows = padded_windows(x, net.history)
    geometry = net.geometry(torch.as_tensor(points, dtype=torch.float32)[None])
    out = [net(w, geometry.expand(len(w), -1))[:, -1] for w in windows.split(batch)]
    return StudentOutput.from_raw(torch.cat(out).numpy())


class StreamingStudent:
    """Step-by-step inference for live use: ``step`` takes one (INPUT_DIM,) input and returns
    that step's raw output (OUTPUT_DIM,); the geometry feature is computed once per object.

    The window is a fixed (1, history, INPUT_DIM) buffer shifted in place, and the network runs
    as a frozen TorchScript trace of that one shape (``compiled``, the default): on one core that
    removes most of the per-step Python overhead of the eager modules (bench/student.py), with
    the same outputs."""

    def __init__(self, net: StudentNet, points: np.ndarray, compiled: bool = True) -> None:
        net.eval()
        self.net = net
        with torch.inference_mode():
            self.geometry = net.geometry(torch.as_tensor(points, dtype=torch.float32)[None])
        self.window = torch.zeros(1, net.history, INPUT_DIM)
        self.started = False
        self.forward = _frozen(net, self.window, self.geometry) if compiled else net

    def reset(self) -> None:
        """A new recording starts."""
        self.started = False

    @torch.inference_mode()
    def step(self, inputs: np.ndarray) -> np.ndarray:
        x = torch.as_tensor(inputs, dtype=torch.float32)
        if self.started:
            self.window[0, :-1] = self.window[0, 1:].clone()
            self.window[0, -1] = x
        else:  # before the recording the hand is still: the first step fills the window
            self.window[0] = x
            self.started = True
        return self.forward(self.window, self.geometry)[0, -1].numpy()

    def run(self, inputs: np.ndarray) -> StudentOutput:
        """A whole recording fed step by step (the streaming path, for comparison and replay)."""
        self.reset()
        return StudentOutput.from_raw(np.stack([self.step(x) for x in inputs]))


def _frozen(net: StudentNet, window: torch.Tensor, geometry: torch.Tensor) -> torch.jit.ScriptModule:
    """``net`` traced for one window shape, frozen and optimised for inference, and warmed up
    (TorchScript's profiling executor specialises the graph on its first runs: a live first step
    would otherwise take tens of milliseconds)."""
    with torch.no_grad():
        traced = torch.jit.optimize_for_inference(
            torch.jit.freeze(torch.jit.trace(net, (window, geometry), check_trace=False))
        )
    with torch.inference_mode():
        for _ in range(3):
            traced(window, geometry)
    return traced
