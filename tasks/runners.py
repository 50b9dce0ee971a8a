"""Prefect task runners built from a profile's ``runner`` section, so that where the
fan-out runs (threads, processes, a Dask LocalCluster, a lab's Dask scheduler) is
configuration, not a code edit.

``build_task_runner`` turns a :class:`RunnerConfig` into a runner. ``ProfileTaskRunner``
is what a flow puts in its decorator: it builds the real runner when the flow run submits
its first task, from the profile named by the run's ``profile`` parameter, because a
flow's runner is fixed when it is decorated while the profile is only known per run."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterable
from contextlib import AbstractContextManager, nullcontext
from types import TracebackType
from typing import Any, Literal

from prefect.context import FlowRunContext
from prefect.futures import PrefectFuture
from prefect.settings import PREFECT_API_URL, get_current_settings, temporary_settings
from prefect.task_runners import ProcessPoolTaskRunner, TaskRunner, ThreadPoolTaskRunner

from tasks.logs import configure_worker, forward_worker_logs
from touch2robot.config import Profile, load_profile
from touch2robot.runner_config import RunnerConfig


def exit_with_parent(parent: int) -> None:
    """Process-pool worker initializer: the worker ends when the flow process that started it is
    gone. A pool's workers outlive a flow process killed with SIGKILL and would go on training
    unobserved, writing the checkpoints that the re-run resuming from them also writes."""

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


def start_worker(parent: int) -> None:
    """Process-pool worker initializer: ends with the flow process (``exit_with_parent``), logs as
    the command asked (``tasks.logs.configure_worker``)."""
    exit_with_parent(parent)
    configure_worker()


def stop_pool_workers(runner: ProcessPoolTaskRunner, grace_s: float = 30.0) -> None:
    """SIGTERM to a process pool's workers, then SIGKILL to any left after ``grace_s``. For a
    flow run asked to stop (Ctrl-C, SIGTERM): the pool's shutdown waits for running tasks,
    and a training runs for hours. A policy training saves a checkpoint where it is first
    (``tasks.common.checkpoint_on_stop``: one update and the save, seconds on a laptop); the
    others resume from their last one."""
    # A worker that dies while sending to Prefect's message queue holds the queue's write lock for
    # good: the flow process's own last message then never leaves, and joining the queue's feeder
    # thread at exit would hang the command (seen as "Timed out waiting for process-pool message
    # forwarding to stop", then no exit). The stopped workers' last logs are not worth that.
    messages = getattr(runner, "_subprocess_message_queue", None)
    if messages is not None:
        messages.cancel_join_thread()
    executor = runner._executor
    workers = list((getattr(executor, "_processes", None) or {}).values())
    for worker in workers:
        if worker.is_alive():
            worker.terminate()
    deadline = time.monotonic() + grace_s
    for worker in workers:
        worker.join(max(0.0, deadline - time.monotonic()))
        if worker.is_alive():
            worker.kill()
            worker.join()


# the profile section a flow's fan-out follows: ``runner`` for data work, ``training_runner``
# for the stages that train (their runs need a process each, see Profile.training_runner)
RunnerSection = Literal["runner", "training_runner"]


def build_task_runner(config: RunnerConfig) -> TaskRunner[Any]:
    """The Prefect task runner a runner section asks for (not started)."""
    if config.kind == "threads":
        return ThreadPoolTaskRunner(max_workers=config.max_workers)
    if config.kind == "processes":
        return ProcessPoolTaskRunner(
            max_workers=config.max_workers,
            initializer=start_worker,
            initargs=(os.getpid(),),
            subprocess_message_processor_factories=(forward_worker_logs,),
        )
    try:
        from prefect_dask.task_runners import DaskTaskRunner
    except ImportError as e:  # the optional extra is missing
        raise ImportError(
            "runner kind 'dask' needs the dask extra: `uv sync --extra dask` (prefect-dask, distributed)"
        ) from e
    if config.dask_address:
        if not get_current_settings().api.url:
            # workers on other machines cannot reach this process's ephemeral API server
            raise RuntimeError(
                f"runner dask_address={config.dask_address!r} needs a Prefect server that the cluster can reach: "
                "set PREFECT_API_URL (see infra/README.md)"
            )
        return DaskTaskRunner(address=config.dask_address)
    return DaskTaskRunner(
        cluster_class="distributed.LocalCluster",
        cluster_kwargs={
            "n_workers": config.n_workers,
            "threads_per_worker": config.threads_per_worker,
            "processes": True,
            # scheduler and workers listen on loopback only; no dashboard web server
            "host": "127.0.0.1",
            "dashboard_address": None,
        },
    )


def _share_ephemeral_api() -> AbstractContextManager[Any]:
    """Settings under which tasks are handed to worker processes.

    Without PREFECT_API_URL a flow process talks to its own ephemeral API server, and
    the serialized settings that go with each task say "no API URL": every worker
    process (Dask or process pool) would then start an ephemeral server of its own,
    about 20 s each on 2 cores, and record its task runs in it. Naming the flow's
    server for the duration of a submit makes the workers report to it instead."""
    ctx = FlowRunContext.get()
    if get_current_settings().api.url or ctx is None or ctx.client is None:
        return nullcontext()
    return temporary_settings(updates={PREFECT_API_URL: str(ctx.client.api_url)})


class ProfileTaskRunner(TaskRunner[PrefectFuture[Any]]):
    """A task runner that becomes the one the flow run's profile asks for.

    Put ``task_runner=ProfileTaskRunner()`` in a fan-out flow's decorator: at the first
    task submitted in a run it reads the run's ``profile`` parameter, loads that
    profile's ``section`` (``runner``, or ``training_runner`` for the stages that train) and
    starts the runner it describes; the runner is shut down with the flow run. ``config``
    pins a runner regardless of the profile (tests, notebooks). A run without a ``profile``
    parameter gets the section's default."""

    def __init__(
        self, config: RunnerConfig | None = None, parameter: str = "profile", section: RunnerSection = "runner"
    ) -> None:
        super().__init__()
        self._config = config
        self._parameter = parameter
        self._section: RunnerSection = section
        self._inner: TaskRunner[Any] | None = None

    def duplicate(self) -> ProfileTaskRunner:
        return type(self)(self._config, self._parameter, self._section)

    def resolve(self) -> RunnerConfig:
        """The runner section for the current flow run."""
        if self._config is not None:
            return self._config
        ctx = FlowRunContext.get()
        profile = (ctx.parameters or {}).get(self._parameter) if ctx is not None else None
        return getattr(Profile() if profile is None else load_profile(profile), self._section)

    @property
    def inner(self) -> TaskRunner[Any] | None:
        """The runner actually in use (None until the first task is submitted)."""
        return self._inner

    def submit(
        self,
        task: Any,
        parameters: dict[str, Any],
        wait_for: Iterable[PrefectFuture[Any]] | None = None,
        dependencies: dict[str, set[Any]] | None = None,
    ) -> PrefectFuture[Any]:
        if not self._started:
            raise RuntimeError("The task runner must be started before submitting work.")
        if self._inner is None:
            # started lazily: the flow run's parameters exist only once the run is under way
            runner = build_task_runner(self.resolve())
            self.logger.info("fan-out on %s", type(runner).__name__)
            self._inner = runner.__enter__()
        if isinstance(self._inner, ThreadPoolTaskRunner):
            return self._inner.submit(task, parameters, wait_for, dependencies)
        with _share_ephemeral_api():
            return self._inner.submit(task, parameters, wait_for, dependencies)

    def __exit__(
        self, exc_type: type[BaseException] | None, exc_value: BaseException | None, traceback: TracebackType | None
    ) -> None:
        inner, self._inner = self._inner, None
        try:
            # a stop (Ctrl-C, SIGTERM: Prefect's TerminationSignal, SystemExit), not a failed task
            if (
                isinstance(inner, ProcessPoolTaskRunner)
                and exc_type is not None
                and not issubclass(exc_type, Exception)
            ):
                stop_pool_workers(inner)
            if inner is not None:
                inner.__exit__(exc_type, exc_value, traceback)
        finally:
            super().__exit__(exc_type, exc_value, traceback)
