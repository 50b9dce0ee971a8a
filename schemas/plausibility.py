"""What a recording's values may physically be: ingest quarantines a file with any value outside these
bounds, naming topic, message index and value. The bounds are wide on purpose: they catch sensor faults,
unit mix-ups and corrupted bytes (1e30, FLT_MAX, a zero quaternion, a clock jump), not unusual motions.

Each bound says what it models:
- tactile arrays (glove taxels, TwinTac channels, palm FSRs) are raw counts of at most a 16-bit ADC;
- joint angles stay within one turn: the LEAP Hand's joints span about -1.6..2.3 rad and a glove's finger
  angles less;
- joint velocities below 100 rad/s: the LEAP Hand's Dynamixel XC330 reach about 10 rad/s unloaded;
- joint efforts below 50 N m: an XC330's stall torque is about 0.5 N m;
- positions within 5 m of the world origin: a table-top scene;
- orientations are unit quaternions to within 1e-3 (float32 round trips stay near 1e-7);
- the reference time of a replay lies within its glove session, which lasts at most MAX_RECORDING_S.
"""

from __future__ import annotations

import re
from dataclasses import dataclass


@dataclass(frozen=True)
class Bounds:
    low: float
    high: float
    what: str  # the unit or quantity, for the quarantine reason


TACTILE_COUNTS = Bounds(0.0, 65535.0, "raw ADC counts")
JOINT_ANGLE = Bounds(-6.2832, 6.2832, "rad")
JOINT_VELOCITY = Bounds(-100.0, 100.0, "rad/s")
JOINT_EFFORT = Bounds(-50.0, 50.0, "N m")
POSITION = Bounds(-5.0, 5.0, "m")
REFERENCE_TIME = Bounds(0.0, 3600.0, "s")

# (message type, field) -> bounds; pose fields pack (x, y, z, qw, qx, qy, qz) per pose
FIELD_BOUNDS: dict[tuple[str, str], Bounds] = {
    ("touch2robot_msgs/msg/TactileArray", "values"): TACTILE_COUNTS,
    ("sensor_msgs/msg/JointState", "position"): JOINT_ANGLE,
    ("sensor_msgs/msg/JointState", "velocity"): JOINT_VELOCITY,
    ("sensor_msgs/msg/JointState", "effort"): JOINT_EFFORT,
    ("touch2robot_msgs/msg/ReferenceTime", "reference_time"): REFERENCE_TIME,
}
POSE_FIELDS = {"pose", "poses"}  # position bounded by POSITION; orientation a unit quaternion
QUATERNION_TOLERANCE = 1e-3
# Tracked keypoints carry positions only: a tracker without orientations may send zero quaternions.
POSITION_ONLY_STREAMS = {"hand_keypoints"}

# A demonstration or replay lasts seconds to minutes; an hour-long file means a clock fault.
MAX_RECORDING_S = 3600.0
# The recorder starts every stream of a file together; a stream starting later than this is a clock jump.
MAX_STREAM_START_SPREAD_S = 60.0

# Metadata values become table values and name files: short, printable, no path syntax.
NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
FILE_NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,254}")
SEED_PATTERN = re.compile(r"0|[1-9][0-9]{0,8}")  # a sweep seed (replay metadata)
