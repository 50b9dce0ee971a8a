"""The profile's ``comparison`` section: what every method is compared with, and how."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from schemas.vocabulary import Method


class ComparisonConfig(BaseModel):
    """Intervals and paired tests of the ``comparison`` table (touch2robot.comparison.statistics)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    versus: Method = Field(
        default=Method.TOUCH2ROBOT,
        description="the method every other method is compared with, demonstration by demonstration",
    )
    confidence: float = Field(default=0.95, gt=0.5, lt=1, description="coverage of every interval")
    # 10,000 resamples: a 95 % bound of F1 over 8 demonstrations moves by ~0.001 (s.d.) between seeds (2,000: ~0.004)
    n_resamples: int = Field(default=10_000, ge=100, le=1_000_000, description="bootstrap resamples per interval")
    seed: int = Field(default=0, ge=0, description="seed of the bootstrap draws (each cell draws from its own stream)")
