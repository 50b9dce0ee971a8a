"""A rig: the glove and robot a lab records with, as a YAML rig file (``<name>.rig.yaml``).

A rig file says, per stream of the contract (schemas/messages.py), which topic carries it and at what rate;
the glove's taxel count, which taxels make each human region (fingertips T1..T5, palm P1..P4; taxels named by
no region, say on the phalanges, are read but belong to none) and per-region threshold options; the names of
the glove's 20 joint angles and of the robot's 16 joints in the contract's order; the robot's TwinTac and FSR
channels (which region each channel senses, and its units). A recording names its rig in the session field
``rig``; ingest reads every stream through that rig, and contacts read its regions and channels.

The demonstrator and the hardware twin record with :data:`DEFAULT_RIG` and write it beside their recordings
as ``simulated.rig.yaml``: the template for a lab's own.
"""

from __future__ import annotations

import hashlib
import re
from typing import Annotated

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, field_validator, model_validator

from schemas.glove import FINGERTIP_TAXELS, GLOVE_JOINT_NAMES, PALM_TAXELS, TAXEL_REGION
from schemas.messages import LEAP_JOINT_NAMES, N_KEYPOINTS, STREAM_TYPES, STREAMS_BY_KIND, Topic
from schemas.plausibility import NAME_PATTERN
from schemas.tables import FINGERTIP_REGIONS, PALM_REGIONS

RIG_SUFFIX = ".rig.yaml"
MAX_TAXELS = 4096  # the largest tactile glove arrays on record are about 1,000 taxels (STAG, 548)
_RANGE = re.compile(r"\s*(\d+)\s*-\s*(\d+)\s*")
# ROS 2 topic names: absolute, alphanumerics and underscores between slashes
_TOPIC = r"^/[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$"


def _taxel_list(value: object) -> object:
    """``[0, 1, "4-7"]`` -> ``[0, 1, 4, 5, 6, 7]``: a region lists taxel indices, or inclusive ranges "a-b"."""
    if not isinstance(value, list | tuple):
        return value
    out: list[object] = []
    for item in value:
        match = _RANGE.fullmatch(item) if isinstance(item, str) else None
        if match:
            low, high = int(match[1]), int(match[2])
            if high < low:
                raise ValueError(f"range {item!r} runs backwards")
            out.extend(range(low, high + 1))
        else:
            out.append(item)
    return out


def compact_ranges(indices: tuple[int, ...]) -> list[int | str]:
    """The inverse of a region's list: runs of 3 or more consecutive indices as "a-b"."""
    out: list[int | str] = []
    i = 0
    while i < len(indices):
        j = i
        while j + 1 < len(indices) and indices[j + 1] == indices[j] + 1:
            j += 1
        out.extend([f"{indices[i]}-{indices[j]}"] if j - i >= 2 else list(indices[i : j + 1]))
        i = j + 1
    return out


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Stream(_Strict):
    """One stream's topic and nominal rate (the recorder's; ingest reads the stamps, the rate documents)."""

    topic: str = Field(pattern=_TOPIC, max_length=200)
    rate_hz: float = Field(gt=0, le=10_000)


class Region(_Strict):
    """The taxels of one human region. ``threshold_k`` overrides ``contacts.glove_noise_k`` for this region
    (a pad a lab knows to be noisier or stiffer)."""

    taxels: Annotated[tuple[int, ...], BeforeValidator(_taxel_list)]
    threshold_k: float | None = Field(default=None, gt=0, le=100)


class Glove(_Strict):
    """The glove's taxel array: its size, and which taxels make each human region."""

    n_taxels: int = Field(ge=9, le=MAX_TAXELS)
    fingertip: dict[str, Region]
    palm: dict[str, Region]
    joint_names: tuple[str, ...] = GLOVE_JOINT_NAMES  # the SDK's names of the 20 angles, in the contract's order

    @model_validator(mode="after")
    def _regions_cover_the_vocabulary(self) -> Glove:
        seen: dict[int, str] = {}
        for group, expected in (("fingertip", FINGERTIP_REGIONS), ("palm", PALM_REGIONS)):
            regions: dict[str, Region] = getattr(self, group)
            if sorted(regions) != sorted(expected):
                missing = [r for r in expected if r not in regions]
                extra = [r for r in regions if r not in expected]
                raise ValueError(
                    f"{group}: the regions are {', '.join(expected)}"
                    + (f"; missing {', '.join(missing)}" if missing else "")
                    + (f"; unknown {', '.join(extra)}" if extra else "")
                )
            for name, region in regions.items():
                where = f"{group}.{name}.taxels"
                if not region.taxels:
                    raise ValueError(f"{where}: the region is empty; give it at least one taxel")
                for index in region.taxels:
                    if not 0 <= index < self.n_taxels:
                        raise ValueError(
                            f"{where}: taxel {index} is out of range (n_taxels {self.n_taxels}: 0..{self.n_taxels - 1})"
                        )
                    if index in seen:
                        raise ValueError(f"{where}: taxel {index} is also in {seen[index]}")
                    seen[index] = f"{group}.{name}"
        if len(self.joint_names) != len(GLOVE_JOINT_NAMES) or len(set(self.joint_names)) != len(self.joint_names):
            raise ValueError(f"joint_names: {len(GLOVE_JOINT_NAMES)} distinct names, in the contract's order")
        return self

    def region_of_taxel(self) -> tuple[str, ...]:
        """Each taxel's region, "-" for taxels of no region."""
        out = ["-"] * self.n_taxels
        for region_map in (self.fingertip, self.palm):
            for name, region in region_map.items():
                for index in region.taxels:
                    out[index] = name
        return tuple(out)

    def threshold_k(self, region: str) -> float | None:
        return {**self.fingertip, **self.palm}[region].threshold_k


class Channels(_Strict):
    """A robot tactile sensor's channels: which region each channel (in message order) senses, and the units
    of its readings."""

    units: str = Field(min_length=1, max_length=40)
    regions: tuple[str, ...]


class Robot(_Strict):
    """The robot hand: its 16 joint names in the contract's order, and its fingertip and palm sensors."""

    joint_names: tuple[str, ...]
    twintac: Channels
    fsr: Channels

    @model_validator(mode="after")
    def _joints_and_channels(self) -> Robot:
        if len(self.joint_names) != len(LEAP_JOINT_NAMES) or len(set(self.joint_names)) != len(self.joint_names):
            raise ValueError(
                f"joint_names: {len(LEAP_JOINT_NAMES)} distinct names, in the order "
                f"{', '.join(LEAP_JOINT_NAMES)} (got {len(self.joint_names)})"
            )
        for sensor, expected in (("twintac", FINGERTIP_REGIONS[:4]), ("fsr", PALM_REGIONS)):
            regions = getattr(self, sensor).regions
            if unknown := [r for r in regions if r not in expected]:
                raise ValueError(f"{sensor}.regions: {unknown[0]!r} is not one of {', '.join(expected)}")
            if missing := [r for r in expected if r not in regions]:
                raise ValueError(f"{sensor}.regions: no channel senses {', '.join(missing)}")
        return self


class Rig(_Strict):
    """A rig file's content (see the module's docstring)."""

    name: str = Field(pattern=f"^{NAME_PATTERN.pattern}$")
    description: str = ""
    streams: dict[str, Stream]
    glove: Glove
    robot: Robot

    @field_validator("streams")
    @classmethod
    def _every_stream_once(cls, streams: dict[str, Stream]) -> dict[str, Stream]:
        if missing := [s for s in STREAM_TYPES if s not in streams]:
            raise ValueError(f"missing {', '.join(missing)} (the streams are {', '.join(STREAM_TYPES)})")
        if unknown := [s for s in streams if s not in STREAM_TYPES]:
            raise ValueError(f"unknown stream {unknown[0]!r} (the streams are {', '.join(STREAM_TYPES)})")
        for kind, names in STREAMS_BY_KIND.items():
            topics = [streams[n].topic for n in names]
            if dupes := sorted({t for t in topics if topics.count(t) > 1}):
                raise ValueError(f"topic {dupes[0]} carries two streams of a {kind}")
        return streams

    def topics(self, kind: str) -> tuple[Topic, ...]:
        """The topics a recording of ``kind`` made on this rig must carry, with their array lengths."""
        return tuple(self._topic(stream) for stream in STREAMS_BY_KIND[kind])

    def topic(self, stream: str) -> str:
        return self.streams[stream].topic

    def _topic(self, stream: str) -> Topic:
        spec = self.streams[stream]
        width, names = {
            "taxels": (self.glove.n_taxels, None),
            "hand_joints": (len(self.glove.joint_names), self.glove.joint_names),
            "hand_keypoints": (N_KEYPOINTS, None),
            "robot_joint_states": (len(self.robot.joint_names), self.robot.joint_names),
            "robot_joint_targets": (len(self.robot.joint_names), self.robot.joint_names),
            "twintac": (len(self.robot.twintac.regions), None),
            "fsr": (len(self.robot.fsr.regions), None),
        }.get(stream, (None, None))
        return Topic(spec.topic, STREAM_TYPES[stream], spec.rate_hz, stream, width, names)

    def digest(self) -> str:
        """The first 16 hex digits of the sha256 of the rig's canonical JSON: two files saying the same
        thing have the same digest."""
        return hashlib.sha256(self.model_dump_json().encode()).hexdigest()[:16]


def _regions(names: tuple[str, ...], region_of: tuple[str, ...]) -> dict[str, Region]:
    return {r: Region(taxels=tuple(i for i, x in enumerate(region_of) if x == r)) for r in names}


DEFAULT_RIG = Rig(
    name="simulated",
    description=(
        "The project's simulated rig: the demonstrator's 256-taxel glove "
        f"({FINGERTIP_TAXELS} taxels per fingertip, {PALM_TAXELS} per palm pad, 24 on the phalanges) and the "
        "hardware twin's LEAP Hand with 4 TwinTac fingertips of 4 channels and 4 palm FSRs"
    ),
    streams={
        "taxels": Stream(topic="/glove/taxels", rate_hz=100.0),
        "hand_joints": Stream(topic="/glove/hand_joints", rate_hz=60.0),
        "hand_keypoints": Stream(topic="/glove/keypoints", rate_hz=60.0),
        "wrist_pose": Stream(topic="/glove/wrist_pose", rate_hz=60.0),
        "object_pose": Stream(topic="/object/pose", rate_hz=100.0),
        "robot_joint_states": Stream(topic="/leap/joint_states", rate_hz=50.0),
        "robot_joint_targets": Stream(topic="/leap/joint_targets", rate_hz=20.0),
        "twintac": Stream(topic="/twintac/raw", rate_hz=100.0),
        "fsr": Stream(topic="/fsr/palm", rate_hz=50.0),
        "time_map": Stream(topic="/replay/reference_time", rate_hz=20.0),
    },
    glove=Glove(
        n_taxels=len(TAXEL_REGION),
        fingertip=_regions(FINGERTIP_REGIONS, TAXEL_REGION),
        palm=_regions(PALM_REGIONS, TAXEL_REGION),
    ),
    robot=Robot(
        joint_names=LEAP_JOINT_NAMES,
        twintac=Channels(units="raw counts", regions=tuple(r for r in FINGERTIP_REGIONS[:4] for _ in range(4))),
        fsr=Channels(units="FSR native units (0 = no load)", regions=PALM_REGIONS),
    ),
)
