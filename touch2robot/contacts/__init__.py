"""Contacts: thresholds, binarisation and alignment of human and real-robot tactile
streams onto the shared eight-region space (T1..T4, P1..P4; T5 excluded).

Glove threshold method (per recording, fingertip and palm separately):
1. per-taxel resting level b_i = ``baseline_quantile`` of its counts over the recording
   (demonstrations start and end with the hand free, so each taxel rests at least that often),
   then the common mode m(t) = 25%-trimmed mean over all taxels of (x_i(t) - b_i) is removed: most taxels
   are unloaded at any instant, so m tracks the glove's shared drift and the quantile's bias;
2. regional response r_k(t) = sum over the region's taxels of (x_i(t) - b_i - m(t)), smoothed by a
   ``smoothing_samples`` moving average;
3. robust noise sigma_k = 1.4826 * MAD(diff r_k) / sqrt(2) on the unsmoothed response (first
   differences cancel slow contact plateaus, so contacts do not inflate it), divided by
   sqrt(window) for the smoothed response;
4. group threshold = ``glove_noise_k`` x the median sigma of the group's regions (one value
   for the five fingertips, one for the four palm pads), and contact = r_k > threshold.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyarrow as pa

from schemas.rig import DEFAULT_RIG, Glove, Robot
from schemas.tables import FINGERTIP_REGIONS, HUMAN_REGIONS, PALM_REGIONS, ROBOT_REGIONS
from touch2robot.contacts.config import ContactsConfig

__all__ = ["ContactsConfig", "GloveThresholds", "glove_contacts", "real_contacts", "twintac_thresholds"]


@dataclass(frozen=True)
class GloveThresholds:
    fingertip: float
    palm: float
    noise: dict[str, float]
    baseline: np.ndarray  # per taxel resting level


def _moving_average(x: np.ndarray, n: int) -> np.ndarray:
    if n <= 1:
        return x
    kernel = np.ones(n) / n
    pad = np.pad(x, ((n // 2, n - 1 - n // 2), (0, 0)), mode="edge")
    return np.stack([np.convolve(pad[:, k], kernel, mode="valid") for k in range(x.shape[1])], 1)


def regional_responses(
    values: np.ndarray, config: ContactsConfig, glove: Glove = DEFAULT_RIG.glove
) -> tuple[np.ndarray, np.ndarray]:
    """Baseline-corrected responses (T, 9) in HUMAN_REGIONS order (unsmoothed), and the per-taxel baseline;
    ``glove``: the rig's taxel layout."""
    taxel_region = np.asarray(glove.region_of_taxel())
    if values.ndim != 2 or values.shape[1] != len(taxel_region):
        raise ValueError(f"glove values must be (time, {len(taxel_region)}), got {values.shape}")
    baseline = np.quantile(values, config.baseline_quantile, axis=0)
    corrected = values - baseline
    # common mode: most taxels are unloaded at any instant, so a robust mean over the glove
    # tracks the shared drift and the quantile's noise bias; remove it from every taxel.
    # A trimmed mean, not the median: counts are integers and a median of integers is
    # biased by up to half a count, which adds up over a region's taxels.
    # imported here: scipy.stats takes 0.55 s, and every command's profile check imports this package
    from scipy.stats import trim_mean

    corrected -= trim_mean(corrected, 0.25, axis=1)[:, None]
    resp = np.stack([corrected[:, r == taxel_region].sum(axis=1) for r in HUMAN_REGIONS], 1)
    return resp, baseline


def _robust_noise(x: np.ndarray) -> float:
    d = np.diff(x)
    if d.size == 0:
        return 0.0
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0))


def glove_thresholds(resp: np.ndarray, baseline: np.ndarray, config: ContactsConfig) -> GloveThresholds:
    """Thresholds for the *smoothed* responses: white noise measured on the raw responses,
    divided by sqrt(window) for the moving average."""
    shrink = np.sqrt(config.smoothing_samples)
    noise = {r: _robust_noise(resp[:, k]) / shrink for k, r in enumerate(HUMAN_REGIONS)}
    tip = config.glove_noise_k * float(np.median([noise[r] for r in FINGERTIP_REGIONS]))
    palm = config.glove_noise_k * float(np.median([noise[r] for r in PALM_REGIONS]))
    return GloveThresholds(tip, palm, noise, baseline)


def region_limits(thr: GloveThresholds, config: ContactsConfig, glove: Glove) -> np.ndarray:
    """Each region's threshold in HUMAN_REGIONS order: its group's, scaled where the rig gives the region
    its own ``threshold_k`` in place of ``contacts.glove_noise_k``."""
    limits = []
    for r in HUMAN_REGIONS:
        group = thr.fingertip if r in FINGERTIP_REGIONS else thr.palm
        k = glove.threshold_k(r)
        limits.append(group if k is None else group * k / config.glove_noise_k)
    return np.asarray(limits)


def glove_contacts(
    t: np.ndarray, values: np.ndarray, config: ContactsConfig, glove: Glove = DEFAULT_RIG.glove
) -> tuple[np.ndarray, np.ndarray, GloveThresholds]:
    """Binary human contacts (T, 9) in HUMAN_REGIONS order, the responses, and the thresholds; ``glove``:
    the rig's taxel layout."""
    if not np.isfinite(values).all():
        raise ValueError("glove values contain NaN/inf")
    raw, baseline = regional_responses(values, config, glove)
    thr = glove_thresholds(raw, baseline, config)
    resp = _moving_average(raw, config.smoothing_samples)
    return resp > region_limits(thr, config, glove), resp, thr


def twintac_thresholds(calibration: np.ndarray, config: ContactsConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-channel thresholds from an unloaded calibration recording (T, 16):
    mean + k * std; returns (threshold, mean, std)."""
    mean = calibration.mean(axis=0)
    std = calibration.std(axis=0)
    return mean + config.twintac_noise_k * std, mean, std


def real_contacts(
    twintac: np.ndarray,
    twintac_threshold: np.ndarray,
    fsr: np.ndarray,
    config: ContactsConfig,
    robot: Robot = DEFAULT_RIG.robot,
) -> tuple[np.ndarray, np.ndarray]:
    """Real-robot contacts: fingertip region = any of its TwinTac channels above its
    threshold -> (T_tt, 4) for T1..T4; palm pad = any of its FSR channels above the FSR
    threshold (0 in native units) -> (T_fsr, 4) for P1..P4. ``robot``: the rig's channels."""
    over = twintac > twintac_threshold
    tips = by_region(over, robot.twintac.regions, ROBOT_REGIONS[:4], np.any)
    return tips, by_region(fsr > config.fsr_threshold, robot.fsr.regions, ROBOT_REGIONS[4:], np.any)


def by_region(channels: np.ndarray, channel_region: tuple[str, ...], regions: tuple[str, ...], reduce) -> np.ndarray:
    """(T, channels) -> (T, regions): ``reduce`` (np.any, np.max, ...) over each region's channels."""
    where = np.asarray(channel_region)
    return np.stack([reduce(channels[:, where == r], axis=1) for r in regions], 1)


def long_rows(
    *,
    source: str,
    method: str,
    task: str,
    subject: str,
    sequence_id: str,
    reference_id: str,
    t: np.ndarray,
    t_ref: np.ndarray,
    regions: tuple[str, ...],
    contact: np.ndarray,
    value: np.ndarray,
) -> pa.Table:
    """Wide (time, region) arrays -> rows of the long ``contacts`` table."""
    n, k = contact.shape
    const = lambda v: pa.array([v] * (n * k), pa.string())  # noqa: E731
    return pa.table(
        {
            "source": const(source),
            "method": const(method),
            "task": const(task),
            "subject": const(subject),
            "sequence_id": const(sequence_id),
            "reference_id": const(reference_id),
            "t": np.repeat(t, k),
            "t_ref": np.repeat(t_ref, k),
            "region": pa.array(np.tile(np.asarray(regions), n)),
            "contact": contact.reshape(-1),
            "value": value.reshape(-1).astype(np.float32),
        }
    )
