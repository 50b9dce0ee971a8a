"""Sensor models of the twin: region forces (N) -> raw readings as the rig's drivers publish them.

The physics are those of the demonstrator's models (touch2robot/synth/sensors.py): TwinTac fingertips
with a per-channel baseline, gain, white noise and a contact spread over four channels; palm FSRs that
read exactly 0 below their activation force. Here every parameter is drawn per replay from a
``TwinConfig`` range, the TwinTac channels also drift slowly and saturate at the ADC's full scale, and
the FSRs follow a power law and saturate too. Readings are pure functions of force, time and noise
drawn up front, so a replay can be read in pieces as its physics arrives.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from schemas.rig import DEFAULT_RIG
from touch2robot.twin.config import ADC_MAX, TwinConfig

# the simulated rig's sensors: 4 TwinTac fingertips (T1..T4, channels in tip order) and 4 palm FSRs
N_TWINTAC_CHANNELS = len(DEFAULT_RIG.robot.twintac.regions)
N_FSR_CHANNELS = len(DEFAULT_RIG.robot.fsr.regions)
CHANNELS_PER_TIP = N_TWINTAC_CHANNELS // 4
SPREAD_CONCENTRATION = 3.0  # Dirichlet concentration of a contact's share over a tip's channels


def _uniform(bounds: tuple[float, float], rng: np.random.Generator, size: int | None = None) -> np.ndarray:
    return rng.uniform(bounds[0], bounds[1], size)


@dataclass(frozen=True)
class TwinTac:
    """One physical set of four fingertip sensors (thumb, index, middle, ring) x four channels. The
    calibration and the replay of a session share it; each recording sits at its own small offset."""

    baseline: np.ndarray  # (16,) unloaded counts
    sensitivity: np.ndarray  # (16,) counts per N of the tip's force: gain x the channel's share of the contact
    noise: np.ndarray  # (16,) white noise std, counts
    drift_rate: np.ndarray  # (16,) counts/s within a recording
    offset_sigma: np.ndarray  # (16,) std of a recording's offset from the baseline, counts

    @classmethod
    def draw(cls, twin: TwinConfig, rng: np.random.Generator) -> TwinTac:
        gain = _uniform(twin.twintac_gain_counts_per_n, rng, N_TWINTAC_CHANNELS)
        contact = rng.dirichlet(np.full(CHANNELS_PER_TIP, SPREAD_CONCENTRATION), size=4).reshape(-1)
        share = (1.0 - twin.twintac_spread) / CHANNELS_PER_TIP + twin.twintac_spread * contact
        noise = _uniform(twin.twintac_noise_counts, rng, N_TWINTAC_CHANNELS)
        return cls(
            baseline=_uniform(twin.twintac_baseline_counts, rng, N_TWINTAC_CHANNELS),
            sensitivity=gain * share,
            noise=noise,
            drift_rate=rng.uniform(-1.0, 1.0, N_TWINTAC_CHANNELS) * twin.twintac_drift_counts_per_s,
            offset_sigma=twin.twintac_offset_drift * noise,
        )

    def recording_offset(self, rng: np.random.Generator) -> np.ndarray:
        """(16,) where this sensor set sits, for one recording, relative to its baseline."""
        return rng.normal(0.0, 1.0, N_TWINTAC_CHANNELS) * self.offset_sigma

    def white_noise(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """(n, 16) white noise of n readings, in counts."""
        return rng.normal(0.0, 1.0, (n, N_TWINTAC_CHANNELS)) * self.noise

    def read(self, tip_force: np.ndarray, t: np.ndarray, offset: np.ndarray, white: np.ndarray) -> np.ndarray:
        """Raw counts (T, 16) for the four fingertip forces (T, 4) in N at recording times ``t`` (T,) s,
        with this recording's ``offset`` (16,) and ``white`` noise (T, 16)."""
        load = np.repeat(np.maximum(tip_force, 0.0), CHANNELS_PER_TIP, axis=1) * self.sensitivity
        raw = self.baseline + offset + self.drift_rate * t[:, None] + load + white
        return np.clip(np.round(raw), 0.0, ADC_MAX).astype(np.float32)


@dataclass(frozen=True)
class PalmFsr:
    """Four palm force-sensing resistors (P1..P4) in the driver's native units: exactly 0 below the
    activation force, then ``gain`` x (force - activation)^``exponent`` with multiplicative noise,
    saturating at the ADC's full scale."""

    activation: np.ndarray  # (4,) N
    gain: np.ndarray  # (4,) units at 1 N above activation
    exponent: np.ndarray  # (4,)
    noise: np.ndarray  # (4,) log-normal sigma

    @classmethod
    def draw(cls, twin: TwinConfig, rng: np.random.Generator) -> PalmFsr:
        return cls(
            activation=_uniform(twin.fsr_activation_n, rng, N_FSR_CHANNELS),
            gain=_uniform(twin.fsr_gain, rng, N_FSR_CHANNELS),
            exponent=_uniform(twin.fsr_exponent, rng, N_FSR_CHANNELS),
            noise=_uniform(twin.fsr_noise, rng, N_FSR_CHANNELS),
        )

    def noise_factor(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """(n, 4) multiplicative noise of n readings."""
        return np.exp(rng.normal(0.0, 1.0, (n, N_FSR_CHANNELS)) * self.noise)

    def read(self, palm_force: np.ndarray, factor: np.ndarray) -> np.ndarray:
        """Readings (T, 4) for the pad forces (T, 4) in N, with ``noise_factor`` draws (T, 4)."""
        over = np.maximum(palm_force - self.activation, 0.0)
        value = self.gain * over**self.exponent * factor
        return np.clip(np.round(value), 0.0, ADC_MAX).astype(np.float32)


def sensor_summary(twintac: TwinTac, fsr: PalmFsr) -> dict[str, float]:
    """The drawn sensor parameters in a few numbers (for run parameters and artefacts)."""
    return {
        "twintac_sensitivity_mean": float(twintac.sensitivity.mean()),
        "twintac_noise_mean": float(twintac.noise.mean()),
        "twintac_drift_max": float(np.abs(twintac.drift_rate).max()),
        "fsr_activation_mean": float(fsr.activation.mean()),
        "fsr_gain_mean": float(fsr.gain.mean()),
        "fsr_exponent_mean": float(fsr.exponent.mean()),
        "fsr_noise_mean": float(fsr.noise.mean()),
    }
