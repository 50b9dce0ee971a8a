"""Robot demonstrations as LeRobot datasets, LeRobot's Diffusion Policy trained on them (Table IX)
and its closed-loop evaluation in the batched MuJoCo env, per task and data-collection method.

Only the configuration is imported here (no torch, mujoco or lerobot): the dataset builder is
``touch2robot.policy.dataset``, training ``touch2robot.policy.train``, evaluation
``touch2robot.policy.evaluate``; ``touch2robot.policy.reader`` fixes LeRobot 0.6.1's window reads.
"""

from touch2robot.policy.config import PolicyConfig

__all__ = ["PolicyConfig"]
