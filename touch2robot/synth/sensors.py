"""Sensor models of the rig: the 256-taxel glove, TwinTac fingertip sensors and palm FSRs.

Each recording gets its own baseline offsets, gains, noise level, drift and crosstalk,
so a single global threshold cannot binarise every recording: thresholds must be
estimated per recording (see ``touch2robot.contacts``)."""

from __future__ import annotations

import numpy as np

from schemas.glove import N_TAXELS
from schemas.messages import N_FSR_CHANNELS, N_TWINTAC_CHANNELS

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


class TwinTac:
    """Four fingertip sensors (thumb, index, middle, ring) with four channels each.
    One instance is one physical set of sensors: the calibration and the replays of a
    session share its baselines, with a small offset drift between recordings."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.baseline = rng.uniform(1000.0, 3000.0, N_TWINTAC_CHANNELS)
        self.noise = rng.uniform(2.0, 5.0, N_TWINTAC_CHANNELS)
        self.gain = rng.uniform(250.0, 500.0, N_TWINTAC_CHANNELS)  # counts per N on the channel
        self.rng = rng

    def read(self, fingertip_force: np.ndarray) -> np.ndarray:
        """Raw counts (T, 16) for the four fingertip forces (T, 4) in N."""
        n = fingertip_force.shape[0]
        share = self.rng.dirichlet(np.full(4, 3.0), size=4).reshape(-1)  # contact spread over channels
        drift = self.rng.normal(0.0, 0.5, N_TWINTAC_CHANNELS) * self.noise
        load = np.repeat(fingertip_force, 4, axis=1) * share * self.gain
        raw = self.baseline + drift + load + self.rng.normal(0.0, 1.0, (n, N_TWINTAC_CHANNELS)) * self.noise
        return np.round(raw).astype(np.float32)


def fsr_readings(palm_force: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Palm FSR output (T, 4) in the driver's native units: exactly 0 below the sensor's
    activation force, then roughly proportional to force with multiplicative noise."""
    activation = rng.uniform(0.15, 0.35, N_FSR_CHANNELS)
    gain = rng.uniform(80.0, 200.0, N_FSR_CHANNELS)
    over = np.maximum(palm_force - activation, 0.0)
    value = gain * over * rng.lognormal(0.0, 0.05, palm_force.shape)
    return np.round(value).astype(np.float32)
