"""Configuration of the simulated demonstrator."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from touch2robot.scenes import TASKS


class SynthConfig(BaseModel):
    """How many recordings the demonstrator writes. Defaults are the ``paper`` profile:
    3 subjects x 10 demonstrations = 30 glove sessions per task."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    seed: int = 0
    tasks: tuple[str, ...] = TASKS
    subjects: int = Field(default=3, ge=1)
    demos_per_subject: int = Field(default=10, ge=1)
    pace: float = Field(
        default=1.0, gt=0, description="time stretch of every scripted motion (longer recordings when > 1)"
    )
