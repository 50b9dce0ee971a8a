"""A re-run of finished work resolves its cache hits in the flow process and starts no process
pool (tasks.runners.ProfileTaskRunner); work that is not cached still runs in the pool. A flow
command uses the Prefect API of a running `touch2robot ui --start` instead of starting one.

Real Prefect in a subprocess (its embedded API, a data folder of its own): Prefect reads its
settings once per process."""

from __future__ import annotations

import http.server
import os
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import pytest
from conftest import run_script_for_result

from app.local_server import UI_API_RECORD, record_ui_api, running_ui_api

ROOT = Path(__file__).resolve().parents[1]

# A module the pool's workers import by name: a fan-out of cached, persisted tasks on a
# processes runner, one of them taking the future of another (as teacher_rollouts takes
# train_teacher's). Every execution of a task body appends "<task> <x> <pid>" to ran.txt.
FAN_OUT = textwrap.dedent(
    """
    import os
    from pathlib import Path

    from prefect import flow, task
    from prefect.context import FlowRunContext

    from tasks.common import cache_policy, stored
    from tasks.runners import ProfileTaskRunner
    from touch2robot.runner_config import RunnerConfig


    def note(data: str, line: str) -> None:
        with open(Path(data, "ran.txt"), "a") as f:
            f.write(f"{line} {os.getpid()}\\n")


    @task(cache_policy=cache_policy())
    def square(x: int, data: str) -> int:
        note(data, f"square {x}")
        return x * x


    @task(cache_policy=cache_policy())
    def plus(squared: int, offset: int, data: str) -> int:
        note(data, f"plus {squared}")
        return squared + offset


    @flow(task_runner=ProfileTaskRunner(RunnerConfig(kind="processes", max_workers=2)))
    def fan_out(xs: list[int], offset: int, data: str) -> dict:
        results = Path(data, "results")
        squares = [stored(square, results).submit(x, data) for x in xs]
        sums = [stored(plus, results).submit(s, offset, data) for s in squares]
        values = [f.result() for f in sums]
        runner = FlowRunContext.get().task_runner
        return {
            "values": values,
            "square_states": [f.state.name for f in squares],
            "plus_states": [f.state.name for f in sums],
            "pool": type(runner.inner).__name__ if runner.inner is not None else None,
            "in_flow_process": runner.cache_hits is not None,
        }
    """
)
RUNS = textwrap.dedent(
    """
    import json, os, sys
    import flows  # configures the environment before Prefect loads its settings
    from fan_out import fan_out

    if __name__ == "__main__":
        data = sys.argv[1]
        ran = os.path.join(data, "ran.txt")
        out = {"flow_pid": os.getpid(), "runs": []}
        for xs, offset in (([1, 2, 3], 1), ([1, 2, 3], 1), ([1, 2, 4], 10)):
            open(ran, "w").close()
            run = fan_out(xs, offset, data)
            run["ran"] = open(ran).read().splitlines()
            out["runs"].append(run)
        print("RESULT " + json.dumps(out))
    """
)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The fan-out run three times on one data folder: first, unchanged, then with a new input
    and a new offset (about a minute: the embedded API, two process pools)."""
    tmp = tmp_path_factory.mktemp("cached_rerun")
    (tmp / "fan_out.py").write_text(FAN_OUT)
    (tmp / "runs.py").write_text(RUNS)
    data = tmp / "data"
    data.mkdir()
    result, _ = run_script_for_result(
        [str(tmp / "runs.py"), str(data)], data, {"PYTHONPATH": os.pathsep.join([str(tmp), str(ROOT)])}
    )
    return result


def _executions(run: dict) -> list[tuple[str, int, int]]:
    return sorted((name, int(x), int(pid)) for name, x, pid in (line.split() for line in run["ran"]))


@pytest.mark.slow
def test_first_run_trains_in_the_pool(runs: dict) -> None:
    first = runs["runs"][0]
    assert first["values"] == [2, 5, 10]
    assert first["pool"] == "ProcessPoolTaskRunner" and not first["in_flow_process"]
    assert first["square_states"] == first["plus_states"] == ["Completed"] * 3
    ran = _executions(first)
    assert [(name, x) for name, x, _ in ran] == [("plus", 1), ("plus", 4), ("plus", 9)] + [
        ("square", x) for x in (1, 2, 3)
    ]
    assert runs["flow_pid"] not in {pid for _, _, pid in ran}


@pytest.mark.slow
def test_an_unchanged_rerun_starts_no_pool_and_returns_the_same(runs: dict) -> None:
    """Every task is a cache hit, the chained ones too: Prefect loads them in the flow process."""
    rerun = runs["runs"][1]
    assert rerun["values"] == runs["runs"][0]["values"]
    assert rerun["pool"] is None and rerun["in_flow_process"]
    assert rerun["square_states"] == rerun["plus_states"] == ["Cached"] * 3
    assert rerun["ran"] == []


@pytest.mark.slow
def test_changed_inputs_still_miss_and_run_in_the_pool(runs: dict) -> None:
    """A new input (4) and a new offset: the squares of 1 and 2 stay cache hits in the flow
    process; the new square and every sum run in the pool, the sums taking the hits' futures
    and, for 16, the future of a square still running in the pool."""
    changed = runs["runs"][2]
    assert changed["values"] == [11, 14, 26]
    assert changed["pool"] == "ProcessPoolTaskRunner" and changed["in_flow_process"]
    assert changed["square_states"] == ["Cached", "Cached", "Completed"]
    assert changed["plus_states"] == ["Completed"] * 3
    ran = _executions(changed)
    assert [(name, x) for name, x, _ in ran] == [("plus", 1), ("plus", 4), ("plus", 16), ("square", 4)]
    assert runs["flow_pid"] not in {pid for _, _, pid in ran}


class _Health(http.server.BaseHTTPRequestHandler):
    def do_GET(self) -> None:
        self.send_response(200 if self.path == "/api/health" else 404)
        self.end_headers()
        self.wfile.write(b"true")

    def log_message(self, *args: object) -> None:
        pass


def test_a_running_ui_server_is_found_and_a_gone_one_is_not(tmp_path: Path) -> None:
    """A flow command uses the Prefect API of the folder's `touch2robot ui --start` only while
    its process runs and the API answers (a UI killed with SIGKILL leaves its record behind)."""
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Health)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    url = f"http://127.0.0.1:{server.server_address[1]}/api"
    try:
        assert running_ui_api(tmp_path) is None  # no record
        record_ui_api(tmp_path, url, os.getpid())
        assert running_ui_api(tmp_path) == url
        gone = subprocess.Popen([sys.executable, "-c", "pass"])
        gone.wait()
        record_ui_api(tmp_path, url, gone.pid)
        assert running_ui_api(tmp_path) is None  # its process is gone
        record_ui_api(tmp_path, f"http://127.0.0.1:{server.server_address[1]}/elsewhere", os.getpid())
        assert running_ui_api(tmp_path) is None  # does not answer
        (tmp_path / UI_API_RECORD).write_text("{")
        assert running_ui_api(tmp_path) is None
    finally:
        server.shutdown()
        server.server_close()
