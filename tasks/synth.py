"""Tasks of the simulated demonstrator."""

from __future__ import annotations

from pathlib import Path

from prefect import task

from schemas.rig import DEFAULT_RIG
from tasks.common import ALWAYS_RUN, cache_policy
from touch2robot.ingest.rigs import write_rig
from touch2robot.synth.config import SynthConfig
from touch2robot.synth.generate import RecordingJob, write_recording
from touch2robot.synth.ratings import write_ratings_csv


@task(
    cache_policy=cache_policy(
        "touch2robot.synth", "touch2robot.scenes", "touch2robot.recording", "touch2robot.geometry", "touch2robot.leap"
    ),
    persist_result=True,
    task_run_name="synth-{job.stem}",
)
def synthesize_recording(config: SynthConfig, job: RecordingJob, recordings: str, groundtruth: str) -> str:
    """Write one demonstrator recording (deterministic in config + job); returns its path."""
    return str(write_recording(config, job, Path(recordings), Path(groundtruth)))


@task(**ALWAYS_RUN)
def write_default_rig(recordings: str) -> str:
    """The rig file the demonstrator and the twin record with, beside their recordings: a lab's template."""
    return str(write_rig(DEFAULT_RIG, Path(recordings)))


@task(cache_policy=cache_policy("touch2robot.synth.ratings"), persist_result=True)
def synthesize_ratings(path: str, seed: int) -> str:
    """The example user-study ratings (ten participants, labelled SYNTHETIC)."""
    write_ratings_csv(Path(path), seed=seed)
    return path
