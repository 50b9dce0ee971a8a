"""Configuration of contact extraction (thresholds and binarisation)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class ContactsConfig(BaseModel):
    """Glove regions are binarised with per-recording thresholds, one for the fingertip
    regions and one for the palm regions; TwinTac channels with per-channel thresholds
    from an unloaded calibration recording; palm FSRs with threshold 0 (native units)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    baseline_quantile: float = Field(
        default=0.10, gt=0, lt=0.5, description="per-taxel resting level = this quantile over the recording"
    )
    smoothing_samples: int = Field(default=5, ge=1, description="moving-average window on regional responses")
    glove_noise_k: float = Field(default=5.0, gt=0, description="threshold = k x robust noise of the regional response")
    twintac_noise_k: float = Field(
        default=6.0, gt=0, description="threshold = calibration mean + k x calibration std, per channel"
    )
    fsr_threshold: float = 0.0
