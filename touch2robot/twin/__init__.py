"""The hardware twin: robot replays measured on a perturbed MuJoCo copy of the rig, not scripted.

Public API, by module (imported from there: this package init stays free of mujoco, as ``touch2robot.sim``'s,
because loading a profile imports ``TwinConfig``):

- ``config``: ``TwinConfig`` -- per-replay perturbation and sensor ranges (the profile's ``twin`` section).
- ``plan``: ``ReplayConfig`` (the profile's ``replay`` section), ``plan_replays`` -- which trajectories run.
- ``replay``: ``replay_rollouts`` (``replay_rollout`` for one) -- trajectories (rows of the ``rollouts`` table)
  executed open loop on a twin drawn per replay, written as the rig's ``robot_replay`` and ``robot_calibration``
  MCAPs; one replay's physics overlaps the writing of the one before.
- ``model``, ``sensors``, ``streams``: the perturbed model, the TwinTac and FSR models, the message streams.
"""

from touch2robot.twin.config import TwinConfig

__all__ = ["TwinConfig"]
