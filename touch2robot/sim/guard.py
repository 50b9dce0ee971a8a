"""Lost physics in the batched simulation is an error, never a silent result.

MuJoCo keeps going when physics is lost: a full contact or constraint buffer drops contacts or
all constraints for the step, and a NaN / huge position, velocity or acceleration resets the
copy's data to the model's default pose. Its multithreaded rollout then stops stepping that copy
and repeats its last state for the rest of the call, and it clears the warning counters at the
start of every copy, so after a call only the last copy of each thread's share shows its warnings.
``BatchEnv.step`` therefore checks cheap signs after every call (a copy whose clock did not advance
by the whole control step, warnings left on a thread's data, a non-finite state, arena use over
``ARENA_BUDGET``) and, only when one shows, replays copies one at a time with ``replay_copy`` to
name the copy and the warning in a ``LostPhysicsError``. One case slips through a single call: a
full contact or constraint buffer in the last substep of a copy that is not the last of its
thread's share leaves no stalled clock and no counter; the overflowing contacts are still there at
the next step's first substep, which is caught (unless the copy is reset in between). Resets after
a bad position, velocity or acceleration always show as a restarted clock (given two or more
substeps per control step).

The arena budget exists because a full arena is worse than a warning: MuJoCo's stack, which
shares the arena with contacts and constraints, ends in a fatal error when it overflows, and in a
rollout worker thread that exits the whole process. Arena use grows with contacts, so stopping
at half the arena turns that crash into an error while the scene still has room.
"""

from __future__ import annotations

import mujoco
import numpy as np

# share of the arena (<size memory>) a copy may use before stepping stops with an error
ARENA_BUDGET = 0.5
MjWarning = mujoco.mjtWarning
WARNING_CAUSES = {
    MjWarning.mjWARN_CONTACTFULL: "contact buffer full",
    MjWarning.mjWARN_CNSTRFULL: "constraint buffer full",
    MjWarning.mjWARN_BADQPOS: "NaN, Inf or huge position (the copy was reset)",
    MjWarning.mjWARN_BADQVEL: "NaN, Inf or huge velocity (the copy was reset)",
    MjWarning.mjWARN_BADQACC: "NaN, Inf or huge acceleration: the simulation is unstable (the copy was reset)",
    MjWarning.mjWARN_BADCTRL: "NaN, Inf or huge control (all controls were zeroed)",
    MjWarning.mjWARN_INERTIA: "invalid inertia",
}
ARENA_HINT = "raise <size memory> in the scene MJCF"


class LostPhysicsError(RuntimeError):
    """Physics of one copy of a batched task scene went wrong: which task, copy (``env``), episode
    time of that copy (``time_s``, seconds since its reset) and what happened (``cause``)."""

    def __init__(self, task: str, env: int | None, time_s: float | None, cause: str) -> None:
        self.task, self.env, self.time_s, self.cause = task, env, time_s, cause
        where = "no copy reproduced it" if env is None else f"env {env} at t = {time_s:.2f} s"
        super().__init__(f"{task}: {where}: {cause}")

    def __reduce__(self) -> tuple[type, tuple[str, int | None, float | None, str]]:
        # picklable with its fields, for process-pool task runners
        return type(self), (self.task, self.env, self.time_s, self.cause)


def raised_warnings(data: mujoco.MjData) -> list[int]:
    """The MuJoCo warnings (``mjtWarning`` values) counted on ``data`` since its counters were cleared."""
    return [int(w) for w in np.flatnonzero(data.warning.number)]


def warning_cause(warning: int, model: mujoco.MjModel) -> str:
    """What a MuJoCo warning means for the simulation, with its name and, for a full buffer, the remedy."""
    name = MjWarning(warning).name
    cause = f"{WARNING_CAUSES[MjWarning(warning)]} ({name})"
    if warning in (MjWarning.mjWARN_CONTACTFULL, MjWarning.mjWARN_CNSTRFULL):
        cause += f" in an arena of {model.narena / 1024:.0f} KiB: {ARENA_HINT}"
    return cause


def arena_over_budget(data: mujoco.MjData, model: mujoco.MjModel) -> bool:
    """Whether ``data`` has used more of the arena than ``ARENA_BUDGET`` (its high-water mark)."""
    return data.maxuse_arena > ARENA_BUDGET * model.narena


def replay_copy(
    model: mujoco.MjModel,
    scratch: mujoco.MjData,
    state: np.ndarray,
    controls: np.ndarray,
    state_spec: int,
    control_spec: int,
) -> tuple[int, str] | None:
    """Step one copy from ``state`` through ``controls`` (nstep, ncontrol) as the rollout does (zero
    solver warm start) on ``scratch``, a data no one else uses; returns (substep, cause) of the first
    substep that loses physics, or None."""
    mujoco.mj_setState(model, scratch, state, state_spec)
    scratch.qacc_warmstart[:] = 0.0
    scratch.warning.number[:] = 0
    scratch.maxuse_arena = 0
    for substep, control in enumerate(controls):
        mujoco.mj_setState(model, scratch, control, control_spec)
        try:
            mujoco.mj_step(model, scratch)
        except mujoco.FatalError as error:
            return substep, f"MuJoCo error {str(error).splitlines()[0]!r}: {ARENA_HINT}"
        warnings = raised_warnings(scratch)
        if warnings:
            return substep, "; ".join(warning_cause(w, model) for w in warnings)
        if arena_over_budget(scratch, model):
            return substep, (
                f"arena use {scratch.maxuse_arena / 1024:.0f} KiB is over {ARENA_BUDGET:.0%} of its "
                f"{model.narena / 1024:.0f} KiB (more contacts would overflow it): {ARENA_HINT}"
            )
        if not np.isfinite(scratch.qpos).all() or not np.isfinite(scratch.qvel).all():
            return substep, "non-finite state"
    return None
