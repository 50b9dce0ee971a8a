"""Configuration of the batched MuJoCo simulation (defaults = the paper profile)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, model_validator


class SimConfig(BaseModel):
    """How the simulation is stepped and batched.

    ``timestep`` x ``substeps`` must equal one control period (1 / ``control_hz``). The 10 ms physics
    step and 20 Hz control are MuJoCo Playground's LEAP settings; 20 Hz is also the rate of the
    robot demonstrations (LeRobot datasets) built from these rollouts.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    n_envs: int = Field(default=200, ge=1, description="parallel copies (Table VII: 200)")
    control_hz: float = Field(default=20.0, gt=0, description="policy / command rate")
    timestep: float = Field(default=0.01, gt=0, description="physics step, s")
    substeps: int = Field(default=5, ge=1, description="physics steps per control step")
    threads: int = Field(default=2, ge=1, description="MuJoCo rollout threads (1 = calling thread only)")
    seed: int = Field(default=0, description="seed of resets and noise")
    contact_threshold_n: float = Field(
        default=0.5, gt=0, description="region contact when summed normal force exceeds this"
    )
    solver_iterations: int = Field(default=10, ge=1, description="Newton solver iterations per step")
    ls_iterations: int = Field(default=8, ge=1, description="line-search iterations per solver iteration")
    episode_s: float | None = Field(default=None, gt=0, description="episode length; None = the task spec's")
    point_cloud_size: int = Field(default=512, ge=1, description="surface points sampled on the object")
    device: str = Field(default="cpu", description="torch device of the rsl-rl adapter's tensors")

    @model_validator(mode="after")
    def _consistent_rates(self) -> SimConfig:
        period = self.timestep * self.substeps
        if abs(period * self.control_hz - 1.0) > 1e-6:
            raise ValueError(f"timestep x substeps = {period} s does not match control_hz = {self.control_hz}")
        return self

    @property
    def control_dt(self) -> float:
        """Seconds per control step."""
        return self.timestep * self.substeps
