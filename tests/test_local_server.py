"""app.local_server: the servers the command starts cannot outlive it (real
processes: a parent that spawns a child, killed with SIGKILL) and a stop reaches the
child's own children. The Prefect API server itself is exercised by
tests/test_reliability.py (a killed `touch2robot ingest`)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from app.local_server import StopRequest, answers, free_port, spawn_owned, stop_group

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux only")

# a parent that starts `sleep` the way the command starts its servers, prints the
# child's pid, then waits to be killed
PARENT = textwrap.dedent(
    """
    import sys, time
    from app.local_server import spawn_owned
    child = spawn_owned(["sleep", "600"])
    print(child.pid, flush=True)
    time.sleep(600)
    """
)


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie waiting for its parent to reap it does not)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return False
    return state != "Z"


def wait_gone(pid: int, timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while alive(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    return not alive(pid)


def test_child_dies_when_its_parent_is_killed() -> None:
    parent = subprocess.Popen([sys.executable, "-c", PARENT], stdout=subprocess.PIPE, text=True)
    assert parent.stdout is not None
    child_pid = int(parent.stdout.readline())
    try:
        assert alive(child_pid)
        # a separate group: a group kill of the parent would not reach it, only the kernel does
        assert os.getpgid(child_pid) == child_pid != os.getpgid(parent.pid)
        parent.kill()
        parent.wait()
        assert wait_gone(child_pid), "the child outlived its SIGKILLed parent"
    finally:
        parent.kill()
        parent.wait()
        if alive(child_pid):
            os.kill(child_pid, signal.SIGKILL)


def test_a_stop_request_notes_the_signal_instead_of_raising_and_restores_the_handlers() -> None:
    before = {sig: signal.getsignal(sig) for sig in StopRequest.SIGNALS}
    with StopRequest() as stop:
        assert stop.wait(0.0) is None
        os.kill(os.getpid(), signal.SIGINT)  # no KeyboardInterrupt: Python would raise it here
        started = time.monotonic()
        assert stop.wait(5.0) == signal.SIGINT
        assert time.monotonic() - started < 1.0  # a noted stop does not sleep again
    assert {sig: signal.getsignal(sig) for sig in StopRequest.SIGNALS} == before


def test_stop_reaches_grandchildren_that_ignore_sigterm() -> None:
    # a shell that starts a grandchild ignoring SIGTERM (as MLflow's job workers outlive theirs)
    proc = spawn_owned(["sh", "-c", "trap '' TERM; sleep 600 & echo $!; wait"], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    grandchild = int(proc.stdout.readline())
    assert alive(grandchild)
    started = time.monotonic()
    stop_group(proc, grace_s=1.0)
    assert proc.returncode is not None
    assert wait_gone(grandchild), "the grandchild survived the stop"
    assert time.monotonic() - started < 10


def processes_in(data: Path) -> list[str]:
    """Live processes whose environment names this data folder."""
    marker = f"TOUCH2ROBOT_DATA={data}".encode()
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and int(entry.name) != os.getpid():
            try:
                if marker in (entry / "environ").read_bytes().split(b"\0") and alive(int(entry.name)):
                    found.append(
                        f"{entry.name}: "
                        f"{(entry / 'cmdline').read_bytes().replace(b'\0', b' ')[:160].decode(errors='replace')}"
                    )
            except OSError:
                continue
    return found


@pytest.mark.slow
@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "Ctrl-C"])
def test_ui_start_serves_both_uis_and_a_stop_leaves_nothing_running(tmp_path: Path, stop: signal.Signals) -> None:
    data = tmp_path / "data"
    mlflow_port, prefect_port = free_port(), free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PREFECT_", "MLFLOW_"))}
    env.update(TOUCH2ROBOT_DATA=str(data), PREFECT_SERVER_ANALYTICS_ENABLED="false", PYTHONUNBUFFERED="1")
    command = [
        sys.executable,
        "-m",
        "app.cli",
        "ui",
        "--start",
        "--port",
        str(mlflow_port),
        "--prefect-port",
        str(prefect_port),
    ]
    log = tmp_path / "ui.log"
    with open(log, "w") as out:
        proc = subprocess.Popen(command, env=env, stdout=out, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 240
        while "Ctrl-C stops them" not in log.read_text() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.5)
        assert "Ctrl-C stops them" in log.read_text(), log.read_text()[-4000:]
        assert answers(f"http://127.0.0.1:{mlflow_port}/health") and answers(
            f"http://127.0.0.1:{prefect_port}/api/health"
        )
        assert len(processes_in(data)) >= 3  # the command and at least one process per server
        proc.send_signal(stop)  # a terminal's Ctrl-C reaches the command only: the servers have their own groups
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            pytest.fail(f"the command did not end within 60 s of {stop.name}; its output:\n{log.read_text()[-4000:]}")
        assert "stopping" in log.read_text()
        assert proc.returncode == (0 if stop == signal.SIGINT else 128 + stop), log.read_text()[-4000:]
        deadline = time.monotonic() + 15
        while (left := processes_in(data)) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not left, f"left running after the stop: {left}"
        assert not answers(f"http://127.0.0.1:{mlflow_port}/health")
    finally:
        proc.kill()
        proc.wait()
        for line in processes_in(data):
            os.kill(int(line.split(":")[0]), signal.SIGKILL)


# Prefect's server transaction that reads, meets another writer's commit, then writes: what its event
# persister does beside a task-run creation. Run in its own interpreter: the patch is for the server process.
READ_THEN_WRITE = textwrap.dedent(
    """
    import asyncio, sqlite3, sys
    from pathlib import Path
    from sqlalchemy import text
    from prefect.server.database.configurations import AioSqliteConfiguration

    async def attempt(db):
        config = AioSqliteConfiguration(connection_url=f"sqlite+aiosqlite:///{db}")
        engine = await config.engine()
        try:
            async with await config.session(engine) as session:
                async with config.begin_transaction(session):
                    await session.execute(text("SELECT count(*) FROM t"))
                    other = sqlite3.connect(db, timeout=0)
                    try:
                        other.execute("INSERT INTO t VALUES (1)")
                        other.commit()
                    except sqlite3.OperationalError:
                        pass  # it had to wait: the transaction holds the write lock
                    other.close()
                    await session.execute(text("INSERT INTO t VALUES (2)"))
            return "committed"
        except Exception as e:
            return type(e).__name__ + ": " + str(e).splitlines()[0]
        finally:
            await engine.dispose()

    def fresh(db):
        for p in db.parent.glob(db.name + "*"):
            p.unlink()
        c = sqlite3.connect(db)
        c.execute("PRAGMA journal_mode=WAL")
        c.execute("CREATE TABLE t (x)")
        c.commit()
        c.close()
        return db

    db = Path(sys.argv[1])
    print("prefect:", asyncio.run(attempt(fresh(db))))
    if sys.argv[2] == "patched":
        from app.prefect_api import _immediate_transactions
        _immediate_transactions()
        print("patched:", asyncio.run(attempt(fresh(db))))
    """
)


def test_the_commands_prefect_api_waits_for_another_writer_instead_of_answering_busy(tmp_path: Path) -> None:
    """Prefect's DEFERRED transaction fails at once ('database is locked': the server's 503, then the client's
    2 s back-off); the command's server (app.prefect_api) begins it IMMEDIATE, and it commits."""
    out = subprocess.run(
        [sys.executable, "-c", READ_THEN_WRITE, str(tmp_path / "prefect.db"), "patched"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=Path(__file__).resolve().parents[1],
    )
    assert out.returncode == 0, out.stderr[-3000:]
    assert "prefect: OperationalError: (sqlite3.OperationalError) database is locked" in out.stdout
    assert "patched: committed" in out.stdout


def test_the_commands_api_clients_share_one_tls_context_and_other_users_of_ssl_do_not() -> None:
    """Each Prefect API client built its own TLS context from certifi's bundle (45 ms a client, a client per
    subflow); against the command's plain-http API they share one. In a subprocess: the change is Prefect's."""
    script = """
        import ssl
        import prefect.client.orchestration as orchestration
        from app.cli import _one_tls_context_for_api_clients

        def context(client):
            return client._client._transport._pool._ssl_context

        url = "http://127.0.0.1:1/api"
        assert context(orchestration.SyncPrefectClient(url)) is not context(orchestration.SyncPrefectClient(url))
        _one_tls_context_for_api_clients()
        _one_tls_context_for_api_clients()  # twice: still one layer
        shared = context(orchestration.SyncPrefectClient(url))
        assert context(orchestration.SyncPrefectClient(url)) is shared
        assert context(orchestration.PrefectClient(url)) is shared
        assert ssl.create_default_context() is not ssl.create_default_context()
        print("ok")
    """
    done = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(script)],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=Path(__file__).resolve().parents[1],
    )
    assert done.returncode == 0 and done.stdout.strip().endswith("ok"), done.stderr[-3000:]
