"""The unified student retargeter (Table VIII): one causal Transformer for all tasks, distilled
from the touch2robot teachers' rollouts, that turns a new glove demonstration into robot joint
targets, wrist commands and predicted contacts without running RL.

- ``config``: ``StudentConfig`` (paper defaults) and the ablation variants.
- ``features``: the per-step inputs of a demonstration (shared by augmentation and inference).
- ``augment``: paired human-robot sequences from teacher rollouts, jittered to 400 rollouts.
- ``model``: PointNet geometry encoder + causal Transformer; the single-tensor serving form.
- ``train``: AdamW distillation with demonstration-level validation and checkpoint resume.
- ``infer``: streaming (step by step, 16-step history) and batched offline inference.
- ``execute``: the student's commands executed in MuJoCo (rollouts, reconstructed contacts).

Only the configuration is imported here (no torch or mujoco).
"""

from touch2robot.student.config import Ablation, StudentConfig

__all__ = ["Ablation", "StudentConfig"]
