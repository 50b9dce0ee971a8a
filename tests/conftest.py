"""Shared test setup: every test process works in its own temporary data folder and
Prefect home (nothing is written into the repository), with Prefect's ephemeral API
given time to start on a 2-core machine."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import tempfile
from collections.abc import Mapping
from pathlib import Path

import pytest

# a worker process that imports this module (a test's helper unpickled in a process pool) keeps its session's folder
_SESSION_DIR = Path(os.environ.get("TOUCH2ROBOT_TEST_SESSION") or tempfile.mkdtemp(prefix="touch2robot-tests-"))
os.environ["TOUCH2ROBOT_TEST_SESSION"] = str(_SESSION_DIR)
os.environ["TOUCH2ROBOT_DATA"] = str(_SESSION_DIR / "data")
os.environ["PREFECT_HOME"] = str(_SESSION_DIR / "prefect")
os.environ["PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS"] = "180"
os.environ["PREFECT_SERVER_ANALYTICS_ENABLED"] = "false"
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.pop("MLFLOW_TRACKING_URI", None)
os.environ.pop("PREFECT_API_URL", None)


def pytest_configure(config: pytest.Config) -> None:
    """pytest's own temporary folders go into the session's folder too (unless --basetemp says where)."""
    if config.option.basetemp is None:
        config.option.basetemp = str(_SESSION_DIR / "pytest")


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    """The session's folder (lakes, checkpoints, Prefect home: gigabytes) goes when every test
    passed; after a failure it stays for a look, with the failed tests' own folders in it."""
    if exitstatus == 0:
        shutil.rmtree(_SESSION_DIR, ignore_errors=True)
    else:
        print(f"\ntest data kept in {_SESSION_DIR}")


@pytest.fixture(autouse=True)
def _no_tracking_uri_leak():
    """MLflow exports MLFLOW_TRACKING_URI whenever a URI is set; one test's store must not
    become the next test's 'user server'."""
    yield
    os.environ.pop("MLFLOW_TRACKING_URI", None)


def live_processes_with_env(name: str, value: str) -> list[str]:
    """Live (not zombie) processes, other than this one, whose environment sets ``name=value``."""
    marker = f"{name}={value}".encode()
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            if (
                marker in (entry / "environ").read_bytes().split(b"\0")
                and (entry / "stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
            ):
                found.append(
                    f"{entry.name}: "
                    f"{(entry / 'cmdline').read_bytes().replace(b'\0', b' ')[:160].decode(errors='replace')}"
                )
        except OSError:
            continue
    return found


def kill_group(proc: subprocess.Popen) -> None:
    """SIGKILL to a process started with ``start_new_session`` and all it started; reaped."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)


def run_script_for_result(argv: list[str], data: Path, extra_env: dict[str, str] | None = None) -> tuple[dict, str]:
    """Run a Python script in a fresh process with its own data folder, Prefect home and embedded API (its
    process group killed afterwards: the API server and any worker left behind); the JSON object it printed
    last on a ``RESULT `` line, and its whole output."""
    import json
    import sys

    env = {
        **os.environ,
        **(extra_env or {}),
        "TOUCH2ROBOT_DATA": str(data),
        "PREFECT_HOME": str(data / "prefect"),
        "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
        "PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS": "120",
    }
    env.pop("PREFECT_API_URL", None)  # the embedded API: the case where workers must be told where it is
    proc = subprocess.Popen(
        [sys.executable, *argv],
        cwd=Path(__file__).resolve().parents[1],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    try:
        output, _ = proc.communicate(timeout=400)
    finally:
        kill_group(proc)
    lines = [line for line in output.splitlines() if line.startswith("RESULT ")]
    assert proc.returncode == 0 and lines, output[-6000:]
    return json.loads(lines[-1][len("RESULT ") :]), output


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


def write_twin_replays(root: Path, method: str = "touch2robot", twin=None, steps: int = 40) -> list[Path]:
    """Robot replays on the hardware twin, one per glove session under ``root/recordings``: a scripted grasp
    (``scripted_rollout_rows``) executed on the twin (default hardware draw unless ``twin`` is given), written
    next to its glove session with its calibration, named and linked as the replay stage does; the rollouts
    go into ``root/lake/rollouts`` (origin teacher), so that tactile fidelity can pair them. Returns the
    replay and calibration paths."""
    import pyarrow as pa

    from schemas.tables import SCHEMAS
    from touch2robot import datasets
    from touch2robot.sim.config import SimConfig
    from touch2robot.twin.config import TwinConfig
    from touch2robot.twin.replay import replay_rollout

    written = []
    by_task: dict[str, list[pa.Table]] = {}
    for k, glove in enumerate(sorted((root / "recordings").glob("*_glove.mcap"))):
        task = glove.name.split("_")[0]
        rows = scripted_rollout_rows(task, method, 1, steps, seed=k)
        rid = f"teacher-{method}-{task}-{len(by_task.get(task, [])):03d}"
        rows = rows.set_column(rows.schema.get_field_index("rollout_id"), "rollout_id", pa.array([rid] * len(rows)))
        by_task.setdefault(task, []).append(rows.select(SCHEMAS["rollouts"].names).cast(SCHEMAS["rollouts"]))
        stem = glove.name.removesuffix("_glove.mcap") + f"_{method}"
        replay, calibration = glove.with_name(f"{stem}_replay.mcap"), glove.with_name(f"{stem}_calib.mcap")
        metadata = {
            "task": task,
            "subject": glove.name.split("_")[1],
            "method": method,
            "reference_recording": glove.name,
            "calibration_recording": calibration.name,
            "trajectory": rid,
            "rig": "simulated",  # the twin records as the built-in rig
        }
        replay_rollout(rows, SimConfig(threads=1), twin or TwinConfig(), (k,), replay, calibration, metadata)
        written += [replay, calibration]
    for task, tables in by_task.items():
        key = datasets.rollouts_key("teacher", task, 0)
        datasets.ROLLOUTS.write(root / "lake", key, pa.concat_tables(tables), method=method)
    return written


@pytest.fixture(scope="session")
def replay_data(smoke_data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The smoke recordings plus a robot replay of a scripted grasp on the hardware twin per glove session
    (``write_twin_replays``). Tests must copy it before changing it."""
    import shutil

    root = tmp_path_factory.mktemp("replays") / "data"
    shutil.copytree(smoke_data, root)
    write_twin_replays(root)
    return root


@pytest.fixture(scope="session")
def demo_lake(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A data folder with one glove demonstration per task, ingested, with human contacts and
    kinematic retargeting in the lake (library calls only). Tests must copy it before changing it."""
    from touch2robot import lake as lake_io
    from touch2robot.contacts import ContactsConfig
    from touch2robot.contacts.extract import human_contacts
    from touch2robot.ingest import ingest_file, recording_rows
    from touch2robot.retarget import LEAP_DEFAULT
    from touch2robot.retarget.lake import load_hand_motion, result_rows
    from touch2robot.retarget.retargeter import Retargeter, retarget_motion
    from touch2robot.settings import DataLayout
    from touch2robot.synth.config import SynthConfig
    from touch2robot.synth.generate import RecordingJob, write_recording

    layout = DataLayout(tmp_path_factory.mktemp("demos") / "data")
    config = SynthConfig(subjects=1, demos_per_subject=1)
    retargeter = Retargeter(LEAP_DEFAULT)
    for task in config.tasks:
        ingest_file(
            write_recording(config, RecordingJob(task, 1, 1), layout.recordings, layout.groundtruth),
            layout.lake,
        )
    for recording in recording_rows(layout.lake).to_pylist():
        rid = recording["recording_id"]
        rows, _ = human_contacts(layout.lake, recording, ContactsConfig())
        lake_io.write_rows(layout.lake, "contacts", rid, rows, {"source": "human", "task": recording["task"]})
        result = retarget_motion(load_hand_motion(layout.lake, rid), LEAP_DEFAULT, retargeter)
        lake_io.write_rows(layout.lake, "retargeted", rid, result_rows(result))
    return layout.root


def scripted_rollout_rows(task: str, method: str, n: int, steps: int, origin: str = "teacher", seed: int = 0):
    """``rollouts`` rows from real MuJoCo physics for tests of the stages that read the table:
    ``n`` copies of a task scene reset at home, driven by a scripted grasp (joint targets blending
    from home toward a closed hand, the wrist lowering then rising, or for the drawer pulling along
    its slide; timing and pull varied per copy). Row
    ``k`` holds the state observed before command ``k`` and that command, as the teachers write.
    Copy ``i`` follows demonstration ``scripted-<i>``."""
    import numpy as np
    import pyarrow as pa

    from touch2robot.sim.config import SimConfig
    from touch2robot.sim.env import BatchEnv
    from touch2robot.sim.scene import build_scene

    close = np.array([1.0, 0.0, 1.0, 0.8] * 3 + [1.0, 1.0, 0.6, 0.4])
    rng = np.random.default_rng(seed)
    cfg = SimConfig(n_envs=n, threads=1)
    env = BatchEnv(build_scene(task, cfg), cfg)
    home = env.home_state[env.layout.qpos][env.scene.hand_qpos]
    onset = rng.uniform(3, 8, n)
    depth = rng.uniform(0.035, 0.05, n)
    pull = rng.uniform(0.002, 0.005, n)  # m per step along the drawer's slide
    slide = env.scene.spec.slide
    rows: dict[str, list] = {
        k: []
        for k in (
            "rollout_id",
            "reference_id",
            "step",
            "joint_position",
            "joint_velocity",
            "joint_target",
            "wrist_state",
            "wrist_pose",
            "object_pose",
            "drawer_opening",
            "region_force",
            "progress",
            "success",
        )
    }
    for k in range(steps):
        grip = np.clip((k - onset) / 10, 0, 1)[:, None]
        targets = home + grip * close
        down = depth * np.clip(k / 12, 0, 1) - 0.006 * np.clip(k - 22, 0, None)
        wrist = np.tile(np.concatenate([env.scene.home_wrist_pos, env.scene.home_wrist_quat]), (n, 1))
        if slide is None:
            wrist[:, 2] -= down
        else:
            wrist[:, 2] -= depth * np.clip(k / 12, 0, 1)
            wrist[:, :3] += (pull * np.clip(k - 16, 0, None))[:, None] * np.asarray(slide.axis)
        obj = env.object_pose if not env.scene.is_drawer else np.zeros((n, 7))
        for i in range(n):
            rows["rollout_id"].append(f"{origin}-{method}-{task}-{i:03d}")
            rows["reference_id"].append(f"scripted-{i:03d}")
            rows["step"].append(k)
            rows["joint_position"].append(env.hand_qpos[i].copy())
            rows["joint_velocity"].append(env.hand_qvel[i].copy())
            rows["joint_target"].append(targets[i])
            rows["wrist_state"].append(env.wrist_pose[i].copy())
            rows["wrist_pose"].append(wrist[i])
            rows["object_pose"].append(obj[i].copy())
            rows["drawer_opening"].append(float(env.drawer_opening[i]))
            rows["region_force"].append(env.region_force[i].copy())
            rows["progress"].append(float(env.progress[i]))
            rows["success"].append(bool(env.success[i]))
        env.step(targets, wrist[:, :3], wrist[:, 3:])
    env.close()
    total = len(rows["step"])
    dt = cfg.control_dt
    return pa.table(
        {
            **{k: [v.tolist() if hasattr(v, "tolist") else v for v in vals] for k, vals in rows.items()},
            "origin": [origin] * total,
            "method": [method] * total,
            "task": [task] * total,
            "subject": ["s00"] * total,
            "t": [s * dt for s in rows["step"]],
            "t_ref": [s * dt for s in rows["step"]],
            "reference_joints": [r.tolist() for r in rows["joint_target"]],
            "seed": [0] * total,  # the sweep seed
        }
    )


def rollouts_following(task: str, method: str, origin: str, reference_id: str, n: int = 2):
    """``scripted_rollout_rows`` of a method that follow one glove session, typed as the ``rollouts`` table."""
    import pyarrow as pa

    from schemas.tables import SCHEMAS

    rows = scripted_rollout_rows(task, method, n, 4, origin=origin)
    column = rows.schema.get_field_index("reference_id")
    rows = rows.set_column(column, "reference_id", pa.array([reference_id] * len(rows)))
    return rows.select(SCHEMAS["rollouts"].names).cast(SCHEMAS["rollouts"])


def lerobot_frame(dataset, index: int) -> dict:
    """One frame of a LeRobot dataset (its ``__getitem__`` is typed ``dict | list[dict]``, for slices)."""
    frame = dataset[index]
    assert isinstance(frame, dict)
    return frame


def comparison_clusters(
    skills: Mapping[str, float],
    scorings: tuple[tuple[str, str], ...] = (("human", "sim"),),
    n_demos: int = 10,
    seed: int = 0,
    scores=lambda method, demo: True,
):
    """Per-demonstration sums (the comparison's clusters) of methods of the given contact ``skills`` (their
    recall) on the same demonstrations of pick and rotate, per (reference_source, source) scoring; a method
    scores a demonstration only where ``scores(method, k)``."""
    import numpy as np
    import pandas as pd

    rng = np.random.default_rng(seed)
    rows = []
    for reference, source in scorings:
        for task in ("pick", "rotate"):
            for k in range(n_demos):
                for method, skill in skills.items():
                    if not scores(method, k):
                        continue
                    pos = int(rng.integers(20, 80))
                    tp, fp = int(rng.binomial(pos, skill)), int(rng.integers(0, 15))
                    rows.append(
                        {
                            "reference_source": reference,
                            "source": source,
                            "method": method,
                            "task": task,
                            "demonstration": f"{task}-{k}",
                            "tp": tp,
                            "fp": fp,
                            "fn": pos - tp,
                            "tn": 200 - pos - fp,
                            "onset_error_sum_ms": float(rng.uniform(20, 300) * (2 - skill)),
                            "onset_pairs": 8,
                        }
                    )
    return pd.DataFrame(rows)
