"""Prefect task runners built from a profile's ``runner`` section, so that where the
fan-out runs (threads, processes, a Dask LocalCluster, a lab's Dask scheduler) is
configuration, not a code edit.

``build_task_runner`` turns a :class:`RunnerConfig` into a runner. ``ProfileTaskRunner``
is what a flow puts in its decorator: it builds the real runner when the flow run submits
its first task, from the profile named by the run's ``profile`` parameter, because a
flow's runner is fixed when it is decorated while the profile is only known per run.

A task whose result the cache already holds runs in the flow process instead (``cached_result_exists``):
a re-run of finished work then starts no process pool or cluster, whose workers would import torch,
LeRobot and MuJoCo (about 10 s on 2 cores) only to load a stored result."""

from __future__ import annotations

import os
import threading
import time
import uuid
from collections.abc import Callable, Iterable
from contextlib import AbstractContextManager, nullcontext
from types import TracebackType
from typing import Any, Literal

from prefect.cache_policies import CachePolicy
from prefect.client.schemas.objects import TaskRun
from prefect.context import FlowRunContext, TaskRunContext
from prefect.filesystems import NullFileSystem
from prefect.futures import PrefectFuture, PrefectWrappedFuture
from prefect.results import get_result_store
from prefect.settings import PREFECT_API_URL, PREFECT_TASKS_REFRESH_CACHE, get_current_settings, temporary_settings
from prefect.task_runners import ProcessPoolTaskRunner, TaskRunner, ThreadPoolTaskRunner
from prefect.utilities.collections import visit_collection
from prefect.utilities.engine import resolve_to_final_result

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
        # Prefect's own default is unbounded: a retarget of 24 recordings ran as 24 threads, and their
        # MLflow logging ran out of its 15 pooled connections (QueuePool timeouts, then retries)
        return ThreadPoolTaskRunner(max_workers=config.max_workers or os.cpu_count())
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


class _NotReady(Exception):
    """A parameter waits on a task run that is not finished where this process can see it."""


def resolve_now(
    parameters: dict[str, Any],
    wait_for: Iterable[PrefectFuture[Any]] | None,
    ready: Callable[[PrefectFuture[Any]], bool],
) -> dict[str, Any] | None:
    """The parameters as Prefect's task engine resolves them before it computes a cache key
    (``SyncTaskRunEngine._resolve_parameters``: futures and states to their results, annotations
    removed), or None when that would wait on a future that is not ``ready``, on a ``wait_for``
    that is not, or when the engine would stop at an upstream that did not complete."""
    for future in wait_for or ():
        if not ready(future):
            return None

    def resolve(expr: Any, context: dict[str, Any]) -> Any:
        if isinstance(expr, PrefectFuture) and not ready(expr):
            raise _NotReady
        return resolve_to_final_result(expr, context)

    try:
        return {
            name: visit_collection(
                value,
                visit_fn=resolve,
                return_data=True,
                max_depth=-1,
                remove_annotations=True,
                context={"parameter_name": name},
            )
            for name, value in parameters.items()
        }
    except Exception:  # _NotReady, or an upstream the engine would report: the submission as before
        return None


def cached_result_exists(task: Any, parameters: dict[str, Any]) -> bool:
    """Whether a run of ``task`` on these resolved ``parameters`` in the current flow run would
    be a cache hit: the key its cache policy gives (with ``cache_key_fn``, the policy Prefect made of
    it) is in the task's result store and not expired, and no ``refresh_cache`` asks to overwrite
    it. This is ``SyncTaskRunEngine.compute_transaction_key`` and ``Transaction.begin``, on a task run
    context that only this check sees (no task run is created). A key that cannot be computed, or a
    task without a cache policy, counts as a miss."""
    ctx = FlowRunContext.get()
    policy = task.cache_policy
    refresh = task.refresh_cache if task.refresh_cache is not None else PREFECT_TASKS_REFRESH_CACHE.value()
    if ctx is None or ctx.flow_run is None or not isinstance(policy, CachePolicy) or refresh:
        return False
    # async_dispatch picks the async variant inside the flow's event loop unless told _sync (untyped kwarg)
    store = get_result_store().update_for_task(task, _sync=True)  # pyright: ignore[reportCallIssue]
    task_run = TaskRun(
        id=uuid.uuid4(),
        name=task.name,
        flow_run_id=ctx.flow_run.id,
        task_key=task.task_key,
        dynamic_key="cache-check",
        task_version=task.version,
    )
    try:
        task_ctx = TaskRunContext(
            task=task, task_run=task_run, parameters=parameters, result_store=store, client=ctx.client
        )
        key = policy.compute_key(task_ctx=task_ctx, inputs=parameters, flow_parameters=ctx.parameters or {})
    except Exception:  # the engine logs it and persists nothing: it will not find a record either
        return False
    if not key:
        return False
    # as ``prefect.transactions.transaction`` does: a flow's null metadata storage is not inherited
    if isinstance(store.metadata_storage, NullFileSystem):
        store = store.model_copy(update={"metadata_storage": None})
    return store.exists(key=key)


class ProfileTaskRunner(TaskRunner[PrefectFuture[Any]]):
    """A task runner that becomes the one the flow run's profile asks for.

    Put ``task_runner=ProfileTaskRunner()`` in a fan-out flow's decorator: at the first
    task submitted in a run it reads the run's ``profile`` parameter, loads that
    profile's ``section`` (``runner``, or ``training_runner`` for the stages that train) and
    starts the runner it describes; the runner is shut down with the flow run. ``config``
    pins a runner regardless of the profile (tests, notebooks). A run without a ``profile``
    parameter gets the section's default.

    Unless that runner is a thread pool anyway, a task whose parameters are known (values, or
    futures that are finished or cache hits of this runner) and whose result is cached
    (``cached_result_exists``) goes to a thread pool of the flow process instead, where Prefect
    loads the result and records the Cached state: the real runner starts at the first task that
    must run. A task that takes a future still running is never held back to find out: it goes to
    the real runner, as every task did before."""

    def __init__(
        self, config: RunnerConfig | None = None, parameter: str = "profile", section: RunnerSection = "runner"
    ) -> None:
        super().__init__()
        self._config = config
        self._parameter = parameter
        self._section: RunnerSection = section
        self._inner: TaskRunner[Any] | None = None
        self._config_in_use: RunnerConfig | None = None
        self._cache_hits: ThreadPoolTaskRunner | None = None
        self._cache_hit_runs: set[uuid.UUID] = set()

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
        """The runner the profile asks for (None until a task that is not a cache hit is submitted)."""
        return self._inner

    @property
    def cache_hits(self) -> ThreadPoolTaskRunner | None:
        """The flow process's runner of cache hits (None until the first one)."""
        return self._cache_hits

    def _ready(self, future: PrefectFuture[Any]) -> bool:
        """Whether waiting on ``future`` is cheap: a cache hit of this runner, or already finished."""
        if future.task_run_id in self._cache_hit_runs:
            return True
        return isinstance(future, PrefectWrappedFuture) and future.wrapped_future.done()

    def _is_cache_hit(
        self, task: Any, parameters: dict[str, Any], wait_for: Iterable[PrefectFuture[Any]] | None
    ) -> bool:
        resolved = resolve_now(parameters, wait_for, self._ready)
        return resolved is not None and cached_result_exists(task, resolved)

    def _submit_cache_hit(
        self,
        task: Any,
        parameters: dict[str, Any],
        wait_for: Iterable[PrefectFuture[Any]] | None,
        dependencies: dict[str, set[Any]] | None,
    ) -> PrefectFuture[Any]:
        if self._cache_hits is None:
            self._cache_hits = ThreadPoolTaskRunner().__enter__()
        future = self._cache_hits.submit(task, parameters, wait_for, dependencies)
        self._cache_hit_runs.add(future.task_run_id)
        return future

    def submit(
        self,
        task: Any,
        parameters: dict[str, Any],
        wait_for: Iterable[PrefectFuture[Any]] | None = None,
        dependencies: dict[str, set[Any]] | None = None,
    ) -> PrefectFuture[Any]:
        if not self._started:
            raise RuntimeError("The task runner must be started before submitting work.")
        if self._config_in_use is None:
            # known only once the run is under way: the flow run's parameters name the profile
            self._config_in_use = self.resolve()
        if self._config_in_use.kind != "threads" and self._is_cache_hit(task, parameters, wait_for):
            return self._submit_cache_hit(task, parameters, wait_for, dependencies)
        if self._inner is None:
            runner = build_task_runner(self._config_in_use)
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
        cache_hits, self._cache_hits = self._cache_hits, None
        self._config_in_use = None
        self._cache_hit_runs.clear()
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
            try:
                if cache_hits is not None:
                    cache_hits.__exit__(exc_type, exc_value, traceback)
            finally:
                super().__exit__(exc_type, exc_value, traceback)
