"""Headless still images of the task scenes from their two cameras."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from touch2robot.sim.config import SimConfig


def select_gl_backend() -> str:
    """Choose MuJoCo's headless GL backend before the renderer is imported: EGL if its library
    loads, else OSMesa (software). An explicit MUJOCO_GL in the environment wins."""
    if "MUJOCO_GL" not in os.environ:
        import ctypes.util

        os.environ["MUJOCO_GL"] = "egl" if ctypes.util.find_library("EGL") else "osmesa"
    if os.environ["MUJOCO_GL"] == "osmesa":
        os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
    return os.environ["MUJOCO_GL"]


def render_scene_images(task: str, width: int = 224, height: int = 224, cfg: SimConfig | None = None) -> dict[str, np.ndarray]:
    """RGB images (height, width, 3) of a task scene at its reset state, one per camera."""
    select_gl_backend()
    import mujoco

    from touch2robot.sim.scene import CAMERAS, build_scene

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

    from touch2robot import scenes

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for task in scenes.REGISTRY:
        for cam, image in render_scene_images(task, width, height).items():
            path = out_dir / f"{task}_{cam}.png"
            Image.fromarray(image).save(path)
            paths.append(path)
    return paths
