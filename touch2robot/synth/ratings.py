"""SYNTHETIC user-study ratings: a plausible example file, not data from any participant.

The output has the long form that :func:`touch2robot.stats.user_study` reads (participant,
condition, question, rating) plus a ``synthetic`` column that is ``True`` on every row (and
``DataFrame.attrs["synthetic"] = True``) so the file can never be mistaken for real results.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from touch2robot.stats import CONDITIONS, QUESTIONS, RATING_MAX, RATING_MIN

__all__ = ["synthetic_ratings", "write_ratings_csv"]

# Touch2Robot is rated somewhat higher: a per-participant shift drawn from small integers with
# a mass at 0 so zero differences (ties between conditions) and tied |differences| occur.
_SHIFTS = np.array([-1, 0, 0, 1, 1, 1, 2, 2, 3])


def synthetic_ratings(n_participants: int = 10, seed: int = 0) -> pd.DataFrame:
    """Deterministic SYNTHETIC 7-point Likert ratings for ``n_participants`` x Q1..Q4 x 2 conditions.

    Returns:
        Long DataFrame with columns participant ("P01", ...), condition, question, rating
        (int 1..7) and synthetic (always True), sorted by participant, question, condition.
    """
    if n_participants < 1:
        raise ValueError(f"n_participants must be >= 1; got {n_participants}")
    rng = np.random.default_rng(seed)
    width = max(2, len(str(n_participants)))
    rows = []
    for i in range(n_participants):
        participant = f"P{i + 1:0{width}d}"
        leniency = rng.integers(-1, 2)  # some participants rate everything higher or lower
        for question in QUESTIONS:
            visual = int(np.clip(4 + leniency + rng.integers(-1, 2), RATING_MIN, RATING_MAX))
            touch = int(np.clip(visual + rng.choice(_SHIFTS), RATING_MIN, RATING_MAX))
            for condition, rating in zip(CONDITIONS, (visual, touch), strict=True):
                rows.append((participant, condition, question, rating, True))
    df = pd.DataFrame(rows, columns=["participant", "condition", "question", "rating", "synthetic"])
    df = df.astype({"rating": np.int64, "synthetic": bool})
    df.attrs["synthetic"] = True
    return df


def write_ratings_csv(
    path: str | os.PathLike[str],
    ratings: pd.DataFrame | None = None,
    *,
    n_participants: int = 10,
    seed: int = 0,
) -> Path:
    """Write ``ratings`` (default: :func:`synthetic_ratings`) to ``path`` atomically.

    The CSV is written to a temporary file in the destination directory, fsynced and moved over
    ``path`` with ``os.replace``, so readers see either the old file or the complete new one.
    """
    target = Path(path)
    df = synthetic_ratings(n_participants, seed) if ratings is None else ratings
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", newline="") as fh:
            df.to_csv(fh, index=False)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return target
