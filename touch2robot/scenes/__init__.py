"""The task suite: one module per task, discovered, so that adding a task is adding one module.

A task module declares ``TASK = Task(...)`` (``touch2robot.scenes.base``): its scene spec
(``default_config()``, the single source of truth shared by the demonstrator and the MuJoCo scenes),
its success criterion, its scripted human demonstration and its language instruction. Every module
of this package that declares a ``TASK`` is registered; ``TASKS`` lists them in suite order.
"""

import importlib
import pkgutil

from touch2robot.scenes.base import SuccessCriterion, Task
from touch2robot.scenes.spec import GeomSpec, ObjectSpec, SlideSpec, TaskSpec


def _discover() -> dict[str, Task]:
    """Every ``TASK`` declared by a module of this package, by name, in suite order."""
    found: list[Task] = []
    for module_info in pkgutil.iter_modules(__path__, prefix=f"{__name__}."):
        declared = getattr(importlib.import_module(module_info.name), "TASK", None)
        if isinstance(declared, Task):
            found.append(declared)
    found.sort(key=lambda t: t.position)
    for name, values in (("name", [t.name for t in found]), ("position", [t.position for t in found])):
        if len(set(values)) != len(values):
            raise ValueError(f"task modules share a {name}: {values}")
    for t in found:
        if t.default_config().name != t.name:
            raise ValueError(f"task {t.name!r}: its default_config() is named {t.default_config().name!r}")
    return {t.name: t for t in found}


REGISTRY: dict[str, Task] = _discover()
# The suite's order: a task's index seeds the demonstrator's random streams and orders every output.
TASKS: tuple[str, ...] = tuple(REGISTRY)


def task(name: str) -> Task:
    """A task by name; raises ValueError listing the known tasks."""
    try:
        return REGISTRY[name]
    except KeyError:
        raise ValueError(f"unknown task {name!r}; known tasks: {', '.join(REGISTRY)}") from None


def get(name: str) -> TaskSpec:
    """The spec of a task by name; raises ValueError listing the known tasks."""
    return task(name).default_config()


__all__ = [
    "REGISTRY",
    "TASKS",
    "GeomSpec",
    "ObjectSpec",
    "SlideSpec",
    "SuccessCriterion",
    "Task",
    "TaskSpec",
    "get",
    "task",
]
