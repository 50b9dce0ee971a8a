"""When a rig's messages are stamped: the recordings' epoch and the ticks of a sensor stream."""

from __future__ import annotations

import numpy as np

EPOCH_NS = 1_767_225_600 * 10**9  # 2026-01-01T00:00:00Z: recordings start from here


def stamps(duration: float, rate: float, rng: np.random.Generator, start: float = 0.0) -> np.ndarray:
    """Sample times (s) of a stream over ``duration`` s from ``start``: it begins up to 10 ms late and
    ticks at ``rate`` with up to a fifth of a period of jitter (strictly increasing)."""
    t = start + rng.uniform(0.0, 0.01) + np.arange(0.0, duration, 1.0 / rate)
    return t + rng.uniform(0.0, 0.2 / rate, t.size)


def to_ns(t0_ns: int, t: np.ndarray) -> np.ndarray:
    """Absolute stamps (int64 ns) of times ``t`` (s) after ``t0_ns``."""
    return t0_ns + np.round(t * 1e9).astype(np.int64)
