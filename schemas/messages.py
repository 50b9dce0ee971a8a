"""ROS 2 message definitions, topics and rates of the three recording kinds (MCAP, CDR).

This is the contract between a rig (real or simulated) and ingestion: a recording is
accepted only if every required topic is present with exactly these message types.
Standard types are used where they fit; the two project types are declared here in
ROS 2 ``.msg`` syntax and written into each file's schema records.
"""

from __future__ import annotations

from dataclasses import dataclass

from schemas.glove import GLOVE_JOINT_NAMES, N_TAXELS

SCHEMA_VERSION = "1"
METADATA_NAME = "touch2robot"  # MCAP metadata record holding kind/task/subject/...
MESSAGE_ENCODING = "cdr"
SCHEMA_ENCODING = "ros2msg"

_TIME = "int32 sec\nuint32 nanosec\n"
_HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"
_SEP = "=" * 80 + "\n"


def _with_deps(body: str, deps: list[tuple[str, str]]) -> str:
    return body + "".join(f"{_SEP}MSG: {name}\n{text}" for name, text in deps)


_HEADER_DEPS = [("std_msgs/Header", _HEADER), ("builtin_interfaces/Time", _TIME)]
_POINT = "float64 x\nfloat64 y\nfloat64 z\n"
_QUAT = "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"
_POSE = "Point position\nQuaternion orientation\n"
_POSE_DEPS = [("geometry_msgs/Pose", _POSE), ("geometry_msgs/Point", _POINT), ("geometry_msgs/Quaternion", _QUAT)]

MSG_DEFINITIONS: dict[str, str] = {
    # Project type: one frame of a tactile array (glove taxels, TwinTac channels, palm FSRs).
    "touch2robot_msgs/msg/TactileArray": _with_deps("std_msgs/Header header\nfloat32[] values\n", _HEADER_DEPS),
    # Project type: the reference-trajectory time being replayed at header.stamp.
    "touch2robot_msgs/msg/ReferenceTime": _with_deps("std_msgs/Header header\nfloat64 reference_time\n", _HEADER_DEPS),
    "sensor_msgs/msg/JointState": _with_deps(
        "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort\n",
        _HEADER_DEPS,
    ),
    "geometry_msgs/msg/PoseStamped": _with_deps(
        "std_msgs/Header header\ngeometry_msgs/Pose pose\n", _HEADER_DEPS + _POSE_DEPS
    ),
    "geometry_msgs/msg/PoseArray": _with_deps(
        "std_msgs/Header header\ngeometry_msgs/Pose[] poses\n", _HEADER_DEPS + _POSE_DEPS
    ),
}

LEAP_JOINT_NAMES: tuple[str, ...] = (
    "if_mcp", "if_rot", "if_pip", "if_dip",
    "mf_mcp", "mf_rot", "mf_pip", "mf_dip",
    "rf_mcp", "rf_rot", "rf_pip", "rf_dip",
    "th_cmc", "th_axl", "th_mcp", "th_ipl",
)  # fmt: skip

N_TWINTAC_CHANNELS = 16  # 4 fingertip sensors (thumb, index, middle, ring) x 4 channels
TWINTAC_CHANNEL_REGION: tuple[str, ...] = tuple(r for r in ("T1", "T2", "T3", "T4") for _ in range(4))
N_FSR_CHANNELS = 4
FSR_CHANNEL_REGION: tuple[str, ...] = ("P1", "P2", "P3", "P4")
N_KEYPOINTS = 21


@dataclass(frozen=True)
class Topic:
    """A topic of the contract: its type, nominal rate, the table it lands in, and the
    fixed array length(s) its payload must have."""

    name: str
    msg_type: str
    rate_hz: float
    table: str
    array_len: int | None = None  # values / position / poses length the message must have
    joint_names: tuple[str, ...] | None = None


GLOVE_TOPICS: tuple[Topic, ...] = (
    Topic("/glove/taxels", "touch2robot_msgs/msg/TactileArray", 100.0, "taxels", N_TAXELS),
    Topic(
        "/glove/hand_joints",
        "sensor_msgs/msg/JointState",
        60.0,
        "hand_joints",
        len(GLOVE_JOINT_NAMES),
        GLOVE_JOINT_NAMES,
    ),
    Topic("/glove/keypoints", "geometry_msgs/msg/PoseArray", 60.0, "hand_keypoints", N_KEYPOINTS),
    Topic("/glove/wrist_pose", "geometry_msgs/msg/PoseStamped", 60.0, "wrist_pose"),
    Topic("/object/pose", "geometry_msgs/msg/PoseStamped", 100.0, "object_pose"),
)

REPLAY_TOPICS: tuple[Topic, ...] = (
    Topic("/leap/joint_states", "sensor_msgs/msg/JointState", 50.0, "robot_joint_states", 16, LEAP_JOINT_NAMES),
    Topic("/leap/joint_targets", "sensor_msgs/msg/JointState", 20.0, "robot_joint_targets", 16, LEAP_JOINT_NAMES),
    Topic("/twintac/raw", "touch2robot_msgs/msg/TactileArray", 100.0, "twintac", N_TWINTAC_CHANNELS),
    Topic("/fsr/palm", "touch2robot_msgs/msg/TactileArray", 50.0, "fsr", N_FSR_CHANNELS),
    Topic("/replay/reference_time", "touch2robot_msgs/msg/ReferenceTime", 20.0, "time_map"),
)

CALIBRATION_TOPICS: tuple[Topic, ...] = (
    Topic("/twintac/raw", "touch2robot_msgs/msg/TactileArray", 100.0, "twintac", N_TWINTAC_CHANNELS),
)

TOPICS_BY_KIND: dict[str, tuple[Topic, ...]] = {
    "glove_session": GLOVE_TOPICS,
    "robot_replay": REPLAY_TOPICS,
    "robot_calibration": CALIBRATION_TOPICS,
}

# Metadata keys every recording carries (values are strings, "" when not applicable).
METADATA_KEYS: dict[str, tuple[str, ...]] = {
    "glove_session": ("kind", "schema_version", "task", "subject"),
    "robot_replay": (
        "kind",
        "schema_version",
        "task",
        "subject",
        "method",
        "reference_recording",
        "calibration_recording",
    ),
    "robot_calibration": ("kind", "schema_version"),
}
# Metadata keys a recording may carry. A replay's ``trajectory`` names the robot trajectory it executed (a
# ``rollouts`` rollout_id) and ``seed`` the sweep seed of the rollouts it is one of (default: none, read as 0):
# tactile fidelity scores that trajectory's contacts against the ones measured here.
OPTIONAL_METADATA_KEYS: dict[str, tuple[str, ...]] = {
    "glove_session": (),
    "robot_replay": ("trajectory", "seed"),
    "robot_calibration": (),
}
# Every field a session may give, whatever its source (the MCAP record, rosbag2 custom_data, a sidecar, the
# command line): the keys above, the rig that recorded it (a calibration also names its sensor) and the
# demonstration's number within its subject's.
SESSION_KEYS: tuple[str, ...] = tuple(
    dict.fromkeys(
        [
            *(k for keys in METADATA_KEYS.values() for k in keys),
            *(k for keys in OPTIONAL_METADATA_KEYS.values() for k in keys),
            "rig",
            "sensor",
            "demo",
        ]
    )
)
