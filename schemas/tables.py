"""Arrow schemas of every table in the lake: the data contract between stages.

Each table lives under ``<data>/lake/<name>/`` as hive-partitioned Parquet
(partition columns are listed in ``PARTITIONS``) and is exposed as a DuckDB
view of the same name by ``touch2robot.catalog``. ``DOCS`` describes every table and
column next to its schema; the catalog writes it into DuckDB as view and column comments.
"""

from __future__ import annotations

from dataclasses import dataclass

import pyarrow as pa

# The shared semantic contact space (paper convention): robot fingertips <-> human
# T1..T4 (thumb, index, middle, ring), robot palm pads <-> P1..P4. The human T5
# (little finger) has no robot counterpart and never enters a comparison.
ROBOT_REGIONS: tuple[str, ...] = ("T1", "T2", "T3", "T4", "P1", "P2", "P3", "P4")
HUMAN_REGIONS: tuple[str, ...] = ("T1", "T2", "T3", "T4", "T5", "P1", "P2", "P3", "P4")
FINGERTIP_REGIONS: tuple[str, ...] = ("T1", "T2", "T3", "T4", "T5")
PALM_REGIONS: tuple[str, ...] = ("P1", "P2", "P3", "P4")

# Contact sources appended to the `contacts` table by the stages.


@dataclass(frozen=True)
class TableDoc:
    """What a table holds (one line) and what each of its columns means (unit, allowed values)."""

    summary: str
    columns: dict[str, str]


_RECORDING_ID = "the recording (recordings.recording_id)"
_T = "time (s) since the recording's first message"


def _stream(column: str, width: int | None) -> pa.Schema:
    """A sensor stream of one recording: its id, the time in seconds since the recording's
    first message, and a float32 array per sample (fixed-width, or as wide as the rig's array)."""
    return pa.schema(
        [
            pa.field("recording_id", pa.string(), nullable=False),
            pa.field("t", pa.float64(), nullable=False),
            pa.field(column, pa.list_(pa.float32(), width if width is not None else -1), nullable=False),
        ]
    )


def _stream_doc(summary: str, column: str, description: str) -> TableDoc:
    return TableDoc(summary, {"recording_id": _RECORDING_ID, "t": _T, column: description})


recordings = pa.schema(
    [
        pa.field("recording_id", pa.string(), nullable=False),
        pa.field("path", pa.string(), nullable=False),
        pa.field("file_name", pa.string(), nullable=False),
        pa.field("size_bytes", pa.int64(), nullable=False),
        pa.field("kind", pa.string()),
        pa.field("task", pa.string()),
        pa.field("subject", pa.string()),
        pa.field("method", pa.string()),
        pa.field("seed", pa.int64()),
        pa.field("reference_recording", pa.string()),
        pa.field("calibration_recording", pa.string()),
        pa.field("trajectory", pa.string()),
        pa.field("rig", pa.string()),
        pa.field("rig_definition", pa.string()),
        pa.field("start_time_s", pa.float64()),
        pa.field("end_time_s", pa.float64()),
        pa.field("duration_s", pa.float64()),
        pa.field("message_counts", pa.string()),
        pa.field("status", pa.string(), nullable=False),
        pa.field("reason", pa.string()),
        pa.field("ingested_at", pa.timestamp("us", tz="UTC")),
    ]
)
recordings_doc = TableDoc(
    "every MCAP file ingest has seen, ingested or quarantined",
    {
        "recording_id": "sha256 of the file content (first 16 hex digits)",
        "path": "the file's path when ingested",
        "file_name": "the file's name",
        "size_bytes": "file size (bytes)",
        "kind": "glove_session | robot_replay | robot_calibration",
        "task": "pick | rotate | wipe | drawer (metadata; empty where not applicable, NULL if unreadable)",
        "subject": "the demonstrating person",
        "method": "replay: the retargeting method whose commands the robot replayed",
        "seed": "replay: the sweep seed of the trajectory it executed (NULL: none named)",
        "reference_recording": "replay: file name of the glove session it replays",
        "calibration_recording": "replay: file name of its TwinTac calibration",
        "trajectory": "replay: the robot trajectory executed (a rollouts rollout_id); NULL when the rig does not say",
        "rig": "the rig it was read with (its session field rig; simulated when it names none); NULL if quarantined",
        "rig_definition": "JSON: that rig file's content (schemas/rig.py): topics, taxel regions, joints, channels",
        "start_time_s": "first message's timestamp (s)",
        "end_time_s": "last message's timestamp (s)",
        "duration_s": "end_time_s - start_time_s",
        "message_counts": "JSON {topic: number of messages}",
        "status": "ingested | quarantined",
        "reason": "why the file was quarantined (empty when ingested)",
        "ingested_at": "when ingest wrote this row (UTC)",
    },
)

# --- Streams of glove sessions -------------------------------------------------
taxels = _stream("values", None)
taxels_doc = _stream_doc(
    "glove tactile frames (100 Hz on the simulated rig)",
    "values",
    "one reading per taxel, as many as the rig's glove.n_taxels (256 on the simulated rig), in the rig's order",
)

hand_joints = _stream("position", 20)
hand_joints_doc = _stream_doc(
    "glove hand joint angles (60 Hz)",
    "position",
    "20 joint angles (rad, flexion positive), schemas.glove.GLOVE_JOINT_NAMES order",
)

hand_keypoints = _stream("xyz", 63)
hand_keypoints_doc = _stream_doc(
    "glove hand keypoints in the world frame (60 Hz)",
    "xyz",
    "21 keypoints x (x, y, z) in m, row-major: wrist, then 4 per finger thumb..little (base to tip)",
)

POSE_FIELDS = [
    pa.field("recording_id", pa.string(), nullable=False),
    pa.field("t", pa.float64(), nullable=False),
    pa.field("px", pa.float64()),
    pa.field("py", pa.float64()),
    pa.field("pz", pa.float64()),
    pa.field("qw", pa.float64()),
    pa.field("qx", pa.float64()),
    pa.field("qy", pa.float64()),
    pa.field("qz", pa.float64()),
]


def _pose_doc(summary: str, body: str) -> TableDoc:
    position = {f"p{axis}": f"{body} position {axis} in the world frame (m)" for axis in "xyz"}
    orientation = {f"q{part}": f"{body} orientation quaternion, {part} component" for part in "wxyz"}
    return TableDoc(summary, {"recording_id": _RECORDING_ID, "t": _T, **position, **orientation})


wrist_pose = pa.schema(POSE_FIELDS)
wrist_pose_doc = _pose_doc("glove wrist pose in the world frame (60 Hz)", "wrist")
object_pose = pa.schema(POSE_FIELDS)
object_pose_doc = _pose_doc("tracked object pose in the world frame (100 Hz)", "object")

# --- Streams of robot replays and calibrations --------------------------------
robot_joint_states = pa.schema(
    [
        pa.field("recording_id", pa.string(), nullable=False),
        pa.field("t", pa.float64(), nullable=False),
        pa.field("position", pa.list_(pa.float32(), 16), nullable=False),
        pa.field("velocity", pa.list_(pa.float32(), 16), nullable=False),
        pa.field("effort", pa.list_(pa.float32(), 16), nullable=False),
    ]
)
robot_joint_states_doc = TableDoc(
    "LEAP Hand measured joint states of robot replays (50 Hz)",
    {
        "recording_id": _RECORDING_ID,
        "t": _T,
        "position": "16 joint positions (rad), LEAP_JOINT_NAMES order",
        "velocity": "16 joint velocities (rad/s); NaN when the driver reports none",
        "effort": "16 joint efforts (driver units); NaN when the driver reports none",
    },
)

robot_joint_targets = _stream("position", 16)
robot_joint_targets_doc = _stream_doc(
    "LEAP Hand joint commands of robot replays (20 Hz)",
    "position",
    "16 commanded joint positions (rad), LEAP_JOINT_NAMES order",
)

twintac = _stream("values", None)
twintac_doc = _stream_doc(
    "TwinTac fingertip sensor frames of replays and calibrations (100 Hz on the simulated rig)",
    "values",
    "raw channels in the rig's robot.twintac order (simulated rig: 16, 4 per fingertip T1..T4)",
)

fsr = _stream("values", None)
fsr_doc = _stream_doc(
    "palm force-sensing resistors of robot replays (50 Hz on the simulated rig)",
    "values",
    "raw readings in the rig's robot.fsr order (simulated rig: 4 in FSR native units, P1..P4)",
)

time_map = pa.schema(
    [
        pa.field("recording_id", pa.string(), nullable=False),
        pa.field("t", pa.float64(), nullable=False),
        pa.field("t_ref", pa.float64(), nullable=False),
    ]
)
time_map_doc = TableDoc(
    "the reference-trajectory time a robot replay was playing at each moment (20 Hz)",
    {
        "recording_id": "the replay recording",
        "t": "replay time (s since the replay's first message)",
        "t_ref": "reference-trajectory time (s since the reference recording's first message)",
    },
)

# --- Derived tables ------------------------------------------------------------
contacts = pa.schema(
    [
        pa.field("source", pa.string(), nullable=False),
        pa.field("method", pa.string(), nullable=False),
        pa.field("seed", pa.int64()),
        pa.field("task", pa.string(), nullable=False),
        pa.field("subject", pa.string(), nullable=False),
        pa.field("sequence_id", pa.string(), nullable=False),
        pa.field("reference_id", pa.string(), nullable=False),
        pa.field("t", pa.float64(), nullable=False),
        pa.field("t_ref", pa.float64(), nullable=False),
        pa.field("region", pa.string(), nullable=False),
        pa.field("contact", pa.bool_(), nullable=False),
        pa.field("value", pa.float32()),
    ]
)
contacts_doc = TableDoc(
    "binary contact per time and robot region, of every source (human, sim, real, reconstructed)",
    {
        "source": "human | sim | real | reconstructed",
        "method": '"human" for the glove; else the retargeting method',
        "seed": "the sweep seed that produced the row (profile seeds); NULL for the glove (human)",
        "task": "pick | rotate | wipe | drawer",
        "subject": "the demonstrating person",
        "sequence_id": "recording id or rollout id",
        "reference_id": "glove recording whose contact preference is the reference",
        "t": "time (s) on the sequence's own clock",
        "t_ref": "time (s) on the reference trajectory's clock",
        "region": "T1..T4 fingertips (thumb, index, middle, ring), P1..P4 palm pads (ROBOT_REGIONS)",
        "contact": "whether the region is in contact",
        "value": "regional response or force behind the decision (NaN if none)",
    },
)

thresholds = pa.schema(
    [
        pa.field("recording_id", pa.string(), nullable=False),
        pa.field("sensor", pa.string(), nullable=False),
        pa.field("applies_to", pa.string(), nullable=False),
        pa.field("threshold", pa.float64(), nullable=False),
        pa.field("baseline", pa.float64()),
        pa.field("noise", pa.float64()),
        pa.field("method", pa.string(), nullable=False),
    ]
)
thresholds_doc = TableDoc(
    "contact thresholds derived per recording and sensor",
    {
        "recording_id": "the recording they were derived for",
        "sensor": "glove | twintac | fsr",
        "applies_to": "fingertip | palm (glove) or channel_<i> (twintac, fsr)",
        "threshold": "contact when the response exceeds it (sensor units)",
        "baseline": "no-contact level (sensor units)",
        "noise": "noise level the threshold is a multiple of (sensor units)",
        "method": "how the threshold was derived",
    },
)

# --- Evaluation tables (flow `evaluate`; rebuilt whole on every run) ----------------
# A key column holding '*' (touch2robot.metrics.ALL) is rolled up over that dimension;
# undefined ratios (0/0) are NULL.
contact_metrics = pa.schema(
    [
        pa.field("source", pa.string(), nullable=False),
        pa.field("method", pa.string(), nullable=False),
        pa.field("seed", pa.int64(), nullable=False),
        pa.field("task", pa.string(), nullable=False),
        pa.field("region", pa.string(), nullable=False),
        pa.field("reference_source", pa.string(), nullable=False),
        pa.field("n_sequences", pa.int64(), nullable=False),
        pa.field("tp", pa.int64(), nullable=False),
        pa.field("fp", pa.int64(), nullable=False),
        pa.field("fn", pa.int64(), nullable=False),
        pa.field("tn", pa.int64(), nullable=False),
        pa.field("n", pa.int64(), nullable=False),
        pa.field("precision", pa.float64()),
        pa.field("recall", pa.float64()),
        pa.field("f1", pa.float64()),
        pa.field("fpr", pa.float64()),
    ]
)
contact_metrics_doc = TableDoc(
    "contact agreement with the human preference per source, method, task and region ('*' = all)",
    {
        "source": "the evaluated source (sim | real | reconstructed)",
        "method": "the retargeting method",
        "seed": "the sweep seed of the evaluated trajectories",
        "task": "the task, or '*' for all",
        "region": "one of ROBOT_REGIONS, or '*' for all",
        "reference_source": 'what it is scored against ("human")',
        "n_sequences": "evaluated sequences",
        "tp": "true positives over all compared time-region pairs",
        "fp": "false positives",
        "fn": "false negatives",
        "tn": "true negatives",
        "n": "tp + fp + fn + tn",
        "precision": "tp / (tp + fp); NULL when undefined",
        "recall": "tp / (tp + fn); NULL when undefined",
        "f1": "2 tp / (2 tp + fp + fn); NULL when undefined",
        "fpr": "fp / (fp + tn); NULL when undefined",
    },
)

onset_errors = pa.schema(
    [
        pa.field("source", pa.string(), nullable=False),
        pa.field("method", pa.string(), nullable=False),
        pa.field("seed", pa.int64(), nullable=False),
        pa.field("task", pa.string(), nullable=False),
        pa.field("sequence_id", pa.string(), nullable=False),
        pa.field("region", pa.string(), nullable=False),
        pa.field("subject", pa.string(), nullable=False),
        pa.field("reference_id", pa.string(), nullable=False),
        pa.field("reference_source", pa.string(), nullable=False),
        pa.field("t_ref_onset", pa.float64()),
        pa.field("t_eval_onset", pa.float64()),
        pa.field("error_ms", pa.float64()),
        pa.field("valid", pa.bool_()),
        pa.field("via_time_map", pa.bool_()),
        pa.field("n_pairs", pa.int64(), nullable=False),
        pa.field("n", pa.int64(), nullable=False),
        pa.field("n_missing_reference", pa.int64(), nullable=False),
        pa.field("n_missing_evaluated", pa.int64(), nullable=False),
        pa.field("n_missing_both", pa.int64(), nullable=False),
    ]
)
onset_errors_doc = TableDoc(
    "contact onset time errors against the human reference: pair rows and summary rows ('*')",
    {
        "source": "the evaluated source (sim | real | reconstructed)",
        "method": "the retargeting method",
        "seed": "the sweep seed of the evaluated trajectories",
        "task": "the task, or '*' for all",
        "sequence_id": "the evaluated sequence; '*' on summary rows",
        "region": "one of ROBOT_REGIONS, or '*' for all",
        "subject": "the demonstrating person; '*' on summary rows",
        "reference_id": "the glove recording scored against; '*' on summary rows",
        "reference_source": 'what it is scored against ("human")',
        "t_ref_onset": "pair rows: reference onset (s, reference clock); NULL if none",
        "t_eval_onset": "pair rows: evaluated onset on the reference clock (s); NULL if none",
        "error_ms": "pair rows: |t_eval_onset - t_ref_onset| (ms); summary rows: E over its valid pairs",
        "valid": "pair rows: an onset on both sides; NULL on summary rows",
        "via_time_map": "pair rows: evaluated times mapped by the recorded time map",
        "n_pairs": "trajectory-region pairs summarised (1 on a pair row)",
        "n": "N: valid pairs",
        "n_missing_reference": "pairs with no reference onset",
        "n_missing_evaluated": "pairs with no evaluated onset",
        "n_missing_both": "pairs with an onset on neither side",
    },
)

# --- The method comparison (flow `evaluate`; rewritten whole, one file per reference source x source) --
# Every method's scores with cluster-bootstrap intervals over demonstrations, and each method's paired
# comparison with the compared-with method (touch2robot.comparison documents every choice).
# Files: lake/comparison/<reference_source>__<source>.parquet
comparison = pa.schema(
    [
        pa.field("reference_source", pa.string(), nullable=False),
        pa.field("source", pa.string(), nullable=False),
        pa.field("metric", pa.string(), nullable=False),
        pa.field("task", pa.string(), nullable=False),
        pa.field("method", pa.string(), nullable=False),
        pa.field("variant", pa.string(), nullable=False),
        pa.field("estimate", pa.float64()),
        pa.field("ci_low", pa.float64()),
        pa.field("ci_high", pa.float64()),
        pa.field("n_demonstrations", pa.int64(), nullable=False),
        pa.field("seeds", pa.string(), nullable=False),
        pa.field("seeds_missing", pa.string(), nullable=False),
        pa.field("versus", pa.string()),
        pa.field("difference", pa.float64()),
        pa.field("difference_ci_low", pa.float64()),
        pa.field("difference_ci_high", pa.float64()),
        pa.field("n_paired", pa.int64(), nullable=False),
        pa.field("wilcoxon_statistic", pa.float64()),
        pa.field("p_value", pa.float64()),
        pa.field("p_holm", pa.float64()),
        pa.field("confidence", pa.float64(), nullable=False),
        pa.field("n_resamples", pa.int64(), nullable=False),
    ]
)
comparison_doc = TableDoc(
    "the method comparison: scores with intervals over demonstrations and paired tests against one method",
    {
        "reference_source": "what it is scored against: human (preference alignment) | real (tactile fidelity)",
        "source": "the evaluated source (sim | real | reconstructed); tactile fidelity: sim, whatever made it",
        "metric": "precision | recall | f1 | fpr | onset_error_ms",
        "task": "the task, or '*' for all (demonstrations of every task pooled)",
        "method": "the retargeting method",
        "variant": "a student ablation of the method ('' = the method itself, compared with the others)",
        "estimate": "the score over all its demonstrations (counts pooled); NULL when undefined",
        "ci_low": "lower bound of the percentile interval of a cluster bootstrap over demonstrations",
        "ci_high": "upper bound of that interval",
        "n_demonstrations": "demonstrations scored",
        "seeds": "the sweep seeds pooled into the row (comma-separated)",
        "seeds_missing": "the profile's seeds with no results for the row ('' when none is missing)",
        "versus": "the method it is compared with (an ablation: the full model); NULL on that method's own rows",
        "difference": "score(versus) - score(method) on the demonstrations both were scored on",
        "difference_ci_low": "lower bound of the paired cluster-bootstrap interval of the difference",
        "difference_ci_high": "upper bound of that interval",
        "n_paired": "demonstrations where both per-demonstration scores are defined (the test's n)",
        "wilcoxon_statistic": "two-sided Wilcoxon signed-rank statistic over those demonstrations",
        "p_value": "its p-value",
        "p_holm": "Holm-adjusted over the methods compared on this reference source, source, task and metric",
        "confidence": "the intervals' coverage",
        "n_resamples": "bootstrap resamples per interval",
    },
)

user_study = pa.schema(
    [
        pa.field("ratings_file", pa.string(), nullable=False),
        pa.field("ratings_sha256", pa.string(), nullable=False),
        pa.field("question", pa.string(), nullable=False),
        pa.field("n", pa.int64(), nullable=False),
        pa.field("n_zero", pa.int64(), nullable=False),
        pa.field("median_visual_feedback", pa.float64()),
        pa.field("iqr_visual_feedback", pa.float64()),
        pa.field("median_touch2robot", pa.float64()),
        pa.field("iqr_touch2robot", pa.float64()),
        pa.field("statistic", pa.float64()),
        pa.field("p", pa.float64()),
        pa.field("p_holm", pa.float64()),
        pa.field("zero_method", pa.string(), nullable=False),
        pa.field("method", pa.string(), nullable=False),
        pa.field("correction", pa.bool_(), nullable=False),
        pa.field("synthetic", pa.bool_(), nullable=False),
    ]
)
user_study_doc = TableDoc(
    "user-study ratings, visual feedback vs touch2robot: a paired Wilcoxon test per question",
    {
        "ratings_file": "the ratings CSV",
        "ratings_sha256": "sha256 of the ratings CSV",
        "question": "the questionnaire item",
        "n": "paired participants",
        "n_zero": 'zero differences (dropped by zero_method "wilcox")',
        "median_visual_feedback": "median rating with visual feedback",
        "iqr_visual_feedback": "interquartile range of the ratings with visual feedback",
        "median_touch2robot": "median rating with touch2robot",
        "iqr_touch2robot": "interquartile range of the ratings with touch2robot",
        "statistic": "two-sided Wilcoxon signed-rank statistic min(R+, R-)",
        "p": "p-value",
        "p_holm": "Holm-adjusted p-value across the questions",
        "zero_method": "scipy.stats.wilcoxon zero_method used",
        "method": "scipy.stats.wilcoxon method used",
        "correction": "scipy.stats.wilcoxon continuity correction used",
        "synthetic": "SYNTHETIC example ratings, not participants",
    },
)

# --- Kinematic retargeting (flow `retarget`; one file per glove recording) -----------
retargeted = pa.schema(
    [
        pa.field("recording_id", pa.string(), nullable=False),
        pa.field("t", pa.float64(), nullable=False),
        pa.field("position", pa.list_(pa.float32(), 16), nullable=False),
        pa.field("status", pa.string(), nullable=False),
        pa.field("residual", pa.list_(pa.float32(), 4), nullable=False),
        # robot wrist pose in the world: the LEAP URDF's `base` / MJCF `wrist` body (the mocap target)
        pa.field("px", pa.float64()),
        pa.field("py", pa.float64()),
        pa.field("pz", pa.float64()),
        pa.field("qw", pa.float64()),
        pa.field("qx", pa.float64()),
        pa.field("qy", pa.float64()),
        pa.field("qz", pa.float64()),
    ]
)
retargeted_doc = TableDoc(
    "kinematic retargeting of glove recordings to LEAP Hand joints, per hand-motion frame",
    {
        "recording_id": "the glove recording",
        "t": "the hand-motion frame's time (s since the recording's first message)",
        "position": "16 LEAP joints (rad), LEAP_JOINT_NAMES order",
        "status": "ok | solver_error | non_finite | residual | invalid_input (not ok: previous solution held)",
        "residual": "fingertip to scaled human target distance (m): thumb, index, middle, ring",
        **{f"p{axis}": f"robot wrist position {axis} in the world frame (m)" for axis in "xyz"},
        **{f"q{part}": f"robot wrist orientation quaternion, {part} component" for part in "wxyz"},
    },
)

# --- Robot trajectories in simulation (flow `teachers`; one file per method x task) ---------
# One row per control step (20 Hz) of a rollout: the state observed at ``t`` and the command
# applied from it (LeRobot's frame convention: observation and action of the same frame).
# ``origin`` says what produced the commands: "teacher" (a trained PPO teacher, deterministic
# actions: touch2robot, contrack, dexmachina), "kinematic" (dex-retargeting: the kinematic
# trajectory replayed with no residual) or "student" (touch2robot's distilled student, on every
# demonstration of the task: the held-out ones are those in `student_predictions`, the others
# were trained on, as every teacher trained on all of them). Row 0 of a rollout is its reset
# state, so replaying the commands from it in the same scene reproduces the rollout: reset with
# hand qpos = joint_position, servo targets = joint_position, wrist body and mocap = wrist_state,
# object = object_pose (drawer: drawer_opening)
# (touch2robot.teachers.rollouts.reset_to_rows). Files: lake/rollouts/method=<m>/<origin>-<task>-seed<seed>.parquet

rollouts = pa.schema(
    [
        pa.field("rollout_id", pa.string(), nullable=False),
        pa.field("origin", pa.string(), nullable=False),
        pa.field("method", pa.string(), nullable=False),
        pa.field("seed", pa.int64(), nullable=False),
        pa.field("task", pa.string(), nullable=False),
        pa.field("subject", pa.string(), nullable=False),
        pa.field("reference_id", pa.string(), nullable=False),
        pa.field("step", pa.int32(), nullable=False),
        pa.field("t", pa.float64(), nullable=False),
        pa.field("t_ref", pa.float64(), nullable=False),
        pa.field("joint_position", pa.list_(pa.float64(), 16), nullable=False),
        pa.field("joint_velocity", pa.list_(pa.float64(), 16), nullable=False),
        pa.field("joint_target", pa.list_(pa.float64(), 16), nullable=False),
        pa.field("reference_joints", pa.list_(pa.float32(), 16), nullable=False),
        pa.field("wrist_state", pa.list_(pa.float64(), 7), nullable=False),
        pa.field("wrist_pose", pa.list_(pa.float64(), 7), nullable=False),
        pa.field("object_pose", pa.list_(pa.float64(), 7), nullable=False),
        pa.field("drawer_opening", pa.float64(), nullable=False),
        pa.field("region_force", pa.list_(pa.float32(), 8), nullable=False),
        pa.field("progress", pa.float32(), nullable=False),
        pa.field("success", pa.bool_(), nullable=False),
    ]
)
rollouts_doc = TableDoc(
    "simulated robot rollouts (teacher, kinematic, student), one row per 20 Hz control step",
    {
        "rollout_id": '"<origin>-<method>-<task>-<index:03d>"',
        "origin": "teacher | kinematic | student (schemas.vocabulary.Origin)",
        "method": "touch2robot | contrack | dexmachina | dex-retargeting",
        "seed": "the sweep seed of the run that recorded them (profile seeds)",
        "task": "pick | rotate | wipe | drawer",
        "subject": "the demonstrating person",
        "reference_id": "the glove recording followed",
        "step": "control step since reset",
        "t": "time (s) since the rollout's reset",
        "t_ref": "time (s) on the reference recording's clock",
        "joint_position": "16 LEAP joints (rad) observed, LEAP_JOINT_NAMES order",
        "joint_velocity": "16 LEAP joint velocities (rad/s) observed",
        "joint_target": "16 LEAP joint commands (rad) applied from this state",
        "reference_joints": "kinematic retargeting at t_ref (rad)",
        "wrist_state": "observed wrist body pose: px py pz (m) qw qx qy qz",
        "wrist_pose": "commanded wrist (mocap) pose from this state: px py pz (m) qw qx qy qz",
        "object_pose": "object body pose in the world: px py pz (m) qw qx qy qz",
        "drawer_opening": "drawer slide travel (m); 0 for free objects",
        "region_force": "contact force (N) on T1..T4, P1..P4",
        "progress": "task progress in [0, 1]",
        "success": "the task's success criterion met so far",
    },
)

# --- Diffusion Policy evaluation (flow `policy`; one file per method x task) ----------------
# Closed-loop success of LeRobot's Diffusion Policy trained on one method's robot demonstrations
# of one task (the paper's downstream test). Files: lake/policy_eval/<method>-<task>-seed<seed>.parquet
policy_eval = pa.schema(
    [
        pa.field("task", pa.string(), nullable=False),
        pa.field("method", pa.string(), nullable=False),
        pa.field("seed", pa.int64(), nullable=False),
        pa.field("origin", pa.string(), nullable=False),
        pa.field("observation", pa.string(), nullable=False),
        pa.field("profile", pa.string(), nullable=False),
        pa.field("dataset_episodes", pa.int32(), nullable=False),
        pa.field("dataset_frames", pa.int32(), nullable=False),
        pa.field("train_steps", pa.int32(), nullable=False),
        pa.field("final_loss", pa.float32(), nullable=False),
        pa.field("episodes", pa.int32(), nullable=False),
        pa.field("successes", pa.int32(), nullable=False),
        pa.field("success_rate", pa.float32(), nullable=False),
        pa.field("ci_low", pa.float32(), nullable=False),
        pa.field("ci_high", pa.float32(), nullable=False),
        pa.field("mean_progress", pa.float32(), nullable=False),
        pa.field("replay_successes", pa.int32(), nullable=False),
        pa.field("replay_success_rate", pa.float32(), nullable=False),
        pa.field("fit_joint_err_rad", pa.float32(), nullable=False),
        pa.field("fit_wrist_err_mm", pa.float32(), nullable=False),
        pa.field("hold_joint_err_rad", pa.float32(), nullable=False),
        pa.field("hold_wrist_err_mm", pa.float32(), nullable=False),
        pa.field("episode_steps", pa.int32(), nullable=False),
        pa.field("replans", pa.int32(), nullable=False),
        pa.field("mlflow_run", pa.string(), nullable=False),
    ]
)
# fit_* and hold_*: open-loop fit on the policy's own dataset (touch2robot.policy.evaluate.ActionFit)
policy_eval_doc = TableDoc(
    "closed-loop success of a Diffusion Policy trained on one method's demonstrations of one task",
    {
        "task": "pick | rotate | wipe | drawer",
        "method": "whose rollouts the demonstrations are",
        "seed": "the sweep seed of the rollouts, training and evaluation episodes",
        "origin": "which rollouts: student | teacher | kinematic",
        "observation": "what the policy sees: images (camera views, state and forces) | state (state, forces, object)",
        "profile": "the run profile (smoke | local | paper | a file)",
        "dataset_episodes": "demonstrations trained on",
        "dataset_frames": "frames trained on",
        "train_steps": "optimizer updates",
        "final_loss": "mean diffusion loss over the last logging window",
        "episodes": "seeded closed-loop episodes",
        "successes": "successful episodes",
        "success_rate": "successes / episodes",
        "ci_low": "95 % Wilson interval of the success rate, lower bound",
        "ci_high": "95 % Wilson interval of the success rate, upper bound",
        "mean_progress": "task progress in [0, 1] at episode end, mean over episodes",
        "replay_successes": "the ceiling: successes of each episode's demonstration commands replayed open loop",
        "replay_success_rate": "replay_successes / episodes",
        "fit_joint_err_rad": "open-loop fit: mean |executed - recorded joint action| (rad) over sampled frames",
        "fit_wrist_err_mm": "open-loop fit: mean |executed - recorded wrist action| (mm) over sampled frames",
        "hold_joint_err_rad": "baseline: the same joint error for holding the frame's state (rad)",
        "hold_wrist_err_mm": "baseline: the same wrist error for holding the frame's state (mm)",
        "episode_steps": "control steps per episode (20 Hz)",
        "replans": "policy inferences per episode",
        "mlflow_run": 'MLflow run of stage "policy" with curves, videos and the policy',
    },
)

# --- Student retargeter (flow `student`) ------------------------------------------------
# Training data of the distilled student: paired human-robot steps from teacher rollouts, one
# row per (rollout, step j). Step j pairs the human demonstration at reference frame j with the
# teacher's command aimed at that frame and the sim contacts it led to. Training rollouts are
# the teacher's rollouts once unchanged, then copies with N(0, std^2) added per frame and joint
# to kinematic_joints and target_joints alike (touch2robot.student.augment).
# Files: lake/student_dataset/<task>-seed<seed>.parquet
student_dataset = pa.schema(
    [
        pa.field("sample_id", pa.string(), nullable=False),
        pa.field("split", pa.string(), nullable=False),
        pa.field("task", pa.string(), nullable=False),
        pa.field("seed", pa.int64(), nullable=False),
        pa.field("reference_id", pa.string(), nullable=False),
        pa.field("source_rollout_id", pa.string(), nullable=False),
        pa.field("augment", pa.int32(), nullable=False),
        pa.field("step", pa.int32(), nullable=False),
        pa.field("t_ref", pa.float64(), nullable=False),
        pa.field("kinematic_joints", pa.list_(pa.float32(), 16), nullable=False),
        pa.field("wrist_pose", pa.list_(pa.float64(), 7), nullable=False),
        pa.field("object_pose", pa.list_(pa.float64(), 7), nullable=False),
        pa.field("preference", pa.list_(pa.bool_(), 8), nullable=False),
        pa.field("target_joints", pa.list_(pa.float64(), 16), nullable=False),
        pa.field("target_wrist", pa.list_(pa.float64(), 7), nullable=False),
        pa.field("contact", pa.list_(pa.bool_(), 8), nullable=False),
    ]
)
student_dataset_doc = TableDoc(
    "the student retargeter's training data: paired human-robot steps from teacher rollouts",
    {
        "sample_id": '"<split>-<task>-<index:03d>": one student sequence',
        "split": "train | val (validation demonstrations, never trained on)",
        "task": "pick | rotate | wipe | drawer",
        "seed": "the sweep seed of the teacher rollouts it augments",
        "reference_id": "the glove recording",
        "source_rollout_id": "the teacher rollout it comes from",
        "augment": "0 = the teacher rollout unchanged, k > 0 = its k-th noisy copy",
        "step": "j: the reference frame the command aims at",
        "t_ref": "time (s) on the glove recording's clock",
        "kinematic_joints": "input: raw kinematic retargeting (rad, + noise)",
        "wrist_pose": "input: kinematic robot wrist pose px py pz (m) qw qx qy qz",
        "object_pose": "input: demonstrated object pose px py pz (m) qw qx qy qz",
        "preference": "input: human tactile preference per ROBOT_REGIONS",
        "target_joints": "target: teacher joint command (rad, + the same noise)",
        "target_wrist": "target: teacher wrist command px py pz (m) qw qx qy qz",
        "contact": "target: sim contact per ROBOT_REGIONS (region force > threshold) after the command",
    },
)

# The student's predicted contacts beside the reconstructed (executed) ones in `contacts`
# (source reconstructed): one row per (student rollout, step, region); sequence_id, t and t_ref
# join them. Predictions cover the whole demonstration, also past an early end of the rollout.
# Files: lake/student_predictions/<method>-<task>-seed<seed>.parquet
student_predictions = pa.schema(
    [
        pa.field("sequence_id", pa.string(), nullable=False),
        pa.field("method", pa.string(), nullable=False),
        pa.field("seed", pa.int64(), nullable=False),
        pa.field("task", pa.string(), nullable=False),
        pa.field("reference_id", pa.string(), nullable=False),
        pa.field("variant", pa.string(), nullable=False),
        pa.field("t", pa.float64(), nullable=False),
        pa.field("t_ref", pa.float64(), nullable=False),
        pa.field("region", pa.string(), nullable=False),
        pa.field("logit", pa.float32(), nullable=False),
        pa.field("contact", pa.bool_(), nullable=False),
    ]
)
student_predictions_doc = TableDoc(
    "the student's predicted contacts on held-out demonstrations, per step and robot region",
    {
        "sequence_id": 'the student rollout ("student-<method>-<task>-<index:03d>")',
        "method": "the retargeting method",
        "seed": "the sweep seed of the student",
        "task": "pick | rotate | wipe | drawer",
        "reference_id": "the held-out glove recording",
        "variant": 'student variant ("full" or an ablation)',
        "t": "time (s) since the rollout's reset (step j: j / 20 Hz)",
        "t_ref": "time (s) on the reference recording's clock",
        "region": "one of ROBOT_REGIONS",
        "logit": "predicted contact logit",
        "contact": "logit > 0",
    },
)

# Every student variant's scores per held-out demonstration (flow `student`; one file per method x variant):
# the comparison's clusters for the ablations, which are not in `contacts` (the full model's are).
# Files: lake/student_variants/<method>__<variant>__<seed>.parquet
student_variants = pa.schema(
    [
        pa.field("method", pa.string(), nullable=False),
        pa.field("seed", pa.int64(), nullable=False),
        pa.field("variant", pa.string(), nullable=False),
        pa.field("task", pa.string(), nullable=False),
        pa.field("demonstration", pa.string(), nullable=False),
        pa.field("tp", pa.int64(), nullable=False),
        pa.field("fp", pa.int64(), nullable=False),
        pa.field("fn", pa.int64(), nullable=False),
        pa.field("tn", pa.int64(), nullable=False),
        pa.field("onset_error_sum_ms", pa.float64(), nullable=False),
        pa.field("onset_pairs", pa.int64(), nullable=False),
    ]
)
student_variants_doc = TableDoc(
    "each student variant's reconstructed contacts vs the human's, summed per held-out demonstration",
    {
        "method": "the teacher method the student was distilled from",
        "seed": "the sweep seed of the student",
        "variant": 'student variant ("full" or an ablation)',
        "task": "pick | rotate | wipe | drawer",
        "demonstration": "the held-out glove recording",
        "tp": "time-region samples in contact in both",
        "fp": "in contact in the reconstruction only",
        "fn": "in contact in the human's only",
        "tn": "in contact in neither",
        "onset_error_sum_ms": "sum of |onset error| (ms) over the demonstration's regions with an onset on both sides",
        "onset_pairs": "those regions",
    },
)

# --- Replays on the robot (flow `replay`; rewritten whole, one file per task x method) ---------
# Every trajectory the replay stage was asked to execute on the hardware twin (or a lab's rig), with
# what it wrote, or why nothing was: a method with no trajectory for a task is a row, not a crash.
# Files: lake/replays/<task>__<method>__<seed>.parquet
replays = pa.schema(
    [
        pa.field("task", pa.string(), nullable=False),
        pa.field("method", pa.string(), nullable=False),
        pa.field("seed", pa.int64(), nullable=False),
        pa.field("origin", pa.string()),
        pa.field("trajectory", pa.string()),
        pa.field("reference_id", pa.string()),
        pa.field("replay_file", pa.string()),
        pa.field("calibration_file", pa.string()),
        pa.field("status", pa.string(), nullable=False),
        pa.field("reason", pa.string(), nullable=False),
        pa.field("rig", pa.string(), nullable=False),
        pa.field("duration_s", pa.float64()),
        pa.field("peak_force", pa.list_(pa.float32(), 8)),
        pa.field("contact_fraction", pa.list_(pa.float32(), 8)),
        pa.field("perturbation", pa.string()),
    ]
)
replays_doc = TableDoc(
    "robot replays the replay stage executed (or skipped), per task x method x demonstration",
    {
        "task": "pick | rotate | wipe | drawer",
        "method": "the retargeting method whose trajectory was executed",
        "seed": "the sweep seed of the trajectory and of the twin's draw",
        "origin": "teacher | kinematic | student: which of the method's rollouts; NULL when skipped",
        "trajectory": "the rollouts rollout_id executed; NULL when skipped",
        "reference_id": "the glove recording the trajectory follows; NULL when skipped",
        "replay_file": "the robot_replay MCAP written (file name); NULL when skipped",
        "calibration_file": "its unloaded TwinTac calibration MCAP (file name); NULL when skipped",
        "status": "replayed | skipped | failed",
        "reason": "why skipped or failed (empty when replayed)",
        "rig": "what executed it: twin (the MuJoCo hardware twin)",
        "duration_s": "replay length (s)",
        "peak_force": "largest contact force measured per region T1..T4, P1..P4 (N)",
        "contact_fraction": "share of the replay's 100 Hz samples with force > 0.5 N per region",
        "perturbation": "JSON: the twin's hardware draw for this replay (friction, mass, gains, latency, ...)",
    },
)

SCHEMAS: dict[str, pa.Schema] = {
    "recordings": recordings,
    "taxels": taxels,
    "hand_joints": hand_joints,
    "hand_keypoints": hand_keypoints,
    "wrist_pose": wrist_pose,
    "object_pose": object_pose,
    "robot_joint_states": robot_joint_states,
    "robot_joint_targets": robot_joint_targets,
    "twintac": twintac,
    "fsr": fsr,
    "time_map": time_map,
    "contacts": contacts,
    "thresholds": thresholds,
    "contact_metrics": contact_metrics,
    "onset_errors": onset_errors,
    "comparison": comparison,
    "user_study": user_study,
    "retargeted": retargeted,
    "rollouts": rollouts,
    "policy_eval": policy_eval,
    "student_dataset": student_dataset,
    "student_predictions": student_predictions,
    "student_variants": student_variants,
    "replays": replays,
}

DOCS: dict[str, TableDoc] = {
    "recordings": recordings_doc,
    "taxels": taxels_doc,
    "hand_joints": hand_joints_doc,
    "hand_keypoints": hand_keypoints_doc,
    "wrist_pose": wrist_pose_doc,
    "object_pose": object_pose_doc,
    "robot_joint_states": robot_joint_states_doc,
    "robot_joint_targets": robot_joint_targets_doc,
    "twintac": twintac_doc,
    "fsr": fsr_doc,
    "time_map": time_map_doc,
    "contacts": contacts_doc,
    "thresholds": thresholds_doc,
    "contact_metrics": contact_metrics_doc,
    "onset_errors": onset_errors_doc,
    "comparison": comparison_doc,
    "user_study": user_study_doc,
    "retargeted": retargeted_doc,
    "rollouts": rollouts_doc,
    "policy_eval": policy_eval_doc,
    "student_dataset": student_dataset_doc,
    "student_predictions": student_predictions_doc,
    "student_variants": student_variants_doc,
    "replays": replays_doc,
}

# Hive partition columns per table (directory levels under lake/<table>/).
PARTITIONS: dict[str, tuple[str, ...]] = {
    "contacts": ("source", "task"),
    "rollouts": ("method",),
}


def unseeded(table: str) -> pa.Schema:
    """A table's schema without its ``seed`` column: the rows a library function computes. The stage that
    stores them adds the sweep seed (``touch2robot.datasets.with_seed``)."""
    schema = SCHEMAS[table]
    return schema.remove(schema.get_field_index("seed"))
