"""Training a teacher with rsl-rl-lib's OnPolicyRunner: the runner configuration (Table VII),
an rsl-rl LogWriter that streams every scalar (reward terms, losses, task figures) to one MLflow
run and uploads each checkpoint to it, and resumption from the last readable checkpoint."""

from __future__ import annotations

import pickle
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from mlflow.entities import Metric
from mlflow.tracking import MlflowClient
from rsl_rl.runners import OnPolicyRunner
from rsl_rl.utils.log_writer import LogWriter

from touch2robot.sim.env import BatchEnv
from touch2robot.sim.rsl_env import RslVecEnv
from touch2robot.sim.scene import build_scene
from touch2robot.teachers.config import PPOConfig, TeacherConfig
from touch2robot.teachers.objective import DemoTracking, References
from touch2robot.tracking import UnloggedSteps

CHECKPOINT = re.compile(r"model_(\d+)\.pt$")


def runner_config(ppo: PPOConfig, logger: dict | None = None) -> dict:
    """rsl-rl 5.x's train_cfg for PPO with MLP actor and critic (observation normalisation on)."""
    mlp = {
        "class_name": "MLPModel",
        "hidden_dims": list(ppo.hidden_dims),
        "activation": ppo.activation,
        "obs_normalization": True,
    }
    cfg = {
        "num_steps_per_env": ppo.num_steps_per_env,
        "save_interval": ppo.save_interval,
        "obs_groups": {"actor": ["actor"], "critic": ["critic"]},
        "actor": {**mlp, "distribution_cfg": {"class_name": "GaussianDistribution", "init_std": ppo.init_noise_std}},
        "critic": mlp,
        "algorithm": {
            "class_name": "PPO",
            "num_learning_epochs": ppo.num_learning_epochs,
            "num_mini_batches": ppo.num_mini_batches,
            "learning_rate": ppo.learning_rate,
            "clip_param": ppo.clip_param,
            "max_grad_norm": ppo.max_grad_norm,
            "gamma": ppo.gamma,
            "lam": ppo.lam,
            "desired_kl": ppo.desired_kl,
            "entropy_coef": ppo.entropy_coef,
            "value_loss_coef": ppo.value_loss_coef,
            "schedule": ppo.schedule,
        },
    }
    if logger is not None:
        cfg["logger"] = logger
    return cfg


def metric_name(tag: str) -> str:
    """An MLflow-valid metric name for an rsl-rl tag (no leading '/', no odd characters)."""
    return re.sub(r"[^A-Za-z0-9_\-. /]", "_", tag).lstrip("/") or "_"


class MlflowLogWriter(LogWriter):
    """rsl-rl LogWriter feeding one MLflow run: scalars are batched per iteration, checkpoints
    become artefacts under ``checkpoints/``. Uses an explicit client and run id, so teachers
    training in parallel threads of one process never share MLflow's active-run state."""

    def __init__(self, log_dir: str | None, run_id: str, tracking_uri: str) -> None:
        self.run_id = run_id
        self.client = MlflowClient(tracking_uri)
        self._unlogged = UnloggedSteps(self.client, run_id)  # a resumed run: no iteration drawn twice
        self._pending: dict[str, float] = {}
        self._step = -1

    def add_scalar(self, tag: str, scalar_value: float, global_step: int) -> None:
        if global_step != self._step:
            self.flush()
            self._step = int(global_step)
        value = float(scalar_value)
        if value == value:  # MLflow rejects NaN only on some stores; skip it everywhere
            self._pending[metric_name(tag)] = value

    def flush(self) -> None:
        """Send the buffered scalars in one request (MLflow's batch limit is 1000)."""
        metrics = [Metric(k, v, 0, self._step) for k, v in self._unlogged(self._step, self._pending).items()]
        for i in range(0, len(metrics), 1000):
            self.client.log_batch(self.run_id, metrics=metrics[i : i + 1000])
        self._pending = {}

    def save_model(self, model_path: str, it: int) -> None:
        self.flush()
        self.client.log_artifact(self.run_id, model_path, "checkpoints")

    def stop(self) -> None:
        self.flush()


def make_teacher_env(
    task: str, refs: References, config: TeacherConfig, method: str, n_envs: int | None = None
) -> RslVecEnv:
    """The batched env of one task driven by the teacher objective of ``method``."""
    env = BatchEnv(build_scene(task, config.sim), config.sim, n_envs or config.sim.n_envs)
    objective = DemoTracking(refs, config, method)
    # episodes end with their reference (truncated) or when tracking is lost; this only caps them
    return RslVecEnv(env, objective, max_episode_length=int(refs.length.max()) + 1, seed=config.seed)


def checkpoints(run_dir: Path) -> list[tuple[int, Path]]:
    """(iteration, path) of the checkpoints in a run folder, newest first."""
    found = [(int(m.group(1)), p) for p in Path(run_dir).glob("model_*.pt") if (m := CHECKPOINT.search(p.name))]
    return sorted(found, reverse=True)


def load_latest(runner: OnPolicyRunner, run_dir: Path) -> int | None:
    """Load the newest readable checkpoint (a kill during a save leaves a torn file: it is skipped
    and later overwritten); returns the number of iterations it had completed, or None."""
    for it, path in checkpoints(run_dir):
        try:
            runner.load(str(path), map_location="cpu")
        except (RuntimeError, EOFError, KeyError, ValueError, OSError, pickle.UnpicklingError):
            continue
        return it + 1
    return None


@dataclass(frozen=True)
class TrainResult:
    iterations: int  # completed in total
    resumed_from: int  # iterations already done when this call started (0 = fresh)
    checkpoint: Path  # the final checkpoint


class _Stopped(Exception):
    """Raised out of rsl-rl's learning loop after an iteration's logging when a stop was asked."""


def _stop_after_logging(runner: OnPolicyRunner, should_stop: Callable[[], bool]) -> None:
    """rsl-rl's ``learn`` has no stop hook; its logger's ``log`` is the last call of every
    iteration before the periodic save, so a stop is checked there, once that iteration's update
    and scalars are done."""
    log = runner.logger.log

    def log_then_check(*args: Any, **kwargs: Any) -> None:
        log(*args, **kwargs)
        if should_stop():
            raise _Stopped

    runner.logger.log = log_then_check


def train(vec_env: RslVecEnv, config: TeacherConfig, run_dir: Path, run_id: str, tracking_uri: str,
          should_stop: Callable[[], bool] | None = None) -> TrainResult:  # fmt: skip
    """Train to ``config.ppo.max_iterations`` iterations, continuing from the newest checkpoint in
    ``run_dir`` if one exists. Every scalar goes to the MLflow run ``run_id``. ``should_stop()``
    (asked after every iteration) turning true ends the call early with a checkpoint of the
    iteration just done, from which the next call continues."""
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(config.seed)
    logger = {"class_name": f"{__name__}:MlflowLogWriter", "run_id": run_id, "tracking_uri": tracking_uri}
    runner = OnPolicyRunner(vec_env, runner_config(config.ppo, logger), log_dir=str(run_dir), device=vec_env.device)
    done = load_latest(runner, run_dir) or 0
    runner.current_learning_iteration = done
    remaining = config.ppo.max_iterations - done
    if should_stop is not None:
        _stop_after_logging(runner, should_stop)
    iterations = max(done, config.ppo.max_iterations)
    if remaining > 0:
        try:
            runner.learn(remaining)
        except _Stopped:
            iterations = runner.current_learning_iteration + 1
            runner.save(str(run_dir / f"model_{runner.current_learning_iteration}.pt"))
            runner.logger.stop_logging_writer()
    final = checkpoints(run_dir)[0][1]
    return TrainResult(iterations=iterations, resumed_from=done, checkpoint=final)


def load_policy(vec_env: RslVecEnv, config: TeacherConfig, checkpoint: Path) -> torch.nn.Module:
    """The deterministic actor of a trained teacher (action = distribution mean)."""
    runner = OnPolicyRunner(vec_env, runner_config(config.ppo), log_dir=None, device=vec_env.device)
    runner.load(str(checkpoint), map_location="cpu")
    return runner.get_inference_policy(device=vec_env.device)
