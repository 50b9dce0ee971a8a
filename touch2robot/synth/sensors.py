"""Sensor model of the demonstrator's glove (the robot's TwinTac and FSR models are the twin's:
``touch2robot.twin.sensors``). The demonstrator's hand has 256 skin points (``schemas.glove``); a rig's glove
samples them through :func:`taxel_pooling`, so any rig layout can be recorded.

Each recording gets its own baseline offsets, gains, noise level, drift and crosstalk,
so a single global threshold cannot binarise every recording: thresholds must be
estimated per recording (see ``touch2robot.contacts``)."""

from __future__ import annotations

import numpy as np

from schemas.glove import TAXEL_REGION
from schemas.rig import Glove

ADC_MAX = 4095.0  # 12-bit readout
CROSSTALK_ROW = 16  # taxels sharing a row line of the resistive matrix


def taxel_pooling(glove: Glove) -> np.ndarray:
    """(rig taxels, 256 skin points): which skin points each of a rig's taxels feels. A region's skin points
    are split, in order, into as many runs as the rig gives the region taxels (a coarser glove's taxel
    covers several points; a finer one's leaves some taxels of a small region without any); taxels of no
    region share the phalanx points alike. The simulated rig's glove is the identity."""
    skin = np.asarray(TAXEL_REGION)
    rig = np.asarray(glove.region_of_taxel())
    pooling = np.zeros((len(rig), len(skin)), dtype=np.float64)
    for region in dict.fromkeys(skin):
        taxels = np.flatnonzero(rig == region)
        if len(taxels):
            for taxel, points in zip(taxels, np.array_split(np.flatnonzero(skin == region), len(taxels)), strict=True):
                pooling[taxel, points] = 1.0
    return pooling


def glove_readings(taxel_force: np.ndarray, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Raw glove counts (T, N) for per-taxel forces (T, N) in N."""
    n, width = taxel_force.shape
    base_level = rng.uniform(40.0, 600.0)
    baseline = base_level + rng.normal(0.0, 0.08 * base_level, width)
    gain = rng.uniform(25.0, 60.0) * rng.uniform(0.7, 1.3, width)  # counts per N
    noise = rng.uniform(0.5, 1.5)
    crosstalk = rng.uniform(0.02, 0.08)
    lines = np.arange(width) // CROSSTALK_ROW
    rows = np.stack([taxel_force[:, lines == k].mean(axis=1) for k in range(lines[-1] + 1)], 1)
    leak = rows[:, lines] * crosstalk
    drift = rng.uniform(0.0, 4.0) * np.sin(2 * np.pi * t / rng.uniform(20.0, 60.0) + rng.uniform(0, 2 * np.pi))
    raw = baseline + drift[:, None] + gain * (taxel_force + leak) + rng.normal(0.0, noise, (n, width))
    return np.clip(np.round(raw), 0.0, ADC_MAX).astype(np.float32)
