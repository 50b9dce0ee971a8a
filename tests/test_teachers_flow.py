"""The teachers flow end to end through Prefect: rollouts and sim contacts in the catalog, one
MLflow run per task x method with its reward terms and checkpoints, cache hits on a re-run, and
a training killed with SIGKILL that resumes from its last checkpoint."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import live_processes_with_env
from mlflow.tracking import MlflowClient

from tasks import tracking
from touch2robot import catalog
from touch2robot.settings import DataLayout

REPO = Path(__file__).resolve().parents[1]


def test_teachers_flow_writes_rollouts_contacts_and_mlflow_runs(demo_lake: Path, tmp_path: Path) -> None:
    from flows.teachers import teachers

    root = tmp_path / "data"
    shutil.copytree(demo_lake, root)
    layout = DataLayout(root)
    rows = teachers(profile="smoke", data=str(root), tasks=["wipe"], methods=["touch2robot"])
    assert {(r["task"], r["method"], r["origin"]) for r in rows} == {
        ("wipe", "touch2robot", "teacher"),
        ("wipe", "dex-retargeting", "kinematic"),
    }
    counts = catalog.query(
        layout,
        "SELECT method, origin, count(DISTINCT rollout_id) AS n, bool_and(t_ref >= 0) AS clocked FROM rollouts GROUP "
        "BY ALL ORDER BY method",
    ).to_pylist()
    assert counts == [
        {"method": "dex-retargeting", "origin": "kinematic", "n": 1, "clocked": True},
        {"method": "touch2robot", "origin": "teacher", "n": 2, "clocked": True},  # smoke: rollouts_per_task 2
    ]
    sim = catalog.query(
        layout, "SELECT method, count(*) AS n FROM contacts WHERE source = 'sim' GROUP BY ALL ORDER BY method"
    ).to_pylist()
    assert [r["method"] for r in sim] == ["dex-retargeting", "touch2robot"]

    teacher = next(r for r in rows if r["origin"] == "teacher")
    uri = tracking.tracking_uri(layout)
    run = MlflowClient(uri).get_run(teacher["mlflow_run"])
    assert {
        "reward/tactile",
        "reward/object_pos",
        "reward/imitation",
        "Loss/learning_rate",
        "rollouts/contact_f1",
    } <= set(run.data.metrics)
    assert run.data.params["ppo.gamma"] == "0.96" and run.data.params["method.rewards.tactile"] == "1.0"
    assert any(a.path.endswith(".pt") for a in MlflowClient(uri).list_artifacts(run.info.run_id, "checkpoints"))

    from flows.evaluate import evaluate

    evaluate(profile="smoke", data=str(root))  # the sim contacts are scored like any other source
    f1 = catalog.query(
        layout,
        "SELECT method, f1 FROM contact_metrics WHERE source = 'sim' AND task = 'wipe' AND region = '*' ORDER BY "
        "method",
    ).to_pylist()
    assert [r["method"] for r in f1] == ["dex-retargeting", "touch2robot"] and all(0 <= r["f1"] <= 1 for r in f1)
    assert abs(f1[1]["f1"] - teacher["contact_f1"]) <= 5e-4  # the flow's figure (3 decimals) is the evaluation's

    checkpoints = sorted(layout.checkpoints.rglob("model_*.pt"))
    before = {p: p.stat().st_mtime_ns for p in checkpoints}
    again = teachers(profile="smoke", data=str(root), tasks=["wipe"], methods=["touch2robot"])
    assert again == rows
    assert {
        p: p.stat().st_mtime_ns for p in sorted(layout.checkpoints.rglob("model_*.pt"))
    } == before  # nothing retrained


PROFILE = """
name: kill-test
teacher:
  sim: {n_envs: 8}
  ppo: {num_steps_per_env: 16, max_iterations: 40, hidden_dims: [32, 32], save_interval: 2}
  rollouts_per_task: 1
"""


@pytest.mark.slow
def test_killed_training_resumes_from_its_last_checkpoint(demo_lake: Path, tmp_path: Path) -> None:
    root = tmp_path / "data"
    shutil.copytree(demo_lake, root)
    profile = tmp_path / "kill-test.yaml"
    profile.write_text(PROFILE)
    layout = DataLayout(root)
    command = [
        sys.executable,
        "-m",
        "app.cli",
        "teachers",
        "--profile",
        str(profile),
        "--data",
        str(root),
        "--task",
        "wipe",
        "--method",
        "touch2robot",
    ]
    env = {**os.environ, "PREFECT_HOME": str(tmp_path / "prefect")}
    first = subprocess.Popen(command, cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while not list(layout.checkpoints.rglob("model_4.pt")):
        assert first.poll() is None, "the flow ended before it was killed"
        assert time.monotonic() < deadline, "no checkpoint within 5 minutes"
        time.sleep(0.5)
    first.send_signal(signal.SIGKILL)
    first.wait()
    # the training ran in a process-pool worker: it must end with the flow, not train on unobserved
    deadline = time.monotonic() + 15
    while (left := live_processes_with_env("PREFECT_HOME", env["PREFECT_HOME"])) and time.monotonic() < deadline:
        time.sleep(0.5)
    assert not left, f"still running after the flow process was killed: {left}"
    folder = next(layout.checkpoints.rglob("model_4.pt")).parent
    done = {p.name for p in folder.glob("model_*.pt")}
    assert "model_38.pt" not in done and "model_39.pt" not in done

    second = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert second.returncode == 0, second.stderr[-3000:]
    assert "resumed at iteration" in second.stdout + second.stderr
    assert done <= {p.name for p in folder.glob("model_*.pt")} and (folder / "model_39.pt").is_file()
    run_id = (folder / "mlflow_run.json").read_text().split('"run_id": "')[1].split('"')[0]
    history = MlflowClient(tracking.tracking_uri(layout)).get_metric_history(run_id, "Loss/learning_rate")
    steps = [m.step for m in history]
    assert steps.count(0) == 1  # not started over: iteration 0 ran once
    assert set(steps) == set(range(40))
    assert catalog.query(
        layout, "SELECT count(DISTINCT rollout_id) AS n FROM rollouts WHERE origin = 'teacher'"
    ).to_pylist() == [{"n": 1}]
