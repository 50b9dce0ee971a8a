"""The fan-out task runner is chosen by configuration (a profile's ``runner`` section).

Anything that imports Prefect runs in a subprocess with its own data folder and Prefect
home: Prefect reads its settings once per process, so an in-process flow run would
leave its environment behind for the rest of the test session."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from conftest import kill_group, live_processes_with_env, run_script_for_result
from pydantic import ValidationError

from touch2robot.runner_config import RunnerConfig

ROOT = Path(__file__).resolve().parents[1]

# Run in a subprocess: builds each kind of runner, then runs tiny flows whose tasks
# report where they ran, and prints one JSON object.
PROBE = textwrap.dedent(
    """
    import json, os, sys
    import flows  # configures the environment before Prefect loads its settings
    from prefect import flow, task
    from prefect.context import FlowRunContext
    from prefect.settings import PREFECT_API_URL, temporary_settings
    from tasks.runners import ProfileTaskRunner, build_task_runner
    from touch2robot.runner_config import RunnerConfig

    @task
    def where(i: int) -> dict:
        import distributed
        worker = distributed.get_worker()
        return {"i": i, "pid": os.getpid(), "worker": worker.address}

    @flow(task_runner=ProfileTaskRunner(RunnerConfig(kind="dask", n_workers=2)))
    def fan_out(n: int) -> dict:
        results = [f.result() for f in where.map(range(n))]
        runner = FlowRunContext.get().task_runner.inner
        workers = sorted(runner.client.scheduler_info()["workers"])
        return {"results": results, "cluster_workers": workers, "runner": type(runner).__name__}

    @task
    def noop(i: int = 0) -> int:
        return os.getpid()

    @flow(task_runner=ProfileTaskRunner())
    def by_profile(profile: str) -> dict:
        pid = noop.submit().result()
        runner = FlowRunContext.get().task_runner.inner
        return {"runner": type(runner).__name__, "max_workers": getattr(runner, "_max_workers", None), "pid": pid}

    @flow(task_runner=ProfileTaskRunner(section="training_runner"))
    def trains(profile: str) -> dict:
        pids = [f.result() for f in noop.map(range(2))]
        runner = FlowRunContext.get().task_runner.inner
        return {"runner": type(runner).__name__, "max_workers": getattr(runner, "_max_workers", None), "pids": pids}

    def main() -> None:
        out = {"flow_pid": os.getpid()}
        threads = build_task_runner(RunnerConfig(kind="threads", max_workers=3))
        processes = build_task_runner(RunnerConfig(kind="processes", max_workers=2))
        local = build_task_runner(RunnerConfig(kind="dask", n_workers=3))
        out["built"] = {
            "threads": [type(threads).__name__, threads._max_workers],
            "processes": [type(processes).__name__, processes._max_workers],
            "dask_local": [type(local).__name__, local.cluster_kwargs],
        }
        try:
            build_task_runner(RunnerConfig(kind="dask", dask_address="tcp://scheduler:8786"))
            out["remote_without_server"] = "built"
        except RuntimeError as e:
            out["remote_without_server"] = str(e)
        with temporary_settings(updates={PREFECT_API_URL: "http://127.0.0.1:4200/api"}):
            remote = build_task_runner(RunnerConfig(kind="dask", dask_address="tcp://scheduler:8786"))
            out["remote"] = [type(remote).__name__, remote.address]
        out["dask"] = fan_out(6)
        out["by_profile"] = by_profile(sys.argv[1])
        out["trains"] = trains(sys.argv[1])
        print("RESULT " + json.dumps(out))

    # Dask starts its workers with the spawn method, which re-imports this script
    if __name__ == "__main__":
        main()
    """
)


@pytest.fixture(scope="module")
def probe(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """Run PROBE once (about a minute: Prefect's embedded API and a LocalCluster start)."""
    tmp = tmp_path_factory.mktemp("runners")
    script = tmp / "probe.py"
    script.write_text(PROBE)
    profile = str(tmp / "threads3.yaml")
    Path(profile).write_text(
        "name: threads3\nrunner:\n  kind: threads\n  max_workers: 3\ntraining_runner:\n  max_workers: 2\n"
    )
    result, output = run_script_for_result([str(script), profile], tmp / "data")
    result["log"] = output
    return result


def test_runner_config_defaults_and_validation() -> None:
    assert RunnerConfig() == RunnerConfig(kind="threads", max_workers=None, dask_address=None, n_workers=2)
    assert (
        RunnerConfig.model_validate({"kind": "dask", "dask_address": "tcp://10.0.0.5:8786"}).dask_address
        == "tcp://10.0.0.5:8786"
    )
    with pytest.raises(ValidationError, match="only used with kind 'dask'"):
        RunnerConfig(kind="threads", dask_address="tcp://scheduler:8786")
    with pytest.raises(ValidationError, match="needs a scheme"):
        RunnerConfig(kind="dask", dask_address="scheduler:8786")
    with pytest.raises(ValidationError):
        RunnerConfig.model_validate({"kind": "ray"})
    with pytest.raises(ValidationError):
        RunnerConfig.model_validate({"kind": "threads", "workers": 2})  # unknown keys are errors
    with pytest.raises(ValidationError):
        RunnerConfig(n_workers=0)


def test_a_thread_pool_without_a_size_has_one_thread_per_cpu() -> None:
    """Prefect's own default is unbounded: every task of a fan-out at once."""
    from prefect.task_runners import ProcessPoolTaskRunner, ThreadPoolTaskRunner

    from tasks.runners import build_task_runner

    threads, processes = (
        build_task_runner(RunnerConfig(kind="threads")),
        build_task_runner(RunnerConfig(kind="processes")),
    )
    assert isinstance(threads, ThreadPoolTaskRunner) and isinstance(processes, ProcessPoolTaskRunner)
    assert threads._max_workers == processes._max_workers == os.cpu_count()


@pytest.mark.slow
def test_build_task_runner_per_kind(probe: dict) -> None:
    built = probe["built"]
    assert built["threads"] == ["ThreadPoolTaskRunner", 3]
    assert built["processes"] == ["ProcessPoolTaskRunner", 2]
    name, kwargs = built["dask_local"]
    assert name == "DaskTaskRunner"
    assert kwargs["n_workers"] == 3 and kwargs["processes"] is True
    assert kwargs["host"] == "127.0.0.1" and kwargs["dashboard_address"] is None  # nothing listens beyond loopback
    assert probe["remote"] == ["DaskTaskRunner", "tcp://scheduler:8786"]
    assert "PREFECT_API_URL" in probe["remote_without_server"]  # a cluster cannot reach an embedded API


@pytest.mark.slow
def test_fan_out_runs_on_dask_workers(probe: dict) -> None:
    dask = probe["dask"]
    assert dask["runner"] == "DaskTaskRunner"
    results = dask["results"]
    assert sorted(r["i"] for r in results) == list(range(6))
    assert len(dask["cluster_workers"]) == 2
    assert {r["worker"] for r in results} <= set(dask["cluster_workers"])
    assert all(r["pid"] != probe["flow_pid"] for r in results)  # not in the flow's process
    # the workers reported to the flow's embedded API instead of each starting its own
    assert probe["log"].count("Starting temporary server") == 1


@pytest.mark.slow
def test_profile_names_the_runner(probe: dict) -> None:
    assert probe["by_profile"]["runner"] == "ThreadPoolTaskRunner"
    assert probe["by_profile"]["max_workers"] == 3
    assert probe["by_profile"]["pid"] == probe["flow_pid"]


@pytest.mark.slow
def test_trainings_run_in_worker_processes(probe: dict) -> None:
    """The training stages' section: a process pool by default (torch's RNG is per process)."""
    assert probe["trains"]["runner"] == "ProcessPoolTaskRunner"
    assert probe["trains"]["max_workers"] == 2
    assert probe["flow_pid"] not in probe["trains"]["pids"]


CHECKPOINT_ON_STOP = textwrap.dedent(
    """
    import os, signal, threading, time
    from tasks.common import checkpoint_on_stop

    checks = []

    def in_a_thread() -> None:
        with checkpoint_on_stop() as stop_requested:
            checks.append(stop_requested())

    thread = threading.Thread(target=in_a_thread)
    thread.start()
    thread.join()
    print("thread", checks, flush=True)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    with checkpoint_on_stop() as stop_requested:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.2)
        print("ignored SIGINT", stop_requested(), flush=True)
        os.kill(os.getpid(), signal.SIGTERM)
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.2)
        print("SIGTERM twice", stop_requested(), flush=True)
        print("checkpoint", flush=True)
    print("went on", flush=True)
    """
)


def test_a_training_asked_to_stop_checkpoints_then_stops_as_asked() -> None:
    """checkpoint_on_stop: the first SIGTERM turns the check true and the second waits for the
    checkpoint too; leaving the block delivers SIGTERM as before (the process ends with it). An
    ignored signal stays ignored, and off the main thread the check stays false."""
    proc = subprocess.run(
        [sys.executable, "-c", CHECKPOINT_ON_STOP], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert proc.stdout.splitlines() == ["thread [False]", "ignored SIGINT False", "SIGTERM twice True", "checkpoint"], (
        proc.stderr[-3000:]
    )
    assert proc.returncode == -signal.SIGTERM, proc.stderr[-3000:]


# Two long "trainings" in a process pool, each writing its worker's pid once it has started;
# the second one saves a "checkpoint" when its process is asked to stop, as the policy's does.
LONG_TRAININGS = textwrap.dedent(
    """
    import os, time
    from pathlib import Path
    from prefect import flow, task
    from tasks.common import checkpoint_on_stop
    from tasks.runners import ProfileTaskRunner
    from touch2robot.runner_config import RunnerConfig

    @task
    def long_training(folder: str, i: int) -> None:
        if i == 0:
            Path(folder, f"{os.getpid()}.pid").write_text(str(i))
            time.sleep(900)
            return
        with checkpoint_on_stop() as stop_requested:
            Path(folder, f"{os.getpid()}.pid").write_text(str(i))
            while not stop_requested():
                time.sleep(0.1)
            time.sleep(2.0)  # the checkpoint takes a while to write
            Path(folder, "checkpoint").write_text(str(os.getpid()))
        Path(folder, "went-on").write_text("the stop signal did not end the training's process")

    @flow(task_runner=ProfileTaskRunner(RunnerConfig(kind="processes", max_workers=2)))
    def trains(folder: str) -> None:
        for f in long_training.map(folder, range(2)):
            f.result()
    """
)
# ...run as the CLI runs a flow: its own API server, SIGTERM handled (app.cli)
RUN_AS_CLI = textwrap.dedent(
    """
    import sys
    from pathlib import Path
    from app.cli import _layout, _run_flow

    if __name__ == "__main__":  # the pool's workers (spawned) import this script again
        _layout(Path(sys.argv[1]))
        sys.path.insert(0, sys.argv[2])
        _run_flow("long_trainings:trains", type(None), folder=sys.argv[3])
    """
)


def test_a_stopped_flow_run_stops_its_trainings_instead_of_waiting_for_them(tmp_path: Path) -> None:
    """SIGTERM to the flow's command alone (a supervisor, ``kill``): the process pool's shutdown
    would wait for the running trainings, hours on a laptop. The workers are stopped instead, a
    training that checkpoints on a stop (the policy's) does so first, the command ends with
    status 128 + 15 and leaves nothing running (its API server neither)."""
    (tmp_path / "long_trainings.py").write_text(LONG_TRAININGS)
    (tmp_path / "run.py").write_text(RUN_AS_CLI)
    started = tmp_path / "started"
    started.mkdir()
    marker = str(tmp_path)
    env = {**os.environ, "PREFECT_SERVER_ANALYTICS_ENABLED": "false", "TOUCH2ROBOT_TEST_MARKER": marker}
    env.pop("PREFECT_API_URL", None)
    log = tmp_path / "flow.log"
    with open(log, "w") as out:
        proc = subprocess.Popen(
            [sys.executable, str(tmp_path / "run.py"), str(tmp_path / "data"), str(tmp_path), str(started)],
            cwd=ROOT,
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    try:
        deadline = time.monotonic() + 300
        while len(list(started.glob("*.pid"))) < 2 and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.5)
        assert len(list(started.glob("*.pid"))) == 2, log.read_text()[-6000:]
        workers = sorted(int(p.stem) for p in started.glob("*.pid"))

        proc.send_signal(signal.SIGTERM)  # the command only, not its process group
        try:
            proc.wait(timeout=90)
        except subprocess.TimeoutExpired:
            pytest.fail(f"the flow run did not end within 90 s of SIGTERM; its log:\n{log.read_text()[-6000:]}")
        assert proc.returncode == 128 + signal.SIGTERM, log.read_text()[-6000:]
        deadline = time.monotonic() + 15
        while (left := live_processes_with_env("TOUCH2ROBOT_TEST_MARKER", marker)) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not left, f"still running after the command ended (the workers were {workers}): {left}"
        checkpointing = next(p.stem for p in started.glob("*.pid") if p.read_text() == "1")
        assert (started / "checkpoint").read_text() == checkpointing, "the training that checkpoints on a stop did not"
        assert not (started / "went-on").exists()
    finally:
        kill_group(proc)
