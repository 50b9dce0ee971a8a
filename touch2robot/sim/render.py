"""Headless still images of the task scenes from their two cameras.

MuJoCo picks its GL backend when ``mujoco`` is first imported, so this module chooses it at its
own import (before it imports mujoco): import it, or set MUJOCO_GL, before anything else imports
mujoco in a process that renders.
"""

from __future__ import annotations

import ctypes.util
import os
import sys
import warnings
from pathlib import Path

import numpy as np


def select_gl_backend() -> str:
    """Choose MuJoCo's headless GL backend: EGL if its library is present, else OSMesa (software,
    with a warning saying so). An explicit MUJOCO_GL in the environment wins."""
    if "MUJOCO_GL" not in os.environ:
        if "mujoco" in sys.modules:
            warnings.warn(
                "mujoco was imported before MUJOCO_GL was set: its default GL backend stays in use", stacklevel=2
            )
        if ctypes.util.find_library("EGL"):
            os.environ["MUJOCO_GL"] = "egl"
        else:
            warnings.warn("EGL is unavailable: rendering with OSMesa (software, slower)", stacklevel=2)
            os.environ["MUJOCO_GL"] = "osmesa"
    if os.environ["MUJOCO_GL"] == "osmesa":
        os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
    return os.environ["MUJOCO_GL"]


select_gl_backend()

import mujoco  # noqa: E402 - after the backend choice, on purpose

from touch2robot import scenes  # noqa: E402
from touch2robot.sim.config import SimConfig  # noqa: E402
from touch2robot.sim.scene import CAMERAS, build_scene  # noqa: E402


def render_scene_images(
    task: str, width: int = 224, height: int = 224, cfg: SimConfig | None = None
) -> dict[str, np.ndarray]:
    """RGB images (height, width, 3) of a task scene at its reset state, one per camera."""
    scene = build_scene(task, cfg)
    data = mujoco.MjData(scene.model)
    data.qpos[:] = scene.home_qpos
    mujoco.mj_forward(scene.model, data)
    with mujoco.Renderer(scene.model, height=height, width=width) as renderer:
        images = {}
        for cam in CAMERAS:
            renderer.update_scene(data, camera=cam)
            images[cam] = renderer.render().copy()
    return images


def render_scenes(out_dir: Path, width: int = 224, height: int = 224) -> list[Path]:
    """Save ``<task>_<camera>.png`` for every registered task and both cameras; returns the paths."""
    from PIL import Image

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for task in scenes.REGISTRY:
        for cam, image in render_scene_images(task, width, height).items():
            path = out_dir / f"{task}_{cam}.png"
            Image.fromarray(image).save(path)
            paths.append(path)
    return paths
