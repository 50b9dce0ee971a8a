"""Servers that the ``touch2robot`` command starts for itself (a Prefect API for its flow
runs, the Prefect and MLflow UIs) as child processes that cannot outlive it.

Without PREFECT_API_URL, Prefect starts a temporary API server as a plain subprocess
and stops it at interpreter exit; a run killed with SIGKILL (an out-of-memory kill, a
scheduler's kill -9) leaves that server running. The command starts the same server
itself instead, so that:

- the server dies with the command, whatever kills it: on Linux the kernel sends it
  SIGKILL when its parent ends (prctl PR_SET_PDEATHSIG);
- it has its own process group, so a normal stop (SIGTERM to the group, then SIGKILL)
  reaches everything it started, and a terminal's Ctrl-C reaches only the command,
  which then stops it;
- it starts while the command is still importing the flows (about half the start-up of
  a run is that import), and it listens on a free port of 127.0.0.1 only.

The API is Prefect's own app (``prefect.server.api.server:create_app`` under uvicorn,
what Prefect's temporary server runs, by way of ``app.prefect_api``) on the data folder's
Prefect database. This module only spawns processes and speaks HTTP: it does not import Prefect."""

from __future__ import annotations

import contextlib
import ctypes
import json
import logging
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import IO, Any

_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
_UVICORN_STARTUP_FAILURE = 3  # uvicorn's exit status when it cannot bind its port


# what ``signal.signal`` takes and returns (typeshed's private ``signal._HANDLER``)
type SignalHandler = Callable[[int, FrameType | None], Any] | int | signal.Handlers | None


logger = logging.getLogger(__name__)


class ServerFailed(RuntimeError):
    """A server the command started exited or did not answer in time."""


def _die_with(parent_pid: int) -> Callable[[], None] | None:
    """A ``preexec_fn`` that makes the child receive SIGKILL when its parent dies (Linux;
    elsewhere there is no such call and only a normal stop ends the child)."""
    if not sys.platform.startswith("linux"):
        return None
    libc = ctypes.CDLL(None, use_errno=True)  # resolved here: the child only makes the call

    def preexec() -> None:
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
        if os.getppid() != parent_pid:  # the parent died before the call: nobody will signal
            os._exit(1)

    return preexec


def spawn_owned(
    cmd: Sequence[str],
    env: Mapping[str, str] | None = None,
    *,
    stdout: int | IO[Any] | None = None,
    stderr: int | IO[Any] | None = None,
    text: bool | None = None,
) -> subprocess.Popen:
    """Start ``cmd`` in its own process group, killed by the kernel if this process dies; ``stdout``,
    ``stderr`` and ``text`` as for ``subprocess.Popen``."""
    return subprocess.Popen(
        list(cmd),
        env=dict(env) if env is not None else None,
        start_new_session=True,
        preexec_fn=_die_with(os.getpid()),
        stdout=stdout,
        stderr=stderr,
        text=text,
    )


def stop_group(proc: subprocess.Popen, grace_s: float = 5.0) -> None:
    """SIGTERM the child's process group, SIGKILL it after ``grace_s``, then once more
    for grandchildren that outlived their parent (MLflow's job workers do); reaps the child."""
    for sig, wait_s in ((signal.SIGTERM, grace_s), (signal.SIGKILL, 5.0)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            break
        try:
            proc.wait(timeout=wait_s)
            break
        except subprocess.TimeoutExpired:
            continue
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def answers(url: str, timeout_s: float = 2.0) -> bool:
    try:
        with urllib.request.urlopen(url, timeout=timeout_s) as response:
            return response.status == 200
    except (urllib.error.URLError, ConnectionError, TimeoutError):
        return False


@dataclass
class PrefectApi:
    """A Prefect API server process of this command (see the module docstring)."""

    env: dict[str, str]
    process: subprocess.Popen | None = None
    port: int = 0
    started_at: float = 0.0  # time.monotonic() at the spawn
    output: str | None = None  # the file its output goes to (None: this command's terminal)

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}/api"

    def start(self) -> PrefectApi:
        """Spawn the server; returns at once (``wait_ready`` waits for it)."""
        self.port = free_port()
        cmd = [
            sys.executable,
            "-m",
            "uvicorn",
            "--factory",
            "app.prefect_api:create_app",  # Prefect's app, write transactions IMMEDIATE (that module says why)
            "--host",
            "127.0.0.1",
            "--port",
            str(self.port),
            "--log-level",
            "error",
            "--lifespan",
            "on",
        ]
        # Prefect's own settings for its temporary server: no UI, only the services a
        # short-lived server needs, one app per process
        env = {**self.env, "PREFECT_UI_ENABLED": "0", "PREFECT__SERVER_EPHEMERAL": "1", "PREFECT__SERVER_FINAL": "1"}
        self.started_at = time.monotonic()
        from tasks.logs import LOG_FILE_ENV, VERBOSE_ENV

        log_file = env.get(LOG_FILE_ENV)
        if log_file and env.get(VERBOSE_ENV) != "1":
            # its shutdown's cancelled database calls are the server's business: the run's log, not the terminal
            self.output = log_file
            with open(log_file, "a") as log:
                self.process = spawn_owned(cmd, env, stdout=log, stderr=subprocess.STDOUT)
        else:
            self.process = spawn_owned(cmd, env)
        return self

    def wait_ready(self, timeout_s: float) -> str:
        """Wait until the API answers its health check; returns its URL. A port taken
        between choosing and binding it is retried on another one."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            assert self.process is not None, "start() first"
            status = self.process.poll()
            if status == _UVICORN_STARTUP_FAILURE:
                self.start()
            elif status is not None:
                where = f"in {self.output}" if self.output else "above"
                raise ServerFailed(f"the Prefect API server exited with status {status} (its output is {where})")
            elif answers(f"{self.url}/health"):
                # the figure bench/rerun.py reads: what a cached re-run spends before any flow can start
                logger.info("Prefect API answered %.1f s after its start", time.monotonic() - self.started_at)
                return self.url
            time.sleep(0.2)
        self.stop()
        raise ServerFailed(
            f"the Prefect API server did not answer within {timeout_s:.0f} s; raise "
            "PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS on a slow machine"
        )

    def stop(self) -> None:
        if self.process is not None:
            stop_group(self.process)
            self.process = None


# beside the Prefect database (PREFECT_HOME of the data folder): the API of a running
# ``touch2robot ui --start``, which the folder's flow commands use instead of starting one
UI_API_RECORD = "ui-api.json"


def record_ui_api(prefect_home: Path, url: str, pid: int) -> Path:
    """Note the API ``url`` of the UI's Prefect server (process ``pid``) for the folder's commands."""
    path = prefect_home / UI_API_RECORD
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps({"url": url, "pid": pid}))
    os.replace(tmp, path)
    return path


def running_ui_api(prefect_home: Path) -> str | None:
    """The API URL of the UI's Prefect server on this folder's database when it still runs and
    answers, else None. A UI killed with SIGKILL leaves its record: its server died with it."""
    try:
        record = json.loads((prefect_home / UI_API_RECORD).read_text())
        url, pid = str(record["url"]), int(record["pid"])
        os.kill(pid, 0)
    except (OSError, ValueError, KeyError, TypeError):  # no record, a bad one, or its process is gone
        return None
    return url if answers(f"{url}/health", timeout_s=1.0) else None


@contextmanager
def stop_on_termination() -> Iterator[None]:
    """Within the block, SIGTERM and SIGHUP raise SystemExit (Python's default is to die
    at once, skipping ``finally``), so the servers the block started are stopped."""

    def on_signal(signum: int, _frame: object) -> None:
        raise SystemExit(128 + signum)

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGTERM, signal.SIGHUP)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


class StopRequest:
    """Ctrl-C (SIGINT), SIGTERM and SIGHUP, noted instead of raised, for a command whose
    main thread only watches its servers. An exception raised wherever the signal lands can
    land inside ``Popen.poll`` after it took the child's wait lock and before the ``try`` that
    releases it; the stop's ``wait()`` then blocks for ever. The handler only sets an
    attribute (taking a lock there could deadlock with the code it interrupted)."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

    def __init__(self) -> None:
        self.signum: int | None = None
        self._previous: dict[int, SignalHandler] = {}

    def _note(self, signum: int, _frame: object) -> None:
        self.signum = signum

    def wait(self, timeout_s: float) -> int | None:
        """Sleep ``timeout_s`` unless a stop came; the signal that asked for it, or None."""
        if self.signum is None:
            time.sleep(timeout_s)  # a signal does not cut it short (PEP 475): at most this late
        return self.signum

    def __enter__(self) -> StopRequest:
        self._previous = {sig: signal.signal(sig, self._note) for sig in self.SIGNALS}
        return self

    def __exit__(self, *_exc: object) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
