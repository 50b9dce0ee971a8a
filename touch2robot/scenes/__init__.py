"""Task scenes: one module per task with ``default_config()``, and a registry by name."""

from collections.abc import Callable

from touch2robot.scenes import drawer, pick, rotate, wipe
from touch2robot.scenes.spec import GeomSpec, ObjectSpec, SlideSpec, TaskSpec

REGISTRY: dict[str, Callable[[], TaskSpec]] = {
    "pick": pick.default_config,
    "rotate": rotate.default_config,
    "wipe": wipe.default_config,
    "drawer": drawer.default_config,
}


def get(name: str) -> TaskSpec:
    """The spec of a task by name; raises ValueError listing the known tasks."""
    try:
        return REGISTRY[name]()
    except KeyError:
        raise ValueError(f"unknown task {name!r}; known tasks: {', '.join(REGISTRY)}") from None


__all__ = ["REGISTRY", "GeomSpec", "ObjectSpec", "SlideSpec", "TaskSpec", "get"]
