"""Sensor model of the rig's 256-taxel glove (the robot's TwinTac and FSR models are the twin's:
``touch2robot.twin.sensors``).

Each recording gets its own baseline offsets, gains, noise level, drift and crosstalk,
so a single global threshold cannot binarise every recording: thresholds must be
estimated per recording (see ``touch2robot.contacts``)."""

from __future__ import annotations

import numpy as np

from schemas.glove import N_TAXELS

ADC_MAX = 4095.0  # 12-bit readout
CROSSTALK_ROW = 16  # taxels sharing a row line of the resistive matrix


def glove_readings(taxel_force: np.ndarray, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Raw glove counts (T, 256) for per-taxel forces (T, 256) in N."""
    n = taxel_force.shape[0]
    base_level = rng.uniform(40.0, 600.0)
    baseline = base_level + rng.normal(0.0, 0.08 * base_level, N_TAXELS)
    gain = rng.uniform(25.0, 60.0) * rng.uniform(0.7, 1.3, N_TAXELS)  # counts per N
    noise = rng.uniform(0.5, 1.5)
    crosstalk = rng.uniform(0.02, 0.08)
    rows = taxel_force.reshape(n, -1, CROSSTALK_ROW).mean(axis=2)
    leak = np.repeat(rows, CROSSTALK_ROW, axis=1) * crosstalk
    drift = rng.uniform(0.0, 4.0) * np.sin(2 * np.pi * t / rng.uniform(20.0, 60.0) + rng.uniform(0, 2 * np.pi))
    raw = baseline + drift[:, None] + gain * (taxel_force + leak) + rng.normal(0.0, noise, (n, N_TAXELS))
    return np.clip(np.round(raw), 0.0, ADC_MAX).astype(np.float32)
