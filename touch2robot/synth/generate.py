"""The simulated demonstrator: writes glove sessions as MCAP files exactly as the rig would, plus
ground truth kept apart (``<data>/groundtruth``, read only by tests). Robot replays are not its
business: they come from executing each method's trajectory on the hardware twin (flow ``replay``)."""

from __future__ import annotations

import os
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from schemas.glove import region_taxels
from schemas.messages import ROBOT_DESCRIPTION_TOPIC, TF_TOPIC
from schemas.rig import DEFAULT_RIG, Rig
from schemas.tables import HUMAN_REGIONS
from schemas.vocabulary import RecordingKind
from touch2robot import geometry, scenes
from touch2robot.leap.urdf import URDF_ROOT, hand_urdf
from touch2robot.recording import cdr, clock
from touch2robot.recording.writer import RecordingWriter
from touch2robot.synth.config import SynthConfig
from touch2robot.synth.hand import HumanHand
from touch2robot.synth.motion import Scene, Trajectory, taxel_forces_along
from touch2robot.synth.sensors import glove_readings, taxel_pooling

CONTACT_N = 0.5
_REGION_IDX = {r: region_taxels(r) for r in HUMAN_REGIONS}


@dataclass(frozen=True)
class RecordingJob:
    """One glove session to write: a subject's demonstration of a task."""

    task: str
    subject: int
    demo: int

    @property
    def stem(self) -> str:
        return f"{self.task}_s{self.subject:02d}_d{self.demo:02d}_glove"

    @property
    def file_name(self) -> str:
        return f"{self.stem}.mcap"


def plan(config: SynthConfig) -> list[RecordingJob]:
    """Every recording the configuration asks for, in a stable order."""
    return [
        RecordingJob(task, subject, demo)
        for task in config.tasks
        for subject in range(1, config.subjects + 1)
        for demo in range(1, config.demos_per_subject + 1)
    ]


def _rng(config: SynthConfig, job: RecordingJob, stream: int) -> np.random.Generator:
    return np.random.default_rng([config.seed, scenes.TASKS.index(job.task), job.subject, job.demo, stream])


def _demonstration(config: SynthConfig, job: RecordingJob) -> tuple[HumanHand, Trajectory, Scene]:
    task = scenes.task(job.task)
    spec = task.default_config()
    subject_rng = np.random.default_rng([config.seed, 1000 + job.subject])
    hand = HumanHand(scale=subject_rng.uniform(0.92, 1.08))
    rng = _rng(config, job, 0)
    traj = task.demonstrate(spec, hand, rng, config.pace * rng.uniform(0.9, 1.1))
    return hand, traj, Scene.from_task(spec)


def _start_offset_s(job: RecordingJob) -> int:
    """A stable, distinct start second per recording (str hash() is salted per process)."""
    return zlib.crc32(job.stem.encode()) % 10**6


def _region_forces(taxel_force: np.ndarray) -> np.ndarray:
    return np.stack([taxel_force[:, _REGION_IDX[r]].sum(axis=1) for r in HUMAN_REGIONS], axis=1)


def _write_groundtruth(
    path: Path, t: np.ndarray, regions: tuple[str, ...], force: np.ndarray, extra: dict | None = None
) -> None:
    n = len(t)
    cols = {
        "t": np.repeat(t, len(regions)),
        "region": np.tile(np.asarray(regions), n),
        "force": force.reshape(-1).astype(np.float32),
        "contact": force.reshape(-1) > CONTACT_N,
    }
    table = pa.table(cols)
    if extra:
        table = table.replace_schema_metadata({k: str(v) for k, v in extra.items()})
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    pq.write_table(table, tmp)
    os.replace(tmp, path)


def write_recording(
    config: SynthConfig, job: RecordingJob, recordings: Path, groundtruth: Path, rig: Rig = DEFAULT_RIG
) -> Path:
    """Write one glove session as ``rig`` records it (its topics, rates and taxel layout), and its ground
    truth; returns the MCAP path."""
    path = recordings / job.file_name
    _write_glove(config, job, path, groundtruth / f"{job.stem}.parquet", rig)
    return path


def _write_glove(config: SynthConfig, job: RecordingJob, path: Path, gt_path: Path, rig: Rig) -> None:
    hand, traj, scene = _demonstration(config, job)
    rng = _rng(config, job, 1)
    duration = float(traj.t[-1])
    t0_ns = clock.EPOCH_NS + _start_offset_s(job) * 10**9
    rate = {name: rig.streams[name].rate_hz for name in ("taxels", "hand_joints", "object_pose")}
    t_tax = clock.stamps(duration, rate["taxels"], rng)
    force = taxel_forces_along(hand, scene, traj.sample(t_tax))
    raw = glove_readings(force @ taxel_pooling(rig.glove).T, t_tax, rng)
    t_hand = clock.stamps(duration, rate["hand_joints"], rng)
    hand_traj = traj.sample(t_hand)
    joints = hand_traj.joints + rng.normal(0.0, 0.01, hand_traj.joints.shape)
    wrist_pos = hand_traj.wrist_pos + rng.normal(0.0, 0.001, hand_traj.wrist_pos.shape)
    keypoints = geometry.transform_points(hand.forward(joints).keypoints, wrist_pos, hand_traj.wrist_quat)
    t_obj = clock.stamps(duration, rate["object_pose"], rng)
    obj = traj.sample(t_obj)
    obj_pos = obj.object_pos + rng.normal(0.0, 0.0005, obj.object_pos.shape)

    def ns(t: float) -> int:
        return t0_ns + round(t * 1e9)

    metadata = {"task": job.task, "subject": f"s{job.subject:02d}", "demo": str(job.demo)}
    topic = rig.topic
    with RecordingWriter(path, RecordingKind.GLOVE_SESSION, metadata, rig=rig, viewer=True) as w:
        # the robot's description once, at the start, as robot_state_publisher latches it
        first = ns(min(t_tax[0], t_hand[0], t_obj[0]))
        w.write(ROBOT_DESCRIPTION_TOPIC.name, first, cdr.encode_string(hand_urdf()))
        # interleave streams in time order, as a live recorder would
        events = sorted(
            [(t, 0, i) for i, t in enumerate(t_tax)]
            + [(t, 1, i) for i, t in enumerate(t_hand)]
            + [(t, 2, i) for i, t in enumerate(t_obj)]
        )
        for t, stream, i in events:
            stamp = ns(t)
            if stream == 0:
                w.write(topic("taxels"), stamp, cdr.encode_tactile(stamp, "glove_right", raw[i]))
            elif stream == 1:
                w.write(
                    topic("hand_joints"),
                    stamp,
                    cdr.encode_joint_state(stamp, "glove_right", rig.glove.joint_names, joints[i]),
                )
                w.write(topic("hand_keypoints"), stamp, cdr.encode_pose_array(stamp, "world", keypoints[i]))
                w.write(
                    topic("wrist_pose"),
                    stamp,
                    cdr.encode_pose_stamped(stamp, "world", wrist_pos[i], hand_traj.wrist_quat[i]),
                )
                # the wrist as a transform: Foxglove's 3D panel places the robot description's root on it
                w.write(
                    TF_TOPIC.name,
                    stamp,
                    cdr.encode_tf(stamp, "world", URDF_ROOT, wrist_pos[i], hand_traj.wrist_quat[i]),
                )
            else:
                w.write(
                    topic("object_pose"),
                    stamp,
                    cdr.encode_pose_stamped(stamp, scenes.get(job.task).object.name, obj_pos[i], obj.object_quat[i]),
                )
    start = min(t_tax[0], t_hand[0], t_obj[0])
    _write_groundtruth(gt_path, t_tax - start, HUMAN_REGIONS, _region_forces(force), {"hand_scale": hand.scale})
    motion = pa.table(
        {
            "t": t_hand - start,
            "joints": pa.array(list(hand_traj.joints.astype(np.float32)), type=pa.list_(pa.float32(), 20)),
            "wrist_pos": pa.array(list(hand_traj.wrist_pos), type=pa.list_(pa.float64(), 3)),
            "wrist_quat": pa.array(list(hand_traj.wrist_quat), type=pa.list_(pa.float64(), 4)),
        }
    )
    pq.write_table(motion, gt_path.with_suffix(".motion.parquet"))
