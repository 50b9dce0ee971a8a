"""Reliability of the embedded setup (no server): runs that overlap or die.

(a) Two ingest flow runs started together on one data folder both finish, and the
    catalog holds each recording's rows once.
(b) A pipeline run killed with SIGKILL leaves no server process of its own behind, and
    the next run takes the finished tasks from the cache instead of running them again.
(c) The same for the command a user types: `touch2robot ingest` killed with SIGKILL,
    its own pid only (as the OOM killer or `kill -9 <pid>` does), leaves nothing running:
    its Prefect API server dies with it (app.local_server).

Flows run in subprocesses (own session each, killed as a group at the end): Prefect
fixes its settings per process, and (b) needs a process to kill."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import duckdb
import pytest
from conftest import kill_group, live_processes_with_env

from touch2robot.ingest import ingest_file
from touch2robot.synth.config import SynthConfig
from touch2robot.synth.generate import plan, write_recording

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.slow

# The signature of a known defect (a lock in tasks.tracking fixes it): two processes
# opening a fresh MLflow SQLite store both run its Alembic migrations and one of them fails.

RUN_FLOW = """
import json, sys
from flows.{module} import {flow}
result = {flow}(profile="smoke", data=sys.argv[1])
print("RESULT " + json.dumps(result, default=str))
"""


def _one_row(con: duckdb.DuckDBPyConnection, sql: str, params: list | None = None) -> tuple:
    """The row of a query that returns exactly one."""
    row = con.execute(sql, params).fetchone()
    assert row is not None
    return row


def flow_env(data: Path) -> dict[str, str]:
    """The embedded defaults, all under ``data`` (what `touch2robot run` does on a laptop)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PREFECT_", "MLFLOW_"))}
    env.update(
        {
            "TOUCH2ROBOT_DATA": str(data),
            "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
            "PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS": "180",
        }
    )
    return env


def start_flow(module: str, flow: str, data: Path, log: Path) -> subprocess.Popen:
    with open(log, "w") as out:  # the child keeps its own descriptor
        return subprocess.Popen(
            [sys.executable, "-c", RUN_FLOW.format(module=module, flow=flow), str(data)],
            cwd=ROOT,
            env=flow_env(data),
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )


@pytest.fixture
def processes() -> Iterator[list[subprocess.Popen]]:
    """Flow processes a test starts; their groups are killed at the end, pass or fail."""
    started: list[subprocess.Popen] = []
    try:
        yield started
    finally:
        for proc in started:
            kill_group(proc)


def finished(proc: subprocess.Popen, log: Path, timeout_s: float = 600) -> dict:
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        kill_group(proc)
    text = log.read_text()
    lines = [line for line in text.splitlines() if line.startswith("RESULT ")]
    assert proc.returncode == 0 and lines, f"exit {proc.returncode}:\n{text[-6000:]}"
    return json.loads(lines[-1].removeprefix("RESULT "))


def live_processes_with(data: Path) -> list[str]:
    """Live (not zombie) processes whose environment names this data folder."""
    return live_processes_with_env("TOUCH2ROBOT_DATA", str(data))


def survivors_after(data: Path, seconds: float = 15) -> list[str]:
    """The processes naming ``data`` still live after up to ``seconds``: a finished command's
    multiprocessing resource tracker exits a moment after it (it waits for its pipe to close)."""
    deadline = time.monotonic() + seconds
    while (left := live_processes_with(data)) and time.monotonic() < deadline:
        time.sleep(0.2)
    return left


def kill_survivors(data: Path) -> None:
    """SIGKILL what a failed test left running in ``data`` (processes this test started)."""
    for line in live_processes_with(data):
        with contextlib.suppress(ProcessLookupError):
            os.kill(int(line.split(":")[0]), signal.SIGKILL)


def smoke_recordings(data: Path) -> list[Path]:
    """The smoke profile's recordings, written by the library (no flow)."""
    config = SynthConfig(subjects=1, demos_per_subject=1)
    return [write_recording(config, job, data / "recordings", data / "groundtruth") for job in plan(config)]


def rows_per_recording(lake: Path) -> dict[tuple[str, str], int]:
    """(table, recording id) -> rows, over every lake table keyed by recording."""
    con = duckdb.connect()
    try:
        counts = {}
        for table in sorted(p.name for p in lake.iterdir() if p.is_dir()):
            glob = (lake / table).as_posix() + "/**/*.parquet"
            column = "sequence_id" if table == "contacts" else "recording_id"
            for rid, n in con.execute(
                f"SELECT {column}, count(*) FROM read_parquet('{glob}', hive_partitioning = true) GROUP BY 1"
            ).fetchall():
                counts[(table, rid)] = n
        return counts
    finally:
        con.close()


def test_two_concurrent_ingests_on_one_folder(tmp_path: Path, processes: list[subprocess.Popen]) -> None:
    data = tmp_path / "data"
    files = smoke_recordings(data)
    # what one ingest of these files writes, by the library alone
    reference = tmp_path / "reference-lake"
    for path in files:
        ingest_file(path, reference)
    expected = rows_per_recording(reference)

    logs = [tmp_path / "ingest-a.log", tmp_path / "ingest-b.log"]
    processes.extend(start_flow("ingest", "ingest", data, log) for log in logs)
    for proc in processes:
        proc.wait(timeout=600)
    results = [finished(proc, log) for proc, log in zip(processes, logs, strict=True)]

    for result in results:
        assert result["files"] == len(files) and result["quarantined"] == 0
    # every file was ingested by one run or the other (or both: same bytes, same file)
    assert all(r["ingested"] + r["unchanged"] == len(files) for r in results)

    con = duckdb.connect(str(data / "catalog.duckdb"), read_only=True)
    try:
        assert con.execute("SELECT count(*), count(DISTINCT recording_id) FROM recordings").fetchone() == (
            len(files),
            len(files),
        )
        for (table, rid), n in expected.items():
            (got,) = _one_row(con, f"SELECT count(*) FROM {table} WHERE recording_id = ?", [rid])
            assert got == n, f"{table} holds {got} rows of {rid}, one ingest writes {n}"
        total, distinct = _one_row(
            con, "SELECT count(*), count(DISTINCT (source, sequence_id, t, region)) FROM contacts"
        )
        assert total == distinct > 0, "duplicate contact rows"
    finally:
        con.close()
    assert not list((data / "lake").rglob("*.tmp")), "a half-written file was left behind"


def kill_once_results_persist(
    proc: subprocess.Popen, results: Path, log: Path, data: Path, group: bool
) -> dict[str, int]:
    """SIGKILL ``proc`` (its whole process group if ``group``) once a few task results are
    persisted; check nothing of it stays running; the results that were whole at the kill
    (name -> mtime)."""
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and proc.poll() is None:
        if results.is_dir() and len(list(results.iterdir())) >= 3:
            break
        time.sleep(0.1)
    time.sleep(1.5)  # the results counted above are complete files by now
    assert proc.poll() is None, f"the run ended before it could be killed:\n{log.read_text()[-4000:]}"
    if not group:
        assert len(live_processes_with(data)) >= 2, "the command runs with its own API server"
    killed_at = time.time_ns()
    if group:
        os.killpg(proc.pid, signal.SIGKILL)
    else:
        os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    # results older than a second at the kill were whole files; a younger one may be cut short
    done_before = {p.name: p.stat().st_mtime_ns for p in results.iterdir() if p.stat().st_mtime_ns < killed_at - 10**9}
    assert len(done_before) >= 3

    left = survivors_after(data)
    assert not left, f"processes of the killed run survive: {left}"
    return done_before


def test_sigkill_mid_run_leaves_no_server_and_the_rerun_uses_the_cache(
    tmp_path: Path, processes: list[subprocess.Popen]
) -> None:
    data = tmp_path / "data"
    results = data / "prefect" / "results"
    first_log = tmp_path / "first.log"
    first = start_flow("pipeline", "pipeline", data, first_log)
    processes.append(first)

    done_before = kill_once_results_persist(first, results, first_log, data, group=True)

    second_log = tmp_path / "second.log"
    second = start_flow("pipeline", "pipeline", data, second_log)
    processes.append(second)
    result = finished(second, second_log)
    assert result["ingest"]["files"] == 4  # the smoke profile's glove sessions (replays come later, from the twin)

    # the tasks finished before the kill were not run again: their results were not rewritten
    rewritten = [name for name, mtime in done_before.items() if (results / name).stat().st_mtime_ns != mtime]
    assert not rewritten, f"results rewritten by the re-run: {rewritten}"
    cached = second_log.read_text().count("Finished in state Cached(")
    assert cached >= len(done_before), second_log.read_text()[-6000:]
    assert not survivors_after(data), "the finished re-run left processes running"


def test_sigkill_of_the_command_alone_leaves_nothing_running_and_the_rerun_resumes(
    smoke_data: Path, tmp_path: Path, processes: list[subprocess.Popen]
) -> None:
    data = tmp_path / "data"
    shutil.copytree(smoke_data / "recordings", data / "recordings")
    files = len(list((data / "recordings").glob("*.mcap")))
    results = data / "prefect" / "results"
    # --verbose: Prefect's per-task state lines (the cache hits counted below) reach the terminal
    command = [sys.executable, "-m", "app.cli", "--verbose", "ingest", "--data", str(data)]

    def launch(log: Path) -> subprocess.Popen:
        with open(log, "w") as out:
            proc = subprocess.Popen(
                command, cwd=ROOT, env=flow_env(data), stdout=out, stderr=subprocess.STDOUT, start_new_session=True
            )
        processes.append(proc)
        return proc

    try:
        first_log = tmp_path / "first.log"
        first = launch(first_log)
        # the command only, not its process group: its API server must die with it
        done_before = kill_once_results_persist(first, results, first_log, data, group=False)

        second_log = tmp_path / "second.log"
        second = launch(second_log)
        second.wait(timeout=600)
        out = second_log.read_text()
        assert second.returncode == 0, out[-6000:]
        assert not survivors_after(data), "the finished command left processes running"
    finally:
        kill_survivors(data)

    rewritten = [name for name, mtime in done_before.items() if (results / name).stat().st_mtime_ns != mtime]
    assert not rewritten, f"results rewritten by the re-run: {rewritten}"
    assert out.count("Finished in state Cached(") >= len(done_before), out[-6000:]
    con = duckdb.connect(str(data / "catalog.duckdb"), read_only=True)
    try:
        assert con.execute("SELECT count(*), count(DISTINCT recording_id) FROM recordings").fetchone() == (files, files)
        total, distinct = _one_row(
            con, "SELECT count(*), count(DISTINCT (source, sequence_id, t, region)) FROM contacts"
        )
        assert total == distinct > 0, "duplicate contact rows"
    finally:
        con.close()


def test_the_library_code_key_follows_the_code_not_the_checkout_folder(tmp_path: Path) -> None:
    from tasks.common import code_digest

    for clone in ("checkout", "worktree"):
        (tmp_path / clone / "pkg" / "sub").mkdir(parents=True)
        (tmp_path / clone / "pkg" / "__init__.py").write_text("X = 1\n")
        (tmp_path / clone / "pkg" / "sub" / "stage.py").write_text("Y = 2\n")
    here, there = (code_digest(tmp_path / c / "pkg" / "__init__.py") for c in ("checkout", "worktree"))
    assert here == there
    (tmp_path / "worktree" / "pkg" / "sub" / "stage.py").write_text("Y = 3\n")
    assert code_digest(tmp_path / "worktree" / "pkg" / "__init__.py") != here
    (tmp_path / "checkout" / "pkg" / "sub" / "stage.py").rename(tmp_path / "checkout" / "pkg" / "sub" / "other.py")
    assert code_digest(tmp_path / "checkout" / "pkg" / "__init__.py") != here  # a moved file is a code change
