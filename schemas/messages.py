"""ROS 2 message definitions and the streams of the three recording kinds (MCAP, CDR).

This is the contract between a rig (real or simulated) and ingestion: a recording is
accepted only if every stream of its kind is present with exactly these message types.
Which topic carries a stream, at what rate, and the glove's and robot's array layouts are
the rig's (schemas/rig.py). Standard types are used where they fit; the two project types
are declared here in ROS 2 ``.msg`` syntax and written into each file's schema records.
"""

from __future__ import annotations

from dataclasses import dataclass

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
    "tf2_msgs/msg/TFMessage": _with_deps(
        "geometry_msgs/TransformStamped[] transforms\n",
        [
            ("geometry_msgs/TransformStamped", "std_msgs/Header header\nstring child_frame_id\nTransform transform\n"),
            ("geometry_msgs/Transform", "Vector3 translation\nQuaternion rotation\n"),
            ("geometry_msgs/Vector3", _POINT),
            ("geometry_msgs/Quaternion", _QUAT),
            *_HEADER_DEPS,
        ],
    ),
    "std_msgs/msg/String": "string data\n",
}

LEAP_JOINT_NAMES: tuple[str, ...] = (
    "if_mcp", "if_rot", "if_pip", "if_dip",
    "mf_mcp", "mf_rot", "mf_pip", "mf_dip",
    "rf_mcp", "rf_rot", "rf_pip", "rf_dip",
    "th_cmc", "th_axl", "th_mcp", "th_ipl",
)  # fmt: skip

N_KEYPOINTS = 21


@dataclass(frozen=True)
class Topic:
    """A topic of one recording as its rig names it: the stream it carries (also the lake table it lands
    in), its type, nominal rate, and the fixed array length(s) its payload must have."""

    name: str
    msg_type: str
    rate_hz: float
    table: str
    array_len: int | None = None  # values / position / poses length the message must have
    joint_names: tuple[str, ...] | None = None


# Every stream of the contract: its message type. A rig file (schemas/rig.py) gives each its topic name
# and rate, and the array lengths of its own glove and robot.
STREAM_TYPES: dict[str, str] = {
    "taxels": "touch2robot_msgs/msg/TactileArray",
    "hand_joints": "sensor_msgs/msg/JointState",
    "hand_keypoints": "geometry_msgs/msg/PoseArray",
    "wrist_pose": "geometry_msgs/msg/PoseStamped",
    "object_pose": "geometry_msgs/msg/PoseStamped",
    "robot_joint_states": "sensor_msgs/msg/JointState",
    "robot_joint_targets": "sensor_msgs/msg/JointState",
    "twintac": "touch2robot_msgs/msg/TactileArray",
    "fsr": "touch2robot_msgs/msg/TactileArray",
    "time_map": "touch2robot_msgs/msg/ReferenceTime",
}

# The streams each kind of recording must carry (each lands in the lake table of its name).
STREAMS_BY_KIND: dict[str, tuple[str, ...]] = {
    "glove_session": ("taxels", "hand_joints", "hand_keypoints", "wrist_pose", "object_pose"),
    "robot_replay": ("robot_joint_states", "robot_joint_targets", "twintac", "fsr", "time_map"),
    "robot_calibration": ("twintac",),
}

# Streams a recorder may add for viewers (Foxglove's 3D panel): the wrist's transform and the robot's URDF.
# Ingest reads neither.
TF_TOPIC = Topic("/tf", "tf2_msgs/msg/TFMessage", 60.0, "tf")
ROBOT_DESCRIPTION_TOPIC = Topic("/robot_description", "std_msgs/msg/String", 0.0, "robot_description")
VIEWER_TOPICS: tuple[Topic, ...] = (TF_TOPIC, ROBOT_DESCRIPTION_TOPIC)

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
