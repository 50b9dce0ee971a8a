"""Shared test setup: every test process works in its own temporary data folder and
Prefect home (nothing is written into the repository), with Prefect's ephemeral API
given time to start on a 2-core machine."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import pytest

_SESSION_DIR = Path(tempfile.mkdtemp(prefix="touch2robot-tests-"))
os.environ["TOUCH2ROBOT_DATA"] = str(_SESSION_DIR / "data")
os.environ["PREFECT_HOME"] = str(_SESSION_DIR / "prefect")
os.environ["PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS"] = "180"
os.environ["PREFECT_SERVER_ANALYTICS_ENABLED"] = "false"
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.pop("MLFLOW_TRACKING_URI", None)
os.environ.pop("PREFECT_API_URL", None)


@pytest.fixture(autouse=True)
def _no_tracking_uri_leak():
    """MLflow exports MLFLOW_TRACKING_URI whenever a URI is set; one test's store must not
    become the next test's 'user server'."""
    yield
    os.environ.pop("MLFLOW_TRACKING_URI", None)


@pytest.fixture(scope="session")
def session_dir() -> Path:
    return _SESSION_DIR


@pytest.fixture(scope="session")
def smoke_data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A data folder with the smoke profile's demonstrator recordings and ground truth
    (library calls only, a few seconds). Tests must copy it before changing it."""
    from touch2robot.config import load_profile
    from touch2robot.settings import DataLayout
    from touch2robot.synth.generate import plan, write_recording

    layout = DataLayout(tmp_path_factory.mktemp("smoke") / "data")
    config = load_profile("smoke").synth
    for job in plan(config):
        write_recording(config, job, layout.recordings, layout.groundtruth)
    return layout.root


@pytest.fixture(scope="session")
def demo_lake(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A data folder with one glove demonstration per task, ingested, with human contacts and
    kinematic retargeting in the lake (library calls only). Tests must copy it before changing it."""
    from touch2robot import lake as lake_io
    from touch2robot.contacts import ContactsConfig
    from touch2robot.contacts.extract import human_contacts
    from touch2robot.ingest import ingest_file, recording_rows
    from touch2robot.retarget import LEAP_DEFAULT
    from touch2robot.retarget.lake import load_hand_motion, write_result
    from touch2robot.retarget.retargeter import Retargeter, retarget_motion
    from touch2robot.settings import DataLayout
    from touch2robot.synth.config import SynthConfig
    from touch2robot.synth.generate import RecordingJob, write_recording

    layout = DataLayout(tmp_path_factory.mktemp("demos") / "data")
    config = SynthConfig(subjects=1, demos_per_subject=1, replays_per_task=0)
    retargeter = Retargeter(LEAP_DEFAULT)
    for task in config.tasks:
        ingest_file(write_recording(config, RecordingJob("glove_session", task, 1, 1), layout.recordings, layout.groundtruth), layout.lake)
    for recording in recording_rows(layout.lake).to_pylist():
        rid = recording["recording_id"]
        rows, _ = human_contacts(layout.lake, recording, ContactsConfig())
        lake_io.write_rows(layout.lake, "contacts", rid, rows, {"source": "human", "task": recording["task"]})
        write_result(layout.lake, retarget_motion(load_hand_motion(layout.lake, rid), LEAP_DEFAULT, retargeter))
    return layout.root
