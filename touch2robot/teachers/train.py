"""Training a teacher with rsl-rl-lib's OnPolicyRunner: the runner configuration (Table VII),
an rsl-rl LogWriter that hands every scalar (reward terms, losses, task figures) to the caller's
``on_log(step, metrics)`` and every checkpoint to its ``on_checkpoint(path)``, and resumption from
the last readable checkpoint. rsl-rl prints its iteration dump, model summaries and git notices;
they go to the ``rsl_rl`` logger at debug level instead."""

from __future__ import annotations

import logging
import pickle
import re
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import rsl_rl.algorithms.ppo
import rsl_rl.runners.on_policy_runner
import rsl_rl.utils.logger
import torch
from rsl_rl.runners import OnPolicyRunner
from rsl_rl.utils.log_writer import LogWriter

from touch2robot.sim.env import BatchEnv
from touch2robot.sim.rsl_env import RslVecEnv
from touch2robot.sim.scene import build_scene
from touch2robot.teachers.config import PPOConfig, TeacherConfig
from touch2robot.teachers.objective import DemoTracking, References

CHECKPOINT = re.compile(r"model_(\d+)\.pt$")
# rsl-rl logs a wall-clock copy of its return and episode length with the elapsed whole seconds as
# the step; those names end so (see ``train``'s ``on_log``)
WALL_CLOCK_SUFFIX = "/time"

OnLog = Callable[[int, dict[str, float]], None]
OnCheckpoint = Callable[[str], None]

_rsl_rl_log = logging.getLogger("rsl_rl")


def _print_to_debug_log(*values: object, sep: str | None = " ", end: str | None = "\n", **_: object) -> None:
    _rsl_rl_log.debug((sep if sep is not None else " ").join(str(v) for v in values).rstrip())


# The modules of rsl-rl that print (a 34-line dump per iteration, the models, the git diff it
# stores): a module-level ``print`` shadows the builtin for them alone, whatever thread or process
# trains, where redirecting sys.stdout would catch every other thread's output too.
for _module in (rsl_rl.utils.logger, rsl_rl.algorithms.ppo, rsl_rl.runners.on_policy_runner):
    _module.print = _print_to_debug_log  # type: ignore[attr-defined]


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


class CallbackLogWriter(LogWriter):
    """rsl-rl LogWriter handing the scalars of every ``Logger.log`` call to ``on_log(step, metrics)``,
    one call per step they were logged at (NaN dropped: MLflow rejects it on some stores), and each
    saved checkpoint's path to ``on_checkpoint``. ``flush`` sends what ``Logger.log`` added."""

    def __init__(self, log_dir: str | None, on_log: OnLog | None = None, on_checkpoint: OnCheckpoint | None = None):
        self.on_log, self.on_checkpoint = on_log, on_checkpoint
        self._pending: dict[int, dict[str, float]] = {}

    def add_scalar(self, tag: str, scalar_value: float, global_step: int) -> None:
        value = float(scalar_value)
        if value == value:
            self._pending.setdefault(int(global_step), {})[metric_name(tag)] = value

    def flush(self) -> None:
        pending, self._pending = self._pending, {}
        if self.on_log is not None:
            for step, metrics in pending.items():
                self.on_log(step, metrics)

    def save_model(self, model_path: str, it: int) -> None:
        self.flush()
        if self.on_checkpoint is not None:
            self.on_checkpoint(model_path)

    def stop(self) -> None:
        self.flush()


@contextmanager
def torch_threads(threads: int) -> Iterator[None]:
    """torch's intra-op thread count set to ``threads`` inside, restored on leaving."""
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def update_threads(config: TeacherConfig) -> int:
    """The torch threads of the PPO update: ``ppo.update_threads``, else the physics' thread count."""
    return config.ppo.update_threads or config.sim.threads


def _update_on_threads(runner: OnPolicyRunner, threads: int) -> None:
    """Run rsl-rl's PPO update on ``threads`` torch threads. No physics runs during the update, so it
    takes the cores the rollout threads use; collection stays on one thread (a small MLP's inference
    is fastest so, and the physics owns the cores then). Both counts are fixed by the configuration:
    sums split over another number of threads round differently, and a training's result must not
    depend on what else runs on the machine."""
    update = runner.alg.update

    def update_on_threads() -> dict[str, float]:
        with torch_threads(threads):
            return update()

    runner.alg.update = update_on_threads


def make_teacher_env(
    task: str, refs: References, config: TeacherConfig, method: str, n_envs: int | None = None
) -> RslVecEnv[DemoTracking]:
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


def _after_logging(runner: OnPolicyRunner, should_stop: Callable[[], bool] | None) -> None:
    """rsl-rl's ``learn`` has no per-iteration hook; its logger's ``log`` is the last call of every
    iteration before the periodic save, so the iteration's scalars are sent and a stop is checked
    there, once that iteration's update is done."""
    log = runner.logger.log

    def log_then_check(*args: Any, **kwargs: Any) -> None:
        log(*args, **kwargs)
        if isinstance(runner.logger.writer, CallbackLogWriter):
            runner.logger.writer.flush()
        if should_stop is not None and should_stop():
            raise _Stopped

    runner.logger.log = log_then_check


def train(
    vec_env: RslVecEnv,
    config: TeacherConfig,
    run_dir: Path,
    on_log: OnLog | None = None,
    on_checkpoint: OnCheckpoint | None = None,
    should_stop: Callable[[], bool] | None = None,
) -> TrainResult:
    """Train to ``config.ppo.max_iterations`` iterations, continuing from the newest checkpoint in
    ``run_dir`` if one exists. After every iteration ``on_log(iteration, metrics)`` gets rsl-rl's
    scalars of it (iterations count from 0), then, in a call of their own, its wall-clock copies
    (names ending ``WALL_CLOCK_SUFFIX``, the step the elapsed whole seconds; merged into the
    iteration's call when the two steps are equal); ``on_checkpoint(path)`` gets every checkpoint
    saved. ``should_stop()`` (asked after every iteration) turning true ends the call early with a
    checkpoint of the iteration just done, from which the next call continues. Collection runs on
    one torch thread, the PPO update on ``update_threads(config)``."""
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(config.seed)
    # rsl-rl deep-copies its logger config: plain functions pass through it as themselves
    logger = {
        "class_name": f"{__name__}:CallbackLogWriter",
        "on_log": None if on_log is None else lambda step, metrics: on_log(step, metrics),
        "on_checkpoint": None if on_checkpoint is None else lambda path: on_checkpoint(path),
    }
    runner = OnPolicyRunner(vec_env, runner_config(config.ppo, logger), log_dir=str(run_dir), device=vec_env.device)
    done = load_latest(runner, run_dir) or 0
    runner.current_learning_iteration = done
    remaining = config.ppo.max_iterations - done
    _after_logging(runner, should_stop)
    _update_on_threads(runner, update_threads(config))
    iterations = max(done, config.ppo.max_iterations)
    if remaining > 0:
        try:
            with torch_threads(1):
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
