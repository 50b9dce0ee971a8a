"""What a task module of ``touch2robot.scenes`` declares: its ``TASK``, and the success criterion the simulation
asks it for."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from touch2robot.scenes.spec import TaskSpec
from touch2robot.synth.hand import HumanHand
from touch2robot.synth.motion import Trajectory


class SuccessCriterion(ABC):
    """A task's success and progress (in [0, 1]) over an episode, vectorised over the ``n`` copies
    of a batch. A criterion that needs the episode's history (maximum lift, visited waypoints) keeps
    it per copy and clears it in ``reset``."""

    def __init__(self, spec: TaskSpec, n: int) -> None:
        self.spec = spec

    def reset(self, ids: np.ndarray) -> None:  # noqa: B027 (stateless criteria have no history to clear)
        """Forget the history of copies ``ids``: their episodes start again."""

    @abstractmethod
    def update(
        self, pos0: np.ndarray, quat0: np.ndarray, pos: np.ndarray, quat: np.ndarray, opening: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(success (n,) bool, progress (n,)) of every copy from its object state: ``pos0`` (n, 3) and
        ``quat0`` (n, 4) at the episode's start, ``pos`` and ``quat`` now, and ``opening`` (n,) the
        drawer's slide position (zeros for free objects). Called once per control step."""


# a scripted human demonstration: (spec, subject's hand, random generator, pace) -> wrist, finger and object motion
Demonstration = Callable[[TaskSpec, HumanHand, np.random.Generator, float], Trajectory]


@dataclass(frozen=True)
class Task:
    """One task of the suite, declared as ``TASK`` by its module in ``touch2robot.scenes``."""

    name: str
    # Place in the suite (TASKS is sorted by it): a task's index in TASKS seeds the demonstrator's random
    # streams and orders every output, so an existing task keeps its position and a new one takes the next.
    position: int
    instruction: str  # the language instruction of the task's robot demonstrations
    default_config: Callable[[], TaskSpec]
    demonstrate: Demonstration
    criterion: type[SuccessCriterion]
