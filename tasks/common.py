"""What every Prefect task of the project shares: a cache policy that survives new
processes and sees the library code, result storage under the data folder."""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from functools import lru_cache
from importlib import util
from pathlib import Path
from typing import Any

from prefect.cache_policies import NO_CACHE, TASK_SOURCE, CachePolicy, Inputs


@lru_cache(maxsize=None)
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


def cache_policy(*modules: str, exclude: tuple[str, ...] = ()) -> CachePolicy:
    """The task's inputs (less ``exclude``: how it runs, not what it computes) + TASK_SOURCE +
    the named library modules (and the schemas, always)."""
    return Inputs(exclude=list(exclude)) + TASK_SOURCE + LibraryCode(modules=("schemas", *modules))


def file_digest(path: str | Path) -> str:
    """Content hash of an input file: a path alone is no cache key."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def one_torch_thread() -> None:
    """One intra-op torch thread for a teacher or student training: the stage trains several side
    by side (``training_runner``), and torch's default of a thread per core each would
    oversubscribe the cores (see ``torch_threads``)."""
    import torch

    torch.set_num_threads(1)


def torch_threads(side_by_side: int) -> int:
    """Intra-op torch threads for one of ``side_by_side`` trainings running at once: this
    machine's cores shared out, at least one each. bench/torch_threads.py, local policy profile
    on 2 cores: one alone 11.8 samples/s with 2 threads and 8.9 with 1; two side by side 17.8
    together with 1 thread each, and 2.8-7.6 with torch's default of a thread per core each."""
    return max(1, len(os.sched_getaffinity(0)) // max(1, side_by_side))


def stored(task_obj: Any, results: Path) -> Any:
    """The task with its results persisted under ``results`` (the data folder a flow run
    was given), so the cache follows the data folder, not the process environment."""
    return task_obj.with_options(result_storage=results, persist_result=True)
