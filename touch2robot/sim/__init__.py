"""Batched MuJoCo simulation of the LEAP Hand task scenes.

Public API, by module (imported from there: this package init stays free of mujoco so that
``touch2robot.sim.render`` can pick the GL backend before mujoco is first imported):

- ``config``: ``SimConfig`` (pydantic; defaults = the paper profile).
- ``scene``: ``build_scene(task, cfg) -> Scene`` (compiled model, state addresses, point cloud).
- ``env``: ``BatchEnv(scene, cfg)`` -- N copies stepped in C by MuJoCo's multithreaded rollout.
- ``success``: ``SuccessTracker`` -- per-task success from the object state.
- ``rsl_env``: ``Objective`` protocol, ``RslVecEnv`` (rsl-rl VecEnv), ``make_vec_env``,
  ``episode_steps``, ``JointTracking`` (the example objective).
- ``render``: ``render_scenes(out_dir, width, height)`` -- PNGs of every scene from both cameras.
"""

from touch2robot.sim.config import SimConfig

__all__ = ["SimConfig"]
