"""Robot demonstrations as LeRobot datasets: each method's rollouts (lake table ``rollouts``)
replayed in MuJoCo and recorded at 20 Hz with LeRobot's own dataset API (v3.0 format).

Features of every frame (one frame per control step, the observation before the step's command):

- ``observation.images.<camera>``: RGB (H, W, 3) from the scene cameras, rendered headless (only with
  ``policy.observation: images``, Table IX's).
- ``observation.state`` (23): the 16 LEAP joint positions (rad) and the wrist pose (px py pz qw qx
  qy qz) of the hand's free wrist joint.
- ``observation.environment_state``: the tactile region forces (N) on T1..T4, P1..P4 (8); with
  ``policy.observation: state`` also the object's pose (px py pz qw qx qy qz) and the drawer's opening (m),
  16 in all (LeRobot's Diffusion Policy reads this key and ignores unknown ones).
- ``observation.tactile`` (8): the tactile region forces (N) on T1..T4, P1..P4 again, under one name
  for every profile. LeRobot 0.6.1 has no tactile convention, so the project keeps its own named
  feature; Diffusion Policy reads only ``observation.state``, images and the environment state, and
  leaves this one to other readers (viewers, other policies).
- ``action`` (23): the 16 joint targets and the commanded wrist pose. The LEAP hand sits on a
  floating (mocap) wrist, so a policy must command the wrist as well as the fingers: the action is
  the full command a rollout applied, and replaying actions reproduces the rollout.
- ``task``: a sentence naming the task.

A rollout's row 0 is its reset state: replay resets BatchEnv copies to it and steps the recorded
commands; the replayed states are what is recorded (so images and state agree), and the gap to the
recorded states is reported (physics is deterministic per copy, so it stays small).
"""

from __future__ import annotations

import os
import shutil
import time
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from schemas.tables import ROBOT_REGIONS
from schemas.vocabulary import Origin
from touch2robot import scenes
from touch2robot.datasets import ROLLOUTS, lerobot_repo_id
from touch2robot.leap import description as hd
from touch2robot.policy.config import VIDEO_BACKEND, PolicyConfig
from touch2robot.scenes import TASKS

# the GL backend is chosen when this is imported, before mujoco: keep it first
from touch2robot.sim import render as _render  # noqa: F401
from touch2robot.sim.config import SimConfig
from touch2robot.sim.env import BatchEnv
from touch2robot.sim.scene import Scene

FPS = 20
ROBOT_TYPE = "leap_hand_floating_wrist"
WRIST_NAMES = ("wrist_px", "wrist_py", "wrist_pz", "wrist_qw", "wrist_qx", "wrist_qy", "wrist_qz")
STATE_NAMES = (*hd.JOINT_NAMES, *WRIST_NAMES)
ACTION_NAMES = (*(f"{j}_target" for j in hd.JOINT_NAMES), *(f"{w}_cmd" for w in WRIST_NAMES))
FORCE_NAMES = tuple(f"force_{r}" for r in ROBOT_REGIONS)
OBJECT_NAMES = ("object_px", "object_py", "object_pz", "object_qw", "object_qx", "object_qy", "object_qz")
TACTILE_KEY = "observation.tactile"
# what observation.environment_state holds, per PolicyConfig.observation
ENVIRONMENT_NAMES = {"images": FORCE_NAMES, "state": (*FORCE_NAMES, *OBJECT_NAMES, "drawer_opening")}
# which rollouts of a task x method become its demonstrations, best first
ORIGIN_PREFERENCE = (Origin.STUDENT, Origin.TEACHER, Origin.KINEMATIC)
assert set(ORIGIN_PREFERENCE) == set(Origin)


class RolloutError(ValueError):
    """A rollouts file that cannot be replayed; the message names the file and what is wrong."""


@dataclass(frozen=True)
class Rollout:
    """One rollout's per-step arrays (T steps), in step order."""

    rollout_id: str
    joint_position: np.ndarray  # (T, 16)
    joint_target: np.ndarray  # (T, 16)
    wrist_state: np.ndarray  # (T, 7) observed wrist body pose
    wrist_pose: np.ndarray  # (T, 7) commanded
    object_pose: np.ndarray  # (T, 7)
    drawer_opening: np.ndarray  # (T,)
    success: bool  # the rollout's own outcome (last row)

    def __len__(self) -> int:
        return len(self.joint_position)


@dataclass(frozen=True)
class Source:
    """The rollouts file chosen for one task x method."""

    task: str
    method: str
    origin: str
    path: Path


def sources(lake: Path, preference: tuple[str, ...] = ORIGIN_PREFERENCE, seed: int = 0) -> list[Source]:
    """Per task x method present in the lake's ``rollouts`` table of sweep seed ``seed``, the file of the most
    preferred origin (default student > teacher > kinematic; origins not in ``preference``
    are never used), sorted by task then method. A file the catalog cannot name (not
    ``method=<m>/<origin>-<task>-seed<seed>.parquet``) raises :class:`touch2robot.datasets.DatasetIdError`."""
    unknown = set(preference) - set(ORIGIN_PREFERENCE)
    if unknown:
        raise ValueError(f"policy.origins: unknown origin(s) {sorted(unknown)}; choose from {ORIGIN_PREFERENCE}")
    best: dict[tuple[str, str], Source] = {}
    for (origin, task, of_seed), partition, path in ROLLOUTS.entries(lake):
        if origin not in preference or of_seed != str(seed):
            continue
        method = partition["method"]
        cand = Source(task, method, origin, path)
        old = best.get((task, method))
        if old is None or preference.index(origin) < preference.index(old.origin):
            best[(task, method)] = cand
    return sorted(best.values(), key=lambda s: (TASKS.index(s.task), s.method))


def _matrix(table: pa.Table, column: str, width: int, path: Path) -> np.ndarray:
    values = table.column(column).combine_chunks()
    flat = (
        values.flatten().to_numpy(zero_copy_only=False)
        if pa.types.is_fixed_size_list(values.type) or pa.types.is_list(values.type)
        else None
    )
    if flat is None or flat.size != width * len(table):
        raise RolloutError(f"{path}: column {column!r} must hold {width} values per row")
    return flat.reshape(len(table), width).astype(np.float64)


def demonstrations(path: Path) -> list[str]:
    """The human demonstrations (``reference_id``) the rollouts of one file follow, sorted."""
    try:
        refs = pq.read_table(path, columns=["reference_id"]).column("reference_id")
    except (KeyError, pa.ArrowInvalid) as e:
        raise RolloutError(f"{path}: cannot read column 'reference_id' ({e})") from None
    return sorted(set(refs.to_pylist()))


def common_demonstrations(paths: list[Path]) -> list[str]:
    """The demonstrations that the rollouts of every file follow (sorted)."""
    sets = [set(demonstrations(p)) for p in paths]
    return sorted(set.intersection(*sets)) if sets else []


def chosen_sources(
    lake: Path,
    cfg: PolicyConfig,
    tasks: Sequence[str] | None = None,
    methods: Sequence[str] | None = None,
    seed: int = 0,
) -> list[tuple[Source, list[str] | None]]:
    """Every task x method's rollouts file of sweep seed ``seed`` (most preferred of ``cfg.origins``, narrowed
    to ``tasks`` / ``methods``) with, under ``cfg.same_demonstrations``, the demonstrations every chosen method
    of its task follows (None = every rollout; [] = none in common, so nothing to compare)."""
    chosen = [
        s
        for s in sources(lake, tuple(cfg.origins), seed)
        if (not tasks or s.task in tasks) and (not methods or s.method in methods)
    ]
    shared: dict[str, list[str]] = {}
    if cfg.same_demonstrations:
        for task_name in {s.task for s in chosen}:
            shared[task_name] = common_demonstrations([s.path for s in chosen if s.task == task_name])
    return [(s, shared.get(s.task)) for s in chosen]


def read_rollouts(path: Path, limit: int | None = None, references: list[str] | None = None) -> list[Rollout]:
    """The rollouts of one file, by rollout id, each sorted by step; steps must run 0, 1, 2, ...
    (row 0 is the reset state). With ``references``: only the first rollout following each of
    those demonstrations, in that order (a deterministic teacher's repeats of a demonstration
    are the same trajectory). Then the first ``limit``."""
    table = pq.read_table(path)
    needed = (
        "rollout_id",
        "reference_id",
        "step",
        "joint_position",
        "joint_target",
        "wrist_state",
        "wrist_pose",
        "object_pose",
        "drawer_opening",
        "success",
    )
    missing = [c for c in needed if c not in table.column_names]
    if missing:
        raise RolloutError(f"{path}: missing columns {missing}")
    ids = table.column("rollout_id").to_numpy(zero_copy_only=False)
    order = np.lexsort((table.column("step").to_numpy(), ids))
    table = table.take(pa.array(order))
    ids = ids[order]
    names, starts = np.unique(ids, return_index=True)
    ends = np.append(starts[1:], len(ids))
    spans = list(zip(names, starts, ends, strict=True))
    if references is not None:
        first_of: dict[str, tuple] = {}
        for span in spans:
            first_of.setdefault(table.column("reference_id")[int(span[1])].as_py(), span)
        absent = [r for r in references if r not in first_of]
        if absent:
            raise RolloutError(f"{path}: no rollout follows demonstration(s) {absent}")
        spans = [first_of[r] for r in references]
    out = []
    for name, a, b in spans[:limit]:
        part = table.slice(a, b - a)
        steps = part.column("step").to_numpy()
        if not np.array_equal(steps, np.arange(len(steps))):
            raise RolloutError(
                f"{path}: rollout {name!r} has steps {steps[:5]}... (expected 0, 1, 2, ... from its reset)"
            )
        out.append(
            Rollout(
                rollout_id=str(name),
                joint_position=_matrix(part, "joint_position", 16, path),
                joint_target=_matrix(part, "joint_target", 16, path),
                wrist_state=_matrix(part, "wrist_state", 7, path),
                wrist_pose=_matrix(part, "wrist_pose", 7, path),
                object_pose=_matrix(part, "object_pose", 7, path),
                drawer_opening=part.column("drawer_opening").to_numpy().astype(np.float64),
                success=bool(part.column("success")[-1].as_py()),
            )
        )
    if not out:
        raise RolloutError(f"{path}: no rollouts")
    return out


def reset_to_first_rows(env: BatchEnv, rollouts: list[Rollout], object_pose: np.ndarray | None = None) -> None:
    """Reset the copies of ``env`` to the rollouts' reset rows (the rollouts contract), optionally
    with other object poses (evaluation jitters the start)."""
    first = lambda field: np.stack([getattr(r, field)[0] for r in rollouts])  # noqa: E731
    env.reset_pose(
        np.arange(env.n),
        first("joint_position"),
        first("wrist_state"),
        first("object_pose") if object_pose is None else object_pose,
        first("drawer_opening"),
    )


def recorded_commands(rollouts: list[Rollout], t: int) -> tuple[np.ndarray, np.ndarray]:
    """(joint targets (N, 16), wrist poses (N, 7)) the rollouts commanded at step ``t``; a rollout
    that has ended repeats its last command."""
    targets = np.stack([r.joint_target[min(t, len(r) - 1)] for r in rollouts])
    wrist = np.stack([r.wrist_pose[min(t, len(r) - 1)] for r in rollouts])
    return targets, wrist


def observation_state(env: BatchEnv) -> np.ndarray:
    """(N, 23) ``observation.state``: joint positions and the wrist free joint's pose."""
    return np.concatenate([env.hand_qpos, env.wrist_pose], axis=1)


def tactile_state(env: BatchEnv) -> np.ndarray:
    """(N, 8) ``observation.tactile`` (``FORCE_NAMES``): the tactile region forces (N)."""
    return env.region_force


def environment_state(env: BatchEnv, observation: str) -> np.ndarray:
    """(N, 8 | 16) ``observation.environment_state`` (``ENVIRONMENT_NAMES[observation]``): the tactile
    region forces and, for a state-only policy, the object's pose and the drawer's opening."""
    forces = tactile_state(env)
    if observation == "images":
        return forces
    # the object's world pose, which the drawer has too (its raw coordinate is the slide's)
    return np.concatenate([forces, env.object_pos, env.object_quat, env.drawer_opening[:, None]], axis=1)


class CameraRenderer:
    """RGB frames of every copy of a BatchEnv from the named cameras: one mujoco.Renderer per
    camera and one MjData, reused across frames."""

    def __init__(self, scene: Scene, cameras: tuple[str, ...], size: int) -> None:
        for cam in cameras:
            if mujoco.mj_name2id(scene.model, mujoco.mjtObj.mjOBJ_CAMERA, cam) < 0:
                raise ValueError(f"scene {scene.spec.name!r} has no camera {cam!r}")
        self.model = scene.model
        self.cameras = cameras
        self.data = mujoco.MjData(self.model)
        self.renderers = {cam: mujoco.Renderer(self.model, height=size, width=size) for cam in cameras}
        self.frames = 0
        self.seconds = 0.0

    def render(self, env: BatchEnv, ids: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """{camera: (k, H, W, 3) uint8} for copies ``ids`` (default all) at their current state."""
        if not self.renderers:  # a state-only policy's dataset
            return {}
        start = time.perf_counter()
        ids = np.arange(env.n) if ids is None else np.asarray(ids)
        out = {cam: np.empty((ids.size, r.height, r.width, 3), np.uint8) for cam, r in self.renderers.items()}
        for k, i in enumerate(ids):
            mujoco.mj_setState(self.model, self.data, env.state[i], mujoco.mjtState.mjSTATE_FULLPHYSICS)
            mujoco.mj_kinematics(self.model, self.data)
            mujoco.mj_camlight(self.model, self.data)
            for cam, r in self.renderers.items():
                r.update_scene(self.data, camera=cam)
                r.render(out=out[cam][k])
        self.frames += ids.size * len(self.renderers)
        self.seconds += time.perf_counter() - start
        return out

    def close(self) -> None:
        for r in self.renderers.values():
            r.close()


def camera_views(cfg: PolicyConfig) -> tuple[str, ...]:
    """The cameras a policy of ``cfg`` sees (none for a state-only one)."""
    return cfg.cameras if cfg.observation == "images" else ()


def features(cfg: PolicyConfig) -> dict:
    """LeRobot feature spec of the datasets (images stored as images, not video)."""
    s = cfg.image_size
    image = {"dtype": "image", "shape": (s, s, 3), "names": ["height", "width", "channels"]}
    environment = ENVIRONMENT_NAMES[cfg.observation]
    return {
        **{f"observation.images.{cam}": image for cam in camera_views(cfg)},
        "observation.state": {"dtype": "float32", "shape": (len(STATE_NAMES),), "names": list(STATE_NAMES)},
        "observation.environment_state": {
            "dtype": "float32",
            "shape": (len(environment),),
            "names": list(environment),
        },
        TACTILE_KEY: {"dtype": "float32", "shape": (len(FORCE_NAMES),), "names": list(FORCE_NAMES)},
        "action": {"dtype": "float32", "shape": (len(ACTION_NAMES),), "names": list(ACTION_NAMES)},
    }


@dataclass(frozen=True)
class DatasetSummary:
    """What one dataset build did."""

    root: str
    repo_id: str
    episodes: int
    frames: int
    rollouts_succeeded: int  # rollouts whose recorded outcome is success
    replay_max_joint_error_rad: float  # replayed vs recorded joint positions, worst step
    replay_mean_joint_error_rad: float
    render_frames: int  # camera images rendered
    render_fps: float  # camera images per second of rendering
    build_s: float


def build_dataset(
    root: Path,
    task: str,
    method: str,
    rollouts: list[Rollout],
    scene: Scene,
    sim: SimConfig,
    cfg: PolicyConfig,
    seed: int = 0,
) -> DatasetSummary:
    """Replay ``rollouts`` (of sweep seed ``seed``) in ``scene`` (``cfg.replay_batch`` at a time as BatchEnv
    copies), render the cameras and write a finalised LeRobot dataset at ``root``. It is built in a
    temporary sibling folder and renamed into place, so ``root`` never holds half a dataset."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    start = time.perf_counter()
    root = Path(root)
    root.parent.mkdir(parents=True, exist_ok=True)
    tmp = root.with_name(f".{root.name}.{uuid.uuid4().hex[:8]}.tmp")
    repo_id = lerobot_repo_id(method, task, seed)
    instruction = scenes.task(task).instruction
    errors: list[np.ndarray] = []
    renderer = CameraRenderer(scene, camera_views(cfg), cfg.image_size)
    try:
        ds = LeRobotDataset.create(
            repo_id, FPS, features(cfg), root=tmp, robot_type=ROBOT_TYPE, use_videos=False, video_backend=VIDEO_BACKEND
        )
        frames = 0
        for first in range(0, len(rollouts), cfg.replay_batch):
            batch = rollouts[first : first + cfg.replay_batch]
            episodes = _replay(batch, scene, sim, renderer, cfg.observation, errors)
            for ep in episodes:
                for t in range(len(ep["action"])):
                    ds.add_frame({**{k: v[t] for k, v in ep.items()}, "task": instruction})
                ds.save_episode()
                frames += len(ep["action"])
        ds.finalize()
        if root.exists():
            shutil.rmtree(root)
        os.replace(tmp, root)
    finally:
        renderer.close()
        shutil.rmtree(tmp, ignore_errors=True)
    err = np.concatenate(errors)
    return DatasetSummary(
        root=str(root),
        repo_id=repo_id,
        episodes=len(rollouts),
        frames=frames,
        rollouts_succeeded=sum(r.success for r in rollouts),
        replay_max_joint_error_rad=float(err.max()),
        replay_mean_joint_error_rad=float(err.mean()),
        render_frames=renderer.frames,
        render_fps=renderer.frames / renderer.seconds if renderer.seconds else float("nan"),
        build_s=time.perf_counter() - start,
    )


def _replay(
    batch: list[Rollout],
    scene: Scene,
    sim: SimConfig,
    renderer: CameraRenderer,
    observation: str,
    errors: list[np.ndarray],
) -> list[dict[str, np.ndarray]]:
    """Replay rollouts together; per rollout the frame arrays of its episode. Copies whose
    rollout has ended keep stepping on their last command (cheaper than a ragged batch) and
    are no longer recorded. Appends each step's worst joint error (replayed vs recorded)."""
    env = BatchEnv(scene, sim, n_envs=len(batch))
    try:
        reset_to_first_rows(env, batch)
        lengths = np.array([len(r) for r in batch])
        cams = [f"observation.images.{c}" for c in renderer.cameras]
        episodes = [
            {k: [] for k in (*cams, "observation.state", "observation.environment_state", TACTILE_KEY, "action")}
            for _ in batch
        ]
        for t in range(lengths.max()):
            live = np.flatnonzero(lengths > t)
            recorded = np.stack([batch[i].joint_position[t] for i in live])
            errors.append(np.abs(env.hand_qpos[live] - recorded).max(axis=1))
            images = renderer.render(env, live)
            state, environment, tactile = (
                observation_state(env),
                environment_state(env, observation),
                tactile_state(env),
            )
            targets, wrist = recorded_commands(batch, t)
            for k, i in enumerate(live):
                ep = episodes[i]
                for cam, key in zip(renderer.cameras, cams, strict=True):
                    ep[key].append(images[cam][k])
                ep["observation.state"].append(state[i].astype(np.float32))
                ep["observation.environment_state"].append(environment[i].astype(np.float32))
                ep[TACTILE_KEY].append(tactile[i].astype(np.float32))
                ep["action"].append(np.concatenate([targets[i], wrist[i]]).astype(np.float32))
            env.step(targets, wrist[:, :3], wrist[:, 3:])
    finally:
        env.close()
    return [{k: np.stack(v) for k, v in ep.items()} for ep in episodes]
