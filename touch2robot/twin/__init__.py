"""The hardware twin: robot replays measured on a perturbed MuJoCo copy of the rig, not scripted.

``replay_rollout`` executes one method's robot trajectory (rows of the ``rollouts`` table) open loop on a
twin drawn per replay from ``TwinConfig`` and writes the ``robot_replay`` and ``robot_calibration`` MCAPs
exactly as the rig would, for the normal ingest.
"""

from touch2robot.twin.config import TwinConfig
from touch2robot.twin.replay import ReplayOutcome, replay_rollout

__all__ = ["ReplayOutcome", "TwinConfig", "replay_rollout"]
