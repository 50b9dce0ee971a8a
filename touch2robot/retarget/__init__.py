"""Kinematic retargeting: human wrist pose + hand keypoints -> LEAP joint trajectories (the Dex
Retargeting baseline, the teachers' hand reference and the student's raw input).

Only the configuration is imported here: it has to load with a profile, without the optional
Dex Retargeting dependency (and torch). The retargeter is ``touch2robot.retarget.retargeter``,
lake input/output ``touch2robot.retarget.lake``, drawings ``touch2robot.retarget.render``.
"""

from touch2robot.retarget.config import LEAP_DEFAULT, RetargetConfig

__all__ = ["LEAP_DEFAULT", "RetargetConfig"]
