"""Configuration of the hardware twin: how far one replay's rig may differ from the training scene.

Every ``(low, high)`` pair is a range that one value is drawn from, uniformly, per replay (seeded);
``low == high`` fixes it. Scales multiply the nominal scene's value (1 = unchanged); offsets add to it.
Sources of the physics ranges (public LEAP Hand sim-to-real setups):
- [PG] MuJoCo Playground, LEAP Hand domain randomisation: ``domain_randomize`` in
  github.com/google-deepmind/mujoco_playground, mujoco_playground/_src/manipulation/leap_hand/reorient.py
- [LS] LEAP_Hand_Sim (IsaacGym), github.com/leap-hand/LEAP_Hand_Sim, leapsim/cfg/task/LeapHandRot.yaml
  (``randomization`` and ``controller`` sections)
- [LA] LEAP Hand API readme, github.com/leap-hand/LEAP_Hand_API (USB latency, servo current limit)
- [XC] ROBOTIS e-manual, Dynamixel XC330-T288: emanual.robotis.com/docs/en/dxl/x/xc330-t288/ (resolution)
- [FSR] Interlink FSR 402 data sheet (FSR 400 series): actuation force 0.1 N, sensitivity range 0.1-10 N,
  force repeatability +-2 % single part, +-6 % part to part; Adafruit's FSR 402 notes give ~0.2 N actuation
Sensor ranges of the TwinTac fingertips have no public figures (the Touch2Robot paper names the sensor but
gives no noise, gain or drift values): they are the project's demonstrator model (touch2robot/synth/sensors.py)
on a 12-bit ADC, with the reason given in each field.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, model_validator

ADC_MAX = 4095.0  # 12-bit readout of the TwinTac and FSR channels

FrictionScale = Annotated[float, Field(ge=0.2, le=3.0)]
MassScale = Annotated[float, Field(ge=0.25, le=4.0)]
ServoScale = Annotated[float, Field(ge=0.5, le=2.0)]
LatencyS = Annotated[float, Field(ge=0.0, le=0.2)]
EncoderNoiseRad = Annotated[float, Field(ge=0.0, le=0.05)]
Counts = Annotated[float, Field(ge=0.0, le=ADC_MAX)]
CountsPerN = Annotated[float, Field(gt=0.0, le=5000.0)]
NoiseCounts = Annotated[float, Field(ge=0.0, le=100.0)]
ActivationN = Annotated[float, Field(ge=0.0, le=2.0)]
FsrGain = Annotated[float, Field(gt=0.0, le=2000.0)]
Exponent = Annotated[float, Field(ge=0.3, le=1.5)]
LogSigma = Annotated[float, Field(ge=0.0, le=0.5)]


class TwinConfig(BaseModel):
    """Per-replay perturbations of the rig (physics) and of its sensors. ``TwinConfig()`` is the default
    perturbed twin; ``TwinConfig.nominal()`` is the training scene itself with fixed, drift-free sensors."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    # ---- physics of the rig
    friction_scale: tuple[FrictionScale, FrictionScale] = Field(
        default=(0.7, 1.4),
        description="sliding friction of the hand's geoms and, drawn separately, of the object's: wear, dust "
        "and pad material. [PG] draws fingertip friction U(0.5, 1.0) around its pads' 0.7 (x0.71..1.43); "
        "[LS] draws 0.3..3.0, which covers very different objects rather than one rig",
    )
    object_mass_scale: tuple[MassScale, MassScale] = Field(
        default=(0.8, 1.2),
        description="object mass and inertia (scaled together: the same shape, another density). [PG] x0.8..1.2",
    )
    object_com_offset_m: Annotated[float, Field(ge=0.0, le=0.03)] = Field(
        default=0.005,
        description="object centre of mass moved by U(-x, x) m per axis: uneven fill or inserts. [PG] +-5 mm; "
        "[LS] +-10 mm",
    )
    joint_damping_scale: tuple[ServoScale, ServoScale] = Field(
        default=(0.8, 1.2), description="damping of each hand joint, drawn per joint: servo wear. [PG] x0.8..1.2"
    )
    armature_scale: tuple[ServoScale, ServoScale] = Field(
        default=(1.0, 1.05),
        description="rotor inertia (armature) of each hand joint, drawn per joint: gearbox differences. "
        "[PG] x1.0..1.05",
    )
    kp_scale: tuple[ServoScale, ServoScale] = Field(
        default=(0.8, 1.2),
        description="position gain of each servo, drawn per joint (bias -kp and -kd follow): the Dynamixel "
        "PD loop differs from its model. [PG] x0.8..1.2; [LS] P gain 2.9..3.1 (x0.97..1.03)",
    )
    force_limit_scale: tuple[ServoScale, ServoScale] = Field(
        default=(0.8, 1.2),
        description="torque limit of each servo, drawn per joint. No public randomisation range: the limit is "
        "a current limit ([LA]: 300 mA by default, 550 mA when raised), and units, supply voltage and "
        "temperature move the torque it gives by tens of percent",
    )
    latency_s: tuple[LatencyS, LatencyS] = Field(
        default=(0.0, 0.03),
        description="command latency (rounded to physics steps): host, USB and servo bus. [LS] executes actions "
        "one step late (exec_lag: 1); [LA] notes the USB latency timer (16 ms by default on FTDI adapters) "
        "and advises lowering it. No measured figure is public: 0..30 ms covers a tuned and an untuned bus",
    )
    encoder_noise_rad: tuple[EncoderNoiseRad, EncoderNoiseRad] = Field(
        default=(0.0, 0.003),
        description="white noise (std, rad) on the recorded joint positions only: [XC] 4096 pulses/rev is "
        "1.5e-3 rad per count; up to two counts of noise and backlash",
    )
    # ---- TwinTac fingertips: 4 sensors x 4 channels
    twintac_baseline_counts: tuple[Counts, Counts] = Field(
        default=(1000.0, 3000.0), description="unloaded level per channel: bridge offset of each channel"
    )
    twintac_gain_counts_per_n: tuple[CountsPerN, CountsPerN] = Field(
        default=(250.0, 500.0),
        description="counts per N of fingertip force at a channel (before the contact's spread over the four "
        "channels); with the ADC's 4095 counts the channels saturate at several N",
    )
    twintac_noise_counts: tuple[NoiseCounts, NoiseCounts] = Field(
        default=(2.0, 5.0), description="white noise (std, counts) per channel: a few LSB of a 12-bit ADC"
    )
    twintac_drift_counts_per_s: Annotated[float, Field(ge=0.0, le=10.0)] = Field(
        default=0.3,
        description="slow drift within a recording, a rate U(-x, x) counts/s per channel (thermal drift of the "
        "bridge): small against the calibration threshold over a replay of seconds",
    )
    twintac_offset_drift: Annotated[float, Field(ge=0.0, le=10.0)] = Field(
        default=0.5,
        description="offset of each recording from the sensor's baseline, std in units of the channel's noise: "
        "the drift between the unloaded calibration and the replay",
    )
    twintac_spread: Annotated[float, Field(ge=0.0, le=1.0)] = Field(
        default=1.0,
        description="how unevenly a contact loads the four channels of a fingertip: 0 = a quarter each, 1 = a "
        "Dirichlet(3) share drawn per replay (where on the tip the object presses)",
    )
    # ---- palm FSRs: 4 pads
    fsr_activation_n: tuple[ActivationN, ActivationN] = Field(
        default=(0.1, 0.2),
        description="force below which an FSR reads exactly 0: [FSR] 0.1 N (data sheet) to ~0.2 N (Adafruit)",
    )
    fsr_gain: tuple[FsrGain, FsrGain] = Field(
        default=(80.0, 200.0),
        description="driver units at 1 N above activation: the divider resistor and ADC of each pad",
    )
    fsr_exponent: tuple[Exponent, Exponent] = Field(
        default=(0.7, 1.0),
        description="power law of the reading in force above activation: an FSR's resistance falls as a power "
        "of force ([FSR] force curve, straight on log-log axes) and a divider readout compresses high forces",
    )
    fsr_noise: tuple[LogSigma, LogSigma] = Field(
        default=(0.02, 0.06),
        description="multiplicative (log-normal sigma) noise of a reading: [FSR] repeatability +-2 % single part "
        "to +-6 % part to part",
    )
    # ---- recordings
    calibration_s: float = Field(
        default=5.0, gt=0.0, le=600.0, description="length of the unloaded TwinTac calibration before each replay"
    )
    hold_s: float = Field(
        default=0.5, ge=0.0, le=10.0, description="time the replay keeps running after its last command, holding it"
    )

    @model_validator(mode="after")
    def _ordered_ranges(self) -> TwinConfig:
        for name, value in self:
            if isinstance(value, tuple) and value[0] > value[1]:
                raise ValueError(f"{name}: low {value[0]} is above high {value[1]}")
        return self

    @classmethod
    def nominal(cls) -> TwinConfig:
        """The training scene itself: no physics perturbation, no latency, no encoder noise, and sensors with
        fixed mid-range parameters (no drift, no per-replay variation; white noise at a fixed level, as any
        ADC has)."""
        return cls(
            friction_scale=(1.0, 1.0),
            object_mass_scale=(1.0, 1.0),
            object_com_offset_m=0.0,
            joint_damping_scale=(1.0, 1.0),
            armature_scale=(1.0, 1.0),
            kp_scale=(1.0, 1.0),
            force_limit_scale=(1.0, 1.0),
            latency_s=(0.0, 0.0),
            encoder_noise_rad=(0.0, 0.0),
            twintac_baseline_counts=(2000.0, 2000.0),
            twintac_gain_counts_per_n=(375.0, 375.0),
            twintac_noise_counts=(3.0, 3.0),
            twintac_drift_counts_per_s=0.0,
            twintac_offset_drift=0.0,
            twintac_spread=0.0,
            fsr_activation_n=(0.15, 0.15),
            fsr_gain=(140.0, 140.0),
            fsr_exponent=(1.0, 1.0),
            fsr_noise=(0.04, 0.04),
        )
