"""What every Prefect task of the project shares: a cache policy that survives new
processes and sees the library code, result storage under the data folder."""

from __future__ import annotations

import hashlib
import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from functools import cache
from importlib import util
from pathlib import Path
from typing import Any, cast

from prefect.cache_policies import INPUTS, NO_CACHE, TASK_SOURCE, CachePolicy
from prefect.utilities.annotations import quote


@cache
def source_digest(module: str) -> str:
    """sha256 over the source files of a module or package (all .py files below it)."""
    spec = util.find_spec(module)
    if spec is None or spec.origin is None:
        raise ModuleNotFoundError(module)
    return code_digest(Path(spec.origin))


def code_digest(origin: Path) -> str:
    """sha256 over a module file, or over a package's .py files (``origin`` its __init__.py)
    with their paths inside the package: the checkout's own folder is no part of the key, so
    a clone elsewhere (a worktree, a worker's image) finds the same cached results."""
    paths = sorted(origin.parent.rglob("*.py")) if origin.name == "__init__.py" else [origin]
    h = hashlib.sha256()
    for p in paths:
        h.update(p.relative_to(origin.parent).as_posix().encode())
        h.update(p.read_bytes())
    return h.hexdigest()


@dataclass
class LibraryCode(CachePolicy):
    """Cache key part for the library code a task calls: TASK_SOURCE sees only the task
    function's own source, not the helpers it calls, so a library change must be keyed too."""

    modules: tuple[str, ...] = ()

    def compute_key(self, task_ctx: Any, inputs: dict[str, Any], flow_parameters: dict[str, Any], **kwargs: Any) -> str:
        return hashlib.sha256("".join(source_digest(m) for m in self.modules).encode()).hexdigest()


# Bookkeeping tasks (catalog refresh, reports, artefacts) run on every flow run; persisting
# their results would only pile up files in the results folder that no later run reads.
ALWAYS_RUN = {"cache_policy": NO_CACHE, "persist_result": False}


def cache_policy(*modules: str) -> CachePolicy:
    """INPUTS + TASK_SOURCE + the named library modules (and the schemas, always)."""
    return INPUTS + TASK_SOURCE + LibraryCode(modules=("schemas", *modules))


def one_torch_thread() -> None:
    """One intra-op torch thread for a training (teacher, student variant, policy): the stages
    train side by side (``training_runner``), and torch's default of a thread per core each
    oversubscribes the cores. A lone training would be faster with them all, but a thread count
    that followed the run's other trainings would make a result depend on them (another count
    sums in another order). bench/torch_threads.py, local policy profile on 2 cores: two side by
    side 17.8 samples/s together with 1 thread each, 2.8-7.6 with 2 each; one alone 8.9 with 1
    thread, 11.8 with 2."""
    import torch

    torch.set_num_threads(1)


def retry_unless_lost_physics(task: Any, task_run: Any, state: Any) -> bool:
    """Retry condition of the tasks that simulate: a simulation that lost physics (``LostPhysicsError``)
    fails the same way again, so it is not retried."""
    from touch2robot.sim.guard import LostPhysicsError

    return not isinstance(state.data, LostPhysicsError)


STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)


@contextmanager
def checkpoint_on_stop() -> Iterator[Callable[[], bool]]:
    """A training's way to keep its progress when its process is asked to stop (SIGTERM from
    ``tasks.runners.stop_pool_workers`` or ``kill``, SIGINT from Ctrl-C): yields a check that
    turns true on the first such signal, so that the training saves a checkpoint where it is
    and returns; on leaving, the signal goes to the handler that was there before, so the
    process still stops as asked. Signals that follow wait for the checkpoint too: a process
    pool that lost a worker sends SIGTERM to the others (SIGKILL stops at once). A signal the
    process ignores stays ignored (a process pool's workers ignore SIGINT: their flow run
    stops them); outside a main thread (a threads runner) no handler can be set and the check stays
    false."""
    if threading.current_thread() is not threading.main_thread():
        yield lambda: False
        return
    previous = {
        signum: handler
        for signum in STOP_SIGNALS
        if (handler := signal.getsignal(signum) or signal.SIG_DFL) != signal.SIG_IGN
    }
    received: list[int] = []
    for signum in previous:
        signal.signal(signum, lambda signum, frame: received.append(signum))
    try:
        yield lambda: bool(received)
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        if received:
            signal.raise_signal(received[0])


def stored(task_obj: Any, results: Path) -> Any:
    """The task with its results persisted under ``results`` (the data folder a flow run
    was given), so the cache follows the data folder, not the process environment."""
    return task_obj.with_options(result_storage=results, persist_result=True)


def unvisited[T](value: T) -> T:
    """A task argument of plain data (row lists, frames) passed as it is: Prefect otherwise visits every element
    of every argument twice per task run looking for futures (1.4 s of a cached smoke re-run in the evaluate flow
    alone). The task and its cache key see ``value`` unchanged; never wrap a future in it."""
    return cast(T, quote(value))
