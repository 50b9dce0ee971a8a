"""Teachers: per-task PPO policies (rsl-rl-lib) in MuJoCo that track human demonstrations and
their contacts, one per task and method (touch2robot, contrack, dexmachina), and the robot
trajectories they produce (the ``rollouts`` table, sim contacts in ``contacts``).

- ``reference``: a demonstration on the control grid (kinematic hand reference, object trajectory,
  tactile preference, geometric contact references).
- ``objective``: the one rsl-rl objective all methods share; methods differ by ``config`` only.
- ``train``: the OnPolicyRunner configuration (Table VII), MLflow LogWriter, checkpoint resume.
- ``rollouts``: deterministic teacher rollouts and the kinematic (Dex Retargeting) replays.
- ``check``: each task's reference success, the kinematic replay of every demonstration to its end.
"""
