"""Task success as a function of the object's state, vectorised over the batch.

Each task's criterion and its parameters come from the task itself (``Task.criterion`` of its
module in ``touch2robot.scenes``, parameters in ``TaskSpec.success``); ``SuccessTracker`` holds the
episode's start state and the latest outcome of every copy.
"""

from __future__ import annotations

import numpy as np

from touch2robot import scenes
from touch2robot.scenes.spec import TaskSpec


class SuccessTracker:
    """Per-copy success bookkeeping of one task over the episode.

    ``reset(ids, pos, quat)`` stores the initial object state of copies ``ids``;
    ``update(pos, quat, opening)`` is called once per control step with the whole batch
    (``opening`` is the drawer's slide position, zeros for free objects).
    """

    def __init__(self, spec: TaskSpec, n: int) -> None:
        self.spec = spec
        self.criterion = scenes.task(spec.name).criterion(spec, n)
        self.pos0 = np.zeros((n, 3))
        self.quat0 = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
        self.success = np.zeros(n, dtype=bool)
        self.progress = np.zeros(n)

    def reset(self, ids: np.ndarray, pos: np.ndarray, quat: np.ndarray) -> None:
        """Start the episode of copies ``ids`` from object poses ``pos`` (k, 3), ``quat`` (k, 4)."""
        self.pos0[ids] = pos
        self.quat0[ids] = quat
        self.criterion.reset(ids)
        self.success[ids] = False
        self.progress[ids] = 0.0

    def update(self, pos: np.ndarray, quat: np.ndarray, opening: np.ndarray) -> None:
        """Advance the bookkeeping with the current object state of every copy."""
        self.success, self.progress = self.criterion.update(self.pos0, self.quat0, pos, quat, opening)
