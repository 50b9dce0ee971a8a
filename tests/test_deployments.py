"""prefect.yaml end to end: a real Prefect server and a real MLflow server on 127.0.0.1,
the deployments registered (app/deploy.py), a process
worker that runs the ingest deployment once on demonstrator data, and the ingest run's
record arriving in the MLflow server.

Every server and worker runs in its own process group and the group is killed at the
end, pass or fail (the MLflow server's job workers outlive a SIGTERM of their parent)."""

from __future__ import annotations

import ast
import json
import os
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import yaml

from app.local_server import stop_group
from touch2robot.synth.config import SynthConfig
from touch2robot.synth.generate import plan, write_recording

ROOT = Path(__file__).resolve().parents[1]
POOL = "touch2robot-local"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextmanager
def spawned(cmd: list[str], env: dict[str, str], log: Path, cwd: Path = ROOT) -> Iterator[subprocess.Popen]:
    """A process in its own session (so its group can be killed whole), output to ``log``."""
    with open(log, "w") as out:
        proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
        try:
            yield proc
        finally:
            stop_group(proc)


def wait_http(url: str, proc: subprocess.Popen, log: Path, timeout_s: float = 180.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise AssertionError(f"{proc.args!r:.200} exited with {proc.returncode}:\n{log.read_text()[-4000:]}")
        try:
            with urllib.request.urlopen(url, timeout=2) as r:
                if r.status == 200:
                    return
        except (urllib.error.URLError, ConnectionError, TimeoutError):
            pass
        time.sleep(0.5)
    raise AssertionError(f"{url} not healthy after {timeout_s:.0f} s:\n{log.read_text()[-4000:]}")


def api(base: str, method: str, path: str, body: dict | None = None) -> Any:
    """A Prefect REST call (the test process itself never imports Prefect: its settings
    would be fixed for the rest of the session)."""
    data = json.dumps(body).encode() if body is not None else None
    req = urllib.request.Request(
        f"{base}{path}", data=data, method=method, headers={"Content-Type": "application/json"}
    )
    with urllib.request.urlopen(req, timeout=30) as r:
        return json.loads(r.read() or b"null")


def run_checked(cmd: list[str], env: dict[str, str], timeout_s: float = 300) -> str:
    out = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout_s, check=False)
    assert out.returncode == 0, f"{cmd}\n{out.stdout[-4000:]}\n{out.stderr[-4000:]}"
    return out.stdout


@pytest.fixture
def servers(tmp_path: Path) -> Iterator[dict]:
    """A Prefect server (SQLite in a tmp PREFECT_HOME) and an MLflow server (SQLite +
    artefact folder in tmp), both on free 127.0.0.1 ports, started side by side."""
    prefect_port, mlflow_port = free_port(), free_port()
    base_env = {k: v for k, v in os.environ.items() if not k.startswith(("PREFECT_", "MLFLOW_"))}
    prefect_env = {
        **base_env,
        "PREFECT_HOME": str(tmp_path / "prefect-server"),
        "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
        "PREFECT_UI_ENABLED": "false",
    }
    prefect_cmd = [
        sys.executable,
        "-m",
        "prefect",
        "server",
        "start",
        "--host",
        "127.0.0.1",
        "--port",
        str(prefect_port),
    ]
    mlflow_cmd = [
        sys.executable,
        "-m",
        "mlflow",
        "server",
        "--host",
        "127.0.0.1",
        "--port",
        str(mlflow_port),
        "--workers",
        "1",
        "--backend-store-uri",
        f"sqlite:///{tmp_path / 'mlflow.db'}",
        "--artifacts-destination",
        str(tmp_path / "mlartifacts"),
    ]
    prefect_log, mlflow_log = tmp_path / "prefect-server.log", tmp_path / "mlflow-server.log"
    with (
        spawned(prefect_cmd, prefect_env, prefect_log) as prefect_proc,
        spawned(mlflow_cmd, base_env, mlflow_log, cwd=tmp_path) as mlflow_proc,
    ):
        prefect_api = f"http://127.0.0.1:{prefect_port}/api"
        mlflow_uri = f"http://127.0.0.1:{mlflow_port}"
        wait_http(f"{prefect_api}/health", prefect_proc, prefect_log)
        wait_http(f"{mlflow_uri}/health", mlflow_proc, mlflow_log)
        yield {
            "prefect_api": prefect_api,
            "mlflow_uri": mlflow_uri,
            "env": base_env,
            "pids": [prefect_proc.pid, mlflow_proc.pid],
        }


def tiny_recordings(data: Path) -> list[Path]:
    """One pick demonstration (a glove session)."""
    config = SynthConfig(tasks=("pick",), subjects=1, demos_per_subject=1)
    return [write_recording(config, job, data / "recordings", data / "groundtruth") for job in plan(config)]


def test_prefect_yaml_lists_every_flow() -> None:
    """One deployment entry per flow module, each pointing at a function that exists."""
    config = yaml.safe_load((ROOT / "prefect.yaml").read_text())
    entrypoints = {d["entrypoint"] for d in config["deployments"]}
    flow_modules = {p.name for p in (ROOT / "flows").glob("*.py") if "@flow(" in p.read_text()}
    assert {e.split(":")[0].removeprefix("flows/") for e in entrypoints} == flow_modules
    for entry in entrypoints:
        path, func = entry.split(":")
        assert f"def {func}(" in (ROOT / path).read_text(), entry
    pools = config["definitions"]["work_pools"]
    assert {p["name"] for p in pools.values()} == {"touch2robot-local", "touch2robot-docker"}
    for d in config["deployments"]:
        path, func = d["entrypoint"].split(":")
        tree = ast.parse((ROOT / path).read_text())
        signature = next(n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == func).args
        accepted = {a.arg for a in signature.args + signature.kwonlyargs}
        # every deployment takes a profile and a data folder, and only parameters its flow has
        assert {"profile", "data"} <= set(d["parameters"]) <= accepted, d["entrypoint"]


@pytest.mark.slow
def test_ingest_deployment_runs_on_a_worker_and_tracks_to_mlflow(servers: dict, tmp_path: Path) -> None:
    data = tmp_path / "data"
    files = tiny_recordings(data)
    client_env = {
        **servers["env"],
        "PREFECT_API_URL": servers["prefect_api"],
        "PREFECT_HOME": str(tmp_path / "prefect-client"),
        "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
        "TOUCH2ROBOT_DATA": str(data),
        "MLFLOW_TRACKING_URI": servers["mlflow_uri"],
    }

    # register (creates the pool too); a second time only updates them
    for _ in range(2):
        deployed = run_checked([sys.executable, "-m", "app.deploy", "--pool", POOL], client_env)
    names = {line.split("\t")[0] for line in deployed.splitlines() if "\t" in line}
    flows = {
        d["entrypoint"].rsplit(":", 1)[1] for d in yaml.safe_load((ROOT / "prefect.yaml").read_text())["deployments"]
    }
    assert names == {f"{flow}/local" for flow in flows}
    listed = api(servers["prefect_api"], "POST", "/deployments/filter", {})
    assert sorted(d["name"] for d in listed) == ["local"] * len(names)
    assert {d["work_pool_name"] for d in listed} == {POOL}
    assert api(servers["prefect_api"], "GET", f"/work_pools/{POOL}")["type"] == "process"
    ingest = api(servers["prefect_api"], "GET", "/deployments/name/ingest/local")
    assert ingest["parameters"] == {"profile": "local", "data": None}
    assert ingest["pull_steps"] == [{"prefect.deployments.steps.set_working_directory": {"directory": str(ROOT)}}]

    run = api(
        servers["prefect_api"],
        "POST",
        f"/deployments/{ingest['id']}/create_flow_run",
        {"parameters": {"profile": "smoke", "data": str(data)}},
    )
    worker_log = tmp_path / "worker.log"
    with spawned(
        [sys.executable, "-m", "prefect", "worker", "start", "--pool", POOL, "--run-once"], client_env, worker_log
    ) as worker:
        deadline = time.monotonic() + 400
        state = None
        while time.monotonic() < deadline:
            state = api(servers["prefect_api"], "GET", f"/flow_runs/{run['id']}")["state"]["type"]
            if state in ("COMPLETED", "FAILED", "CRASHED", "CANCELLED") or worker.poll() is not None:
                break
            time.sleep(1)
        worker.wait(timeout=60)  # --run-once: it exits once the run it picked up is over
    state = api(servers["prefect_api"], "GET", f"/flow_runs/{run['id']}")["state"]["type"]
    assert state == "COMPLETED", worker_log.read_text()[-6000:]

    # the flow ran the project's ingest on the given folder...
    import duckdb

    con = duckdb.connect(str(data / "catalog.duckdb"), read_only=True)
    try:
        assert con.execute("SELECT count(*) FROM recordings WHERE status = 'ingested'").fetchone() == (len(files),)
    finally:
        con.close()
    # ...and its MLflow run arrived in the tracking server, artefacts included
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=servers["mlflow_uri"])
    experiment = client.get_experiment_by_name("touch2robot/ingest")
    assert experiment is not None
    runs = client.search_runs([experiment.experiment_id])
    assert len(runs) == 1
    assert runs[0].info.run_name == "ingest-smoke" and runs[0].info.status == "FINISHED"
    assert runs[0].data.metrics["files"] == len(files) and runs[0].data.metrics["quarantined"] == 0
    artifacts = {a.path for a in client.list_artifacts(runs[0].info.run_id)}
    assert {"glove_thresholds.json", "quarantined.json"} <= artifacts
    assert any((tmp_path / "mlartifacts").rglob("glove_thresholds.json"))  # stored by the server, not the client
