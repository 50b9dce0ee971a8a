"""Arrow schemas of every table in the lake: the data contract between stages.

Each table lives under ``<data>/lake/<name>/`` as hive-partitioned Parquet
(partition columns are listed in ``PARTITIONS``) and is exposed as a DuckDB
view of the same name by ``touch2robot.catalog``.
"""

from __future__ import annotations

import pyarrow as pa

# The shared semantic contact space (paper convention): robot fingertips <-> human
# T1..T4 (thumb, index, middle, ring), robot palm pads <-> P1..P4. The human T5
# (little finger) has no robot counterpart and never enters a comparison.
ROBOT_REGIONS: tuple[str, ...] = ("T1", "T2", "T3", "T4", "P1", "P2", "P3", "P4")
HUMAN_REGIONS: tuple[str, ...] = ("T1", "T2", "T3", "T4", "T5", "P1", "P2", "P3", "P4")
FINGERTIP_REGIONS: tuple[str, ...] = ("T1", "T2", "T3", "T4", "T5")
PALM_REGIONS: tuple[str, ...] = ("P1", "P2", "P3", "P4")

# Contact sources appended to the `contacts` table by the stages.
CONTACT_SOURCES: tuple[str, ...] = ("human", "sim", "real", "reconstructed")

RECORDING_KINDS: tuple[str, ...] = ("glove_session", "robot_replay", "robot_calibration")


def _stream(column: str, width: int) -> pa.Schema:
    """A sensor stream of one recording: its id, the time in seconds since the recording's
    first message, and a fixed-width float32 array per sample."""
    return pa.schema(
        [
            pa.field("recording_id", pa.string(), nullable=False),
            pa.field("t", pa.float64(), nullable=False),
            pa.field(column, pa.list_(pa.float32(), width), nullable=False),
        ]
    )


recordings = pa.schema(
    [
        pa.field("recording_id", pa.string(), nullable=False),  # sha256 of the file content (first 16 hex)
        pa.field("path", pa.string(), nullable=False),
        pa.field("file_name", pa.string(), nullable=False),
        pa.field("size_bytes", pa.int64(), nullable=False),
        pa.field("kind", pa.string()),
        pa.field("task", pa.string()),
        pa.field("subject", pa.string()),
        pa.field("method", pa.string()),
        pa.field("reference_recording", pa.string()),  # replay: file name of the glove session it replays
        pa.field("calibration_recording", pa.string()),  # replay: file name of its TwinTac calibration
        pa.field("start_time_s", pa.float64()),
        pa.field("end_time_s", pa.float64()),
        pa.field("duration_s", pa.float64()),
        pa.field("message_counts", pa.string()),  # JSON {topic: count}
        pa.field("status", pa.string(), nullable=False),  # "ingested" | "quarantined"
        pa.field("reason", pa.string()),  # why quarantined (empty when ingested)
        pa.field("ingested_at", pa.timestamp("us", tz="UTC")),
    ]
)

# --- Streams of glove sessions -------------------------------------------------
taxels = _stream("values", 256)

hand_joints = _stream("position", 20)

# 21 keypoints x (x, y, z) in the world frame, row-major (wrist, then 4 per finger thumb..little)
hand_keypoints = _stream("xyz", 63)

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
wrist_pose = pa.schema(POSE_FIELDS)
object_pose = pa.schema(POSE_FIELDS)

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

robot_joint_targets = _stream("position", 16)

twintac = _stream("values", 16)

fsr = _stream("values", 4)

time_map = pa.schema(
    [
        pa.field("recording_id", pa.string(), nullable=False),  # the replay recording
        pa.field("t", pa.float64(), nullable=False),  # replay time (s since replay start)
        pa.field("t_ref", pa.float64(), nullable=False),  # reference-trajectory time (s since reference start)
    ]
)

# --- Derived tables ------------------------------------------------------------
contacts = pa.schema(
    [
        pa.field("source", pa.string(), nullable=False),  # human | sim | real | reconstructed
        pa.field("method", pa.string(), nullable=False),  # "human" for the glove; else the method name
        pa.field("task", pa.string(), nullable=False),
        pa.field("subject", pa.string(), nullable=False),
        pa.field("sequence_id", pa.string(), nullable=False),  # recording id or rollout id
        pa.field("reference_id", pa.string(), nullable=False),  # glove recording whose preference is the reference
        pa.field("t", pa.float64(), nullable=False),  # seconds in the sequence's own clock
        pa.field("t_ref", pa.float64(), nullable=False),  # seconds on the reference trajectory's clock
        pa.field("region", pa.string(), nullable=False),  # one of ROBOT_REGIONS
        pa.field("contact", pa.bool_(), nullable=False),
        pa.field("value", pa.float32()),  # regional response / force behind the decision (NaN if none)
    ]
)

thresholds = pa.schema(
    [
        pa.field("recording_id", pa.string(), nullable=False),
        pa.field("sensor", pa.string(), nullable=False),  # glove | twintac | fsr
        pa.field("applies_to", pa.string(), nullable=False),  # fingertip | palm (glove) or channel_<i>
        pa.field("threshold", pa.float64(), nullable=False),
        pa.field("baseline", pa.float64()),
        pa.field("noise", pa.float64()),
        pa.field("method", pa.string(), nullable=False),  # how it was derived
    ]
)

# --- Evaluation tables (flow `evaluate`; rebuilt whole on every run) ----------------
# A key column holding '*' (touch2robot.metrics.ALL) is rolled up over that dimension;
# undefined ratios (0/0) are NULL.
contact_metrics = pa.schema(
    [
        pa.field("source", pa.string(), nullable=False),  # the evaluated source (sim | real | reconstructed)
        pa.field("method", pa.string(), nullable=False),
        pa.field("task", pa.string(), nullable=False),  # or '*'
        pa.field("region", pa.string(), nullable=False),  # one of ROBOT_REGIONS, or '*'
        pa.field("reference_source", pa.string(), nullable=False),  # what it is scored against ("human")
        pa.field("n_sequences", pa.int64(), nullable=False),
        pa.field("tp", pa.int64(), nullable=False),  # over all compared time-region pairs
        pa.field("fp", pa.int64(), nullable=False),
        pa.field("fn", pa.int64(), nullable=False),
        pa.field("tn", pa.int64(), nullable=False),
        pa.field("n", pa.int64(), nullable=False),  # tp + fp + fn + tn
        pa.field("precision", pa.float64()),
        pa.field("recall", pa.float64()),
        pa.field("f1", pa.float64()),
        pa.field("fpr", pa.float64()),
    ]
)

onset_errors = pa.schema(
    [
        pa.field("source", pa.string(), nullable=False),
        pa.field("method", pa.string(), nullable=False),
        pa.field("task", pa.string(), nullable=False),  # or '*'
        pa.field("sequence_id", pa.string(), nullable=False),  # evaluated sequence; '*' on summary rows
        pa.field("region", pa.string(), nullable=False),  # or '*'
        pa.field("subject", pa.string(), nullable=False),  # '*' on summary rows
        pa.field("reference_id", pa.string(), nullable=False),  # '*' on summary rows
        pa.field("reference_source", pa.string(), nullable=False),
        pa.field("t_ref_onset", pa.float64()),  # pair rows: reference onset (s, reference clock); NULL if none
        pa.field("t_eval_onset", pa.float64()),  # pair rows: evaluated onset on the reference clock; NULL if none
        pa.field("error_ms", pa.float64()),  # pair: |t_eval - t_ref| in ms; summary: E over its valid pairs
        pa.field("valid", pa.bool_()),  # pair rows: an onset on both sides; NULL on summary rows
        pa.field("via_time_map", pa.bool_()),  # pair rows: evaluated times mapped by the recorded time map
        pa.field("n_pairs", pa.int64(), nullable=False),  # trajectory-region pairs summarised (1 on a pair row)
        pa.field("n", pa.int64(), nullable=False),  # N: valid pairs
        pa.field("n_missing_reference", pa.int64(), nullable=False),
        pa.field("n_missing_evaluated", pa.int64(), nullable=False),
        pa.field("n_missing_both", pa.int64(), nullable=False),
    ]
)

user_study = pa.schema(
    [
        pa.field("ratings_file", pa.string(), nullable=False),
        pa.field("ratings_sha256", pa.string(), nullable=False),
        pa.field("question", pa.string(), nullable=False),
        pa.field("n", pa.int64(), nullable=False),  # paired participants
        pa.field("n_zero", pa.int64(), nullable=False),  # zero differences (dropped by zero_method "wilcox")
        pa.field("median_visual_feedback", pa.float64()),
        pa.field("iqr_visual_feedback", pa.float64()),
        pa.field("median_touch2robot", pa.float64()),
        pa.field("iqr_touch2robot", pa.float64()),
        pa.field("statistic", pa.float64()),  # two-sided Wilcoxon signed-rank min(R+, R-)
        pa.field("p", pa.float64()),
        pa.field("p_holm", pa.float64()),  # Holm-adjusted across the questions
        pa.field("zero_method", pa.string(), nullable=False),  # scipy.stats.wilcoxon settings used
        pa.field("method", pa.string(), nullable=False),
        pa.field("correction", pa.bool_(), nullable=False),
        pa.field("synthetic", pa.bool_(), nullable=False),  # SYNTHETIC example ratings, not participants
    ]
)

# --- Kinematic retargeting (flow `retarget`; one file per glove recording) -----------
retargeted = pa.schema(
    [
        pa.field("recording_id", pa.string(), nullable=False),  # the glove recording
        pa.field(
            "t", pa.float64(), nullable=False
        ),  # the hand-motion frame's time (s since the recording's first message)
        pa.field("position", pa.list_(pa.float32(), 16), nullable=False),  # LEAP joints (rad), LEAP_JOINT_NAMES order
        pa.field(
            "status", pa.string(), nullable=False
        ),  # ok | solver_error | non_finite | residual | invalid_input (not ok: previous solution held)
        pa.field(
            "residual", pa.list_(pa.float32(), 4), nullable=False
        ),  # fingertip to scaled human target (m): thumb, index, middle, ring
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

# --- Robot trajectories in simulation (flow `teachers`; one file per method x task) ---------
# One row per control step (20 Hz) of a rollout: the state observed at ``t`` and the command
# applied from it (LeRobot's frame convention: observation and action of the same frame).
# ``origin`` says what produced the commands: "teacher" (a trained PPO teacher, deterministic
# actions: touch2robot, contrack, dexmachina), "kinematic" (dex-retargeting: the kinematic
# trajectory replayed with no residual) or "student" (touch2robot's distilled student, on every
# demonstration of the task: the held-out ones are those in `student_predictions`, the others
# were trained on, as every teacher trained on all of them). Row 0 of a rollout is its reset state, so replaying the commands from
# it in the same scene reproduces the rollout: reset with hand qpos = joint_position, servo targets
# = joint_position, wrist body and mocap = wrist_state, object = object_pose (drawer: drawer_opening)
# (touch2robot.teachers.rollouts.reset_to_rows). Files: lake/rollouts/method=<m>/<origin>-<task>.parquet
ROLLOUT_METHODS: tuple[str, ...] = ("touch2robot", "contrack", "dexmachina", "dex-retargeting")
ROLLOUT_ORIGINS: tuple[str, ...] = ("teacher", "kinematic", "student")

rollouts = pa.schema(
    [
        pa.field("rollout_id", pa.string(), nullable=False),  # "<origin>-<method>-<task>-<index:03d>"
        pa.field("origin", pa.string(), nullable=False),  # one of ROLLOUT_ORIGINS
        pa.field("method", pa.string(), nullable=False),
        pa.field("task", pa.string(), nullable=False),
        pa.field("subject", pa.string(), nullable=False),
        pa.field("reference_id", pa.string(), nullable=False),  # the glove recording followed
        pa.field("step", pa.int32(), nullable=False),  # control step since reset
        pa.field("t", pa.float64(), nullable=False),  # s since the rollout's reset
        pa.field("t_ref", pa.float64(), nullable=False),  # s on the reference recording's clock
        pa.field(
            "joint_position", pa.list_(pa.float64(), 16), nullable=False
        ),  # LEAP joints (rad), LEAP_JOINT_NAMES order
        pa.field("joint_velocity", pa.list_(pa.float64(), 16), nullable=False),
        pa.field("joint_target", pa.list_(pa.float64(), 16), nullable=False),  # command applied from this state
        pa.field("reference_joints", pa.list_(pa.float32(), 16), nullable=False),  # kinematic retargeting at t_ref
        pa.field(
            "wrist_state", pa.list_(pa.float64(), 7), nullable=False
        ),  # observed wrist body pose: px py pz qw qx qy qz
        pa.field(
            "wrist_pose", pa.list_(pa.float64(), 7), nullable=False
        ),  # commanded wrist (mocap) pose from this state
        pa.field("object_pose", pa.list_(pa.float64(), 7), nullable=False),  # object body pose in the world
        pa.field("drawer_opening", pa.float64(), nullable=False),  # slide travel (m); 0 for free objects
        pa.field("region_force", pa.list_(pa.float32(), 8), nullable=False),  # N on T1..T4, P1..P4
        pa.field("progress", pa.float32(), nullable=False),  # task progress in [0, 1]
        pa.field("success", pa.bool_(), nullable=False),  # the task's success criterion so far
    ]
)

# --- Diffusion Policy evaluation (flow `policy`; one file per method x task) ----------------
# Closed-loop success of LeRobot's Diffusion Policy trained on one method's robot demonstrations
# of one task (the paper's downstream test). Files: lake/policy_eval/<method>-<task>.parquet
policy_eval = pa.schema(
    [
        pa.field("task", pa.string(), nullable=False),
        pa.field("method", pa.string(), nullable=False),  # whose rollouts the demonstrations are
        pa.field("origin", pa.string(), nullable=False),  # which rollouts: student | teacher | kinematic
        pa.field("profile", pa.string(), nullable=False),
        pa.field("dataset_episodes", pa.int32(), nullable=False),  # demonstrations trained on
        pa.field("dataset_frames", pa.int32(), nullable=False),
        pa.field("train_steps", pa.int32(), nullable=False),  # optimizer updates
        pa.field("final_loss", pa.float32(), nullable=False),  # mean diffusion loss over the last logging window
        pa.field("episodes", pa.int32(), nullable=False),  # seeded closed-loop episodes
        pa.field("successes", pa.int32(), nullable=False),
        pa.field("success_rate", pa.float32(), nullable=False),
        pa.field("ci_low", pa.float32(), nullable=False),  # 95 % Wilson interval of the success rate
        pa.field("ci_high", pa.float32(), nullable=False),
        pa.field("mean_progress", pa.float32(), nullable=False),  # task progress in [0, 1] at episode end
        # the ceiling: each episode's demonstration commands replayed open loop from the same (jittered) start
        pa.field("replay_successes", pa.int32(), nullable=False),
        pa.field("replay_success_rate", pa.float32(), nullable=False),
        # open-loop fit on the policy's own dataset (touch2robot.policy.evaluate.ActionFit): mean
        # |executed - recorded action| over sampled frames, and the same for holding the frame's state
        pa.field("fit_joint_err_rad", pa.float32(), nullable=False),
        pa.field("fit_wrist_err_mm", pa.float32(), nullable=False),
        pa.field("hold_joint_err_rad", pa.float32(), nullable=False),
        pa.field("hold_wrist_err_mm", pa.float32(), nullable=False),
        pa.field("episode_steps", pa.int32(), nullable=False),  # control steps per episode (20 Hz)
        pa.field("replans", pa.int32(), nullable=False),  # policy inferences per episode
        pa.field("mlflow_run", pa.string(), nullable=False),  # run of stage "policy" with curves, videos, policy
    ]
)

# --- Student retargeter (flow `student`) ------------------------------------------------
# Training data of the distilled student: paired human-robot steps from teacher rollouts, one
# row per (rollout, step j). Step j pairs the human demonstration at reference frame j with the
# teacher's command aimed at that frame and the sim contacts it led to. Training rollouts are
# the teacher's rollouts once unchanged, then copies with N(0, std^2) added per frame and joint
# to kinematic_joints and target_joints alike (touch2robot.student.augment).
# Files: lake/student_dataset/<task>.parquet
student_dataset = pa.schema(
    [
        pa.field("sample_id", pa.string(), nullable=False),  # "<split>-<task>-<index:03d>": one student sequence
        pa.field("split", pa.string(), nullable=False),  # train | val (validation demonstrations, never trained on)
        pa.field("task", pa.string(), nullable=False),
        pa.field("reference_id", pa.string(), nullable=False),  # the glove recording
        pa.field("source_rollout_id", pa.string(), nullable=False),  # the teacher rollout it comes from
        pa.field(
            "augment", pa.int32(), nullable=False
        ),  # 0 = the teacher rollout unchanged, k > 0 = its k-th noisy copy
        pa.field("step", pa.int32(), nullable=False),  # j: the reference frame the command aims at
        pa.field("t_ref", pa.float64(), nullable=False),  # s on the glove recording's clock
        pa.field(
            "kinematic_joints", pa.list_(pa.float32(), 16), nullable=False
        ),  # input: raw kinematic retargeting (+ noise)
        pa.field(
            "wrist_pose", pa.list_(pa.float64(), 7), nullable=False
        ),  # input: kinematic robot wrist px py pz qw qx qy qz
        pa.field("object_pose", pa.list_(pa.float64(), 7), nullable=False),  # input: demonstrated object pose
        pa.field(
            "preference", pa.list_(pa.bool_(), 8), nullable=False
        ),  # input: human tactile preference, ROBOT_REGIONS
        pa.field(
            "target_joints", pa.list_(pa.float64(), 16), nullable=False
        ),  # target: teacher joint command (+ the same noise)
        pa.field("target_wrist", pa.list_(pa.float64(), 7), nullable=False),  # target: teacher wrist command
        pa.field(
            "contact", pa.list_(pa.bool_(), 8), nullable=False
        ),  # target: sim contact (region force > threshold) after it
    ]
)

# The student's predicted contacts beside the reconstructed (executed) ones in `contacts`
# (source reconstructed): one row per (student rollout, step, region); sequence_id, t and t_ref
# join them. Predictions cover the whole demonstration, also past an early end of the rollout.
# Files: lake/student_predictions/<method>-<task>.parquet
student_predictions = pa.schema(
    [
        pa.field(
            "sequence_id", pa.string(), nullable=False
        ),  # the student rollout ("student-<method>-<task>-<index:03d>")
        pa.field("method", pa.string(), nullable=False),
        pa.field("task", pa.string(), nullable=False),
        pa.field("reference_id", pa.string(), nullable=False),  # the held-out glove recording
        pa.field("variant", pa.string(), nullable=False),  # student variant ("full" or an ablation)
        pa.field("t", pa.float64(), nullable=False),  # s since the rollout's reset (step j: j / 20 Hz)
        pa.field("t_ref", pa.float64(), nullable=False),
        pa.field("region", pa.string(), nullable=False),  # one of ROBOT_REGIONS
        pa.field("logit", pa.float32(), nullable=False),  # predicted contact logit
        pa.field("contact", pa.bool_(), nullable=False),  # logit > 0
    ]
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
    "user_study": user_study,
    "retargeted": retargeted,
    "rollouts": rollouts,
    "policy_eval": policy_eval,
    "student_dataset": student_dataset,
    "student_predictions": student_predictions,
}

# Hive partition columns per table (directory levels under lake/<table>/).
PARTITIONS: dict[str, tuple[str, ...]] = {
    "contacts": ("source", "task"),
    "rollouts": ("method",),
}
