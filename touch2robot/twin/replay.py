"""One robot replay on the hardware twin: a method's trajectory executed open loop on a perturbed rig,
recorded as the rig records it.

The rows of one rollout (``rollouts`` table) give the reset state (row 0) and the commands (joint
targets + wrist pose, one per control step). The twin (``touch2robot.twin.model``) starts from that state
exactly as ``BatchEnv.reset_pose`` does, holds the reset command until the first command arrives (after
the drawn latency), then each command for one control period, and the last one for ``TwinConfig.hold_s``.
Open loop, so the whole control sequence is known up front and MuJoCo's rollout steps it in C, in
chunks, on a worker thread; meanwhile this thread writes the calibration and then each chunk's messages
(sensor models of ``touch2robot.twin.sensors``; timing and encoding in ``touch2robot.twin.streams``) as
its physics arrives, and draws the next replay's rig, whose physics the worker steps next
(``replay_rollouts``: the replay stage's batches). Lost physics leaves neither file.

Clocks: physics time 0 is when command 0 is sent; the recording's streams start a few ms earlier and its
clock sits at a fixed epoch plus an offset drawn per recording (seed and file name). A sample at recording
time t reads the physics at the last step at or before it.
"""

from __future__ import annotations

import queue
import threading
import zlib
from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import pyarrow as pa
from mujoco import rollout as mj_rollout

from schemas.rig import DEFAULT_RIG
from schemas.vocabulary import RecordingKind
from touch2robot import scenes
from touch2robot.recording import clock
from touch2robot.recording.writer import RecordingWriter
from touch2robot.sim.config import SimConfig
from touch2robot.sim.env import CONTROL_SPEC, STATE_SPEC
from touch2robot.sim.guard import LostPhysicsError, arena_over_budget, raised_warnings, replay_copy, warning_cause
from touch2robot.sim.scene import Scene, build_scene
from touch2robot.twin import streams
from touch2robot.twin.config import TwinConfig
from touch2robot.twin.model import TwinModel, perturb
from touch2robot.twin.sensors import PalmFsr, TwinTac, sensor_summary

CLOCK_SPAN_S = 10**7  # replays' clocks are spread over ~4 months after the epoch
CHUNK_S = 0.5  # physics handed to the writer in pieces of this length
TAIL_S = 0.05  # the last piece
COMMAND_JITTER_S = 0.001  # the command loop's scheduling jitter
COMMAND_START_S = (0.02, 0.05)  # the first command leaves this long after the recording starts
CALIBRATION_GAP_S = (2.0, 30.0)  # the calibration ends this long before the replay starts
RIG = DEFAULT_RIG  # the twin is the simulated rig's robot: it records as that rig file says
RATE_HZ = {topic.name: topic.rate_hz for topic in RIG.topics(RecordingKind.ROBOT_REPLAY)}
TWINTAC, FSR, JOINT_STATES, JOINT_TARGETS, REFERENCE_TIME = (
    RIG.topic(stream) for stream in ("twintac", "fsr", "robot_joint_states", "robot_joint_targets", "time_map")
)
# the command and the reference time it executes are published together, one stream here
_STREAMS = (TWINTAC, FSR, JOINT_STATES, JOINT_TARGETS)
_WIDTHS = {"joint_position": 16, "joint_target": 16, "wrist_state": 7, "wrist_pose": 7, "object_pose": 7}
_SCALARS = ("step", "t_ref", "drawer_opening")


@dataclass(frozen=True)
class ReplayOutcome:
    """What one replay wrote and what its twin measured (forces are the twin's true region forces)."""

    replay_path: Path
    calibration_path: Path
    steps: int  # physics steps simulated
    duration_s: float  # physics time simulated, s
    peak_region_force: tuple[float, ...]  # per region T1..T4, P1..P4, N
    contact_fraction: tuple[float, ...]  # per region: share of the 100 Hz samples with force > 0.5 N
    perturbation: dict[str, float]  # every value drawn for this replay


@dataclass(frozen=True)
class _Commands:
    """One rollout's reset state and command sequence."""

    task: str
    joint_position: np.ndarray  # (16,) at reset
    wrist_state: np.ndarray  # (7,) at reset
    object_pose: np.ndarray  # (7,) at reset
    drawer_opening: float  # at reset
    joint_target: np.ndarray  # (K, 16)
    wrist_pose: np.ndarray  # (K, 7)
    t_ref: np.ndarray  # (K,)


def _matrix(table: pa.Table, name: str, width: int) -> np.ndarray:
    col = table[name].combine_chunks()
    values = col.flatten().to_numpy(zero_copy_only=False).astype(np.float64)
    if values.size != width * len(col):
        raise ValueError(f"rollout column {name!r} must hold {width} values per row")
    return values.reshape(len(col), width)


def _commands(rollout: pa.Table) -> _Commands:
    """The rows of one rollout as a reset state and commands, sorted by step; ValueError names what is wrong."""
    if rollout.num_rows == 0:
        raise ValueError("the rollout table is empty: no trajectory to replay")
    names = set(rollout.column_names)  # (the property builds a new list at every use)
    missing = [c for c in ("rollout_id", "task", *_WIDTHS, *_SCALARS) if c not in names]
    if missing:
        raise ValueError(f"the rollout table lacks column(s) {', '.join(missing)}")
    for name in ("rollout_id", "task"):
        values = rollout[name].unique().to_pylist()
        if len(values) != 1:
            raise ValueError(f"the rows must be one rollout; column {name!r} holds {sorted(map(str, values))}")
    task = str(rollout["task"][0].as_py())
    if task not in scenes.TASKS:
        raise ValueError(f"rollout of unknown task {task!r}; the tasks are {', '.join(scenes.TASKS)}")
    rows = rollout.select([*_WIDTHS, *_SCALARS])
    step = rows["step"].to_numpy()
    if np.any(np.diff(step) < 0):  # a rollout's rows are stored in step order: sort only what is not
        rows = rows.take(pa.array(np.argsort(step, kind="stable")))
    cols = {name: _matrix(rows, name, width) for name, width in _WIDTHS.items()}
    wrist = cols["wrist_pose"].copy()
    wrist[:, 3:] /= np.linalg.norm(wrist[:, 3:], axis=1, keepdims=True)
    return _Commands(
        task=task,
        joint_position=cols["joint_position"][0],
        wrist_state=cols["wrist_state"][0],
        object_pose=cols["object_pose"][0],
        drawer_opening=float(rows["drawer_opening"][0].as_py()),
        joint_target=cols["joint_target"],
        wrist_pose=wrist,
        t_ref=rows["t_ref"].to_numpy().astype(np.float64),
    )


_scenes: dict[tuple[str, str], Scene] = {}


def _nominal_scene(task: str, sim: SimConfig) -> Scene:
    """The compiled training scene of a task (read only: the twin perturbs copies of its model), compiled
    once per process and simulation settings."""
    key = (task, sim.model_dump_json())
    if key not in _scenes:
        _scenes[key] = build_scene(task, sim)
    return _scenes[key]


_scratch = threading.local()


def _scene_data(
    cache: dict[tuple[str, str], mujoco.MjData], task: str, sim: SimConfig, model: mujoco.MjModel
) -> mujoco.MjData:
    """The data of a scene's models in ``cache`` (a new MjData zeroes a 16 MB arena: it costs as much as a
    tenth of a replay's physics). One data per scene serves every replay its owner runs one at a time."""
    key = (task, sim.model_dump_json())
    if key not in cache:
        cache[key] = mujoco.MjData(model)
    return cache[key]


def _thread_data(task: str, sim: SimConfig, model: mujoco.MjModel) -> mujoco.MjData:
    """This thread's data of a scene (rigs are drawn one at a time per thread)."""
    return _scene_data(_scratch.__dict__.setdefault("data", {}), task, sim, model)


def _initial_state(scene: Scene, model: mujoco.MjModel, data: mujoco.MjData, cmd: _Commands) -> np.ndarray:
    """The full physics state at reset, as ``BatchEnv.reset_pose`` makes it: hand joints and their servo
    targets at the recorded joints, wrist body and mocap target at the recorded wrist, object (or drawer)
    where it was; at rest."""
    mujoco.mj_resetData(model, data)
    data.qpos[:] = scene.home_qpos
    data.qpos[scene.hand_qpos] = cmd.joint_position
    if scene.is_drawer:
        data.qpos[scene.object_qpos] = cmd.drawer_opening
    else:
        data.qpos[scene.object_qpos : scene.object_qpos + 7] = cmd.object_pose
    data.qpos[scene.wrist_qpos : scene.wrist_qpos + 7] = cmd.wrist_state
    data.mocap_pos[0], data.mocap_quat[0] = cmd.wrist_state[:3], cmd.wrist_state[3:]
    data.ctrl[:] = cmd.joint_position
    mujoco.mj_forward(model, data)
    state = np.empty(mujoco.mj_stateSize(model, STATE_SPEC))
    mujoco.mj_getState(model, data, state, STATE_SPEC)
    return state


def _control(model: mujoco.MjModel, cmd: _Commands, n_steps: int, substeps: int, latency: int) -> np.ndarray:
    """(n_steps, ncontrol) per physics step: ctrl, no applied force, mocap pos and quat. Step j runs command
    (j - latency) // substeps (clipped to the last); before the first arrives, the reset command holds."""
    low, high = model.actuator_ctrlrange.T
    targets = np.clip(np.vstack([cmd.joint_position, cmd.joint_target]), low, high)
    wrist = np.vstack([cmd.wrist_state, cmd.wrist_pose])
    which = np.clip((np.arange(n_steps) - latency) // substeps, -1, len(cmd.joint_target) - 1) + 1
    nu, nv = model.nu, model.nv
    control = np.zeros((n_steps, nu + nv + 7))
    control[:, :nu] = targets[which]
    control[:, nu + nv :] = wrist[which]
    return control


class _Physics:
    """One replay's physics, stepped by ``_PhysicsWorker`` chunk after chunk, the solver's warm start carried
    across chunks (the result equals one rollout over all steps). ``states[j]`` is the state at physics time
    j x timestep (row 0: the reset state), ``sensordata[j]`` the sensors at that time; ``ready()`` blocks until
    the next chunk is done and returns how many steps are."""

    def __init__(self, task: str, model: mujoco.MjModel, data: mujoco.MjData, state: np.ndarray, control: np.ndarray):
        self.task, self.model, self.data, self.control = task, model, data, control
        n = len(control)
        self.states = np.empty((n + 1, len(state)))
        self.states[0] = state
        self.sensordata = np.empty((n, model.nsensordata))
        chunk, tail = (max(1, round(length / model.opt.timestep)) for length in (CHUNK_S, TAIL_S))
        # the messages of the last chunk are written after all physics is done: a short one shortens that wait
        cut = max(0, n - tail)
        self.bounds = [(lo, min(lo + chunk, cut)) for lo in range(0, cut, chunk)] + [(cut, n)]
        self._done: queue.SimpleQueue[int | BaseException] = queue.SimpleQueue()
        self._stop = threading.Event()

    def run(self, pool: mj_rollout.Rollout) -> None:
        """Step every chunk (on the worker's thread), handing each one's end, or the error, to ``ready``."""
        warmstart = np.zeros((1, self.model.nv))
        try:
            for lo, hi in self.bounds:
                if self._stop.is_set():
                    return
                try:
                    # shapes and types are right by construction: the wrapper's checks cost 0.2 ms a chunk
                    pool.rollout(
                        [self.model],
                        [self.data],
                        self.states[lo : lo + 1],
                        self.control[None, lo:hi],
                        control_spec=CONTROL_SPEC,
                        skip_checks=True,
                        nstep=hi - lo,
                        initial_warmstart=warmstart,
                        state=self.states[None, lo + 1 : hi + 1],
                        sensordata=self.sensordata[None, lo:hi],
                    )
                except mujoco.FatalError as error:
                    raise self._lost(lo, hi, f"MuJoCo error {str(error).splitlines()[0]!r}") from None
                self._check(lo, hi)
                warmstart = self.data.qacc_warmstart[None].copy()
                self._done.put(hi)
        except BaseException as error:  # handed to the writing thread, which raises it
            self._done.put(error)

    def _check(self, lo: int, hi: int) -> None:
        """The guard of ``touch2robot.sim.guard``: the rollout stops stepping at a warning (its clock stalls),
        and leaves the warnings and arena use of the chunk on its data."""
        dt = self.model.opt.timestep
        stalled = abs(self.states[hi, 0] - self.states[lo, 0] - (hi - lo) * dt) > 0.5 * dt
        finite = np.isfinite(self.states[hi]).all()
        warnings = raised_warnings(self.data)
        if stalled or not finite or warnings or arena_over_budget(self.data, self.model):
            cause = "; ".join(warning_cause(w, self.model) for w in warnings) or (
                "non-finite state" if not finite else "arena use over budget"
            )
            raise self._lost(lo, hi, cause)

    def _lost(self, lo: int, hi: int, cause: str) -> LostPhysicsError:
        """Name the step by replaying the chunk one step at a time (fresh data), else the chunk's start."""
        found = replay_copy(
            self.model, mujoco.MjData(self.model), self.states[lo], self.control[lo:hi], STATE_SPEC, CONTROL_SPEC
        )
        if found is not None:
            substep, cause = found
            return LostPhysicsError(self.task, 0, (lo + substep + 1) * self.model.opt.timestep, cause)
        return LostPhysicsError(self.task, 0, lo * self.model.opt.timestep, cause)

    def ready(self) -> int:
        item = self._done.get()
        if isinstance(item, BaseException):
            raise item
        return item

    def stop(self) -> None:
        """Skip the chunks not yet begun (a replay abandoned while its physics is queued or running)."""
        self._stop.set()


class _PhysicsWorker:
    """One thread that steps replays' physics back to back, in the order submitted (MuJoCo's rollout releases
    the GIL): while it steps one replay, the calling thread writes the one before's messages and draws the
    next one's rig, so the physics never waits for either. Its own data per scene: two replays' physics never
    run at once on it, and the calling thread's data (``_thread_data``) is free for the next rig's draw."""

    def __init__(self) -> None:
        self._queue: queue.SimpleQueue[_Physics | None] = queue.SimpleQueue()
        self._data: dict[tuple[str, str], mujoco.MjData] = {}
        self._thread = threading.Thread(target=self._serve, name="twin-physics", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        with mj_rollout.Rollout(nthread=0) as pool:
            while (physics := self._queue.get()) is not None:
                physics.run(pool)

    def data(self, task: str, sim: SimConfig, model: mujoco.MjModel) -> mujoco.MjData:
        """The worker's data of a scene."""
        return _scene_data(self._data, task, sim, model)

    def submit(self, physics: _Physics) -> None:
        self._queue.put(physics)

    def close(self) -> None:
        """End the thread once what is queued is done (``_Physics.stop`` what is not wanted)."""
        self._queue.put(None)
        self._thread.join()


def _effort(model: mujoco.MjModel, ctrl: np.ndarray, q: np.ndarray, qdot: np.ndarray) -> np.ndarray:
    """Position servos' torque (what the rig's current reading gives): gain x ctrl + bias . (1, q, qdot),
    clipped to the force range (the model's actuators are in joint order)."""
    force = model.actuator_gainprm[:, 0] * ctrl + model.actuator_biasprm[:, 1] * q + model.actuator_biasprm[:, 2] * qdot
    low, high = model.actuator_forcerange.T
    return np.where(model.actuator_forcelimited.astype(bool), np.clip(force, low, high), force)


def _seed_list(seed: int | Sequence[int]) -> list[int]:
    return [seed] if isinstance(seed, int) else [int(v) for v in seed]


def _seeds(seed: int | Sequence[int]) -> list[np.random.Generator]:
    """Independent generators of one replay: rig, sensors, stream timing and noise, clock."""
    return [np.random.default_rng(child) for child in np.random.SeedSequence(_seed_list(seed)).spawn(4)]


@dataclass(frozen=True)
class TwinPhysics:
    """What one replay simulates: the rig drawn for it, its reset state and its control per physics step."""

    commands: _Commands
    scene: Scene  # the nominal scene the rig perturbs
    rig: TwinModel
    data: mujoco.MjData  # the drawing thread's scratch data of the scene (its next draw reuses it)
    initial_state: np.ndarray  # full physics state at reset
    control: np.ndarray  # (steps, ncontrol): ctrl, applied force (none), mocap pos, mocap quat


def twin_physics(rollout: pa.Table, sim: SimConfig, twin: TwinConfig, seed: int | Sequence[int]) -> TwinPhysics:
    """Draw the rig of a replay (as ``replay_rollout`` does with the same seed) and lay out its physics:
    the commands, then ``twin.hold_s`` holding the last, all delayed by the rig's latency."""
    return _twin_physics(rollout, sim, twin, _seeds(seed)[0])


def _twin_physics(rollout: pa.Table, sim: SimConfig, twin: TwinConfig, rig_rng: np.random.Generator) -> TwinPhysics:
    cmd = _commands(rollout)
    scene = _nominal_scene(cmd.task, sim)
    data = _thread_data(cmd.task, sim, scene.model)
    rig = perturb(scene, twin, sim.timestep, rig_rng, data)
    n_steps = len(cmd.joint_target) * sim.substeps + rig.latency_steps + round(twin.hold_s / sim.timestep)
    control = _control(rig.model, cmd, n_steps, sim.substeps, rig.latency_steps)
    return TwinPhysics(cmd, scene, rig, data, _initial_state(scene, rig.model, data, cmd), control)


@dataclass(frozen=True)
class ReplayRequest:
    """One replay asked of ``replay_rollouts``: the rows of one rollout, the seed of its rig, the two files to
    write and the replay's metadata (task, subject, method, reference_recording, calibration_recording, rig)."""

    rollout: pa.Table
    seed: int | Sequence[int]
    replay_path: Path
    calibration_path: Path
    metadata: dict[str, str]


@dataclass(frozen=True)
class _Started:
    """A replay whose physics is submitted: what writing its recordings needs."""

    request: ReplayRequest
    prepared: TwinPhysics
    physics: _Physics
    twintac: TwinTac
    fsr: PalmFsr
    layout: _Layout
    replay_t0: int  # ns
    calibration_t0: int  # ns
    stream_rng: np.random.Generator


def replay_rollouts(
    requests: Iterable[ReplayRequest], sim: SimConfig, twin: TwinConfig
) -> Iterator[ReplayOutcome | ValueError | LostPhysicsError]:
    """Execute each request's rollout on a twin drawn from ``twin`` with its seed, and write its ``robot_replay``
    MCAP and its unloaded ``robot_calibration`` MCAP (same TwinTac set): both appear whole, the calibration
    first, or neither does. Yields, in the requests' order, what each replay measured, or the ValueError of
    rows that are not one rollout of a known task, or the LostPhysicsError of lost physics (the next replays
    go on). One replay's physics runs while the one before is written and the one after is drawn
    (``_PhysicsWorker``); each result equals that of the replay alone."""
    worker = _PhysicsWorker()
    in_flight: deque[_Started | ValueError] = deque()
    try:
        for request in requests:
            try:
                in_flight.append(_start(request, sim, twin, worker))
            except ValueError as error:
                in_flight.append(error)
            if len(in_flight) == 2:
                yield _settle(in_flight.popleft(), sim, twin)
        while in_flight:
            yield _settle(in_flight.popleft(), sim, twin)
    finally:
        for started in in_flight:
            if isinstance(started, _Started):
                started.physics.stop()
        worker.close()


def replay_rollout(
    rollout: pa.Table,
    sim: SimConfig,
    twin: TwinConfig,
    seed: int | Sequence[int],
    replay_path: Path,
    calibration_path: Path,
    metadata: dict[str, str],
) -> ReplayOutcome:
    """``replay_rollouts`` of one request; raises its ValueError or LostPhysicsError."""
    (result,) = replay_rollouts([ReplayRequest(rollout, seed, replay_path, calibration_path, metadata)], sim, twin)
    if isinstance(result, Exception):
        raise result
    return result


def _start(request: ReplayRequest, sim: SimConfig, twin: TwinConfig, worker: _PhysicsWorker) -> _Started:
    """Draw a replay's rig and sensors, submit its physics and lay out its messages."""
    rig_rng, sensor_rng, _, _ = _seeds(request.seed)
    prepared = _twin_physics(request.rollout, sim, twin, rig_rng)
    task, model = prepared.commands.task, prepared.rig.model
    data = worker.data(task, sim, prepared.scene.model)
    physics = _Physics(task, model, data, prepared.initial_state, prepared.control)
    worker.submit(physics)
    # the hardware (rig and sensor set) is the seed's; the session is the recording's own: its clock, jitter
    # and noise differ between two replays on one rig, as recordings made one after another do (two
    # byte-identical calibrations would be one recording to the ingest)
    name_seed = zlib.crc32(Path(request.replay_path).name.encode())
    _, _, stream_rng, clock_rng = _seeds([*_seed_list(request.seed), name_seed])
    twintac, fsr = TwinTac.draw(twin, sensor_rng), PalmFsr.draw(twin, sensor_rng)
    replay_t0 = clock.EPOCH_NS + round(clock_rng.uniform(0, CLOCK_SPAN_S) * 1e9)
    calibration_t0 = replay_t0 - round((twin.calibration_s + clock_rng.uniform(*CALIBRATION_GAP_S)) * 1e9)
    layout = _Layout.plan(sim, len(prepared.control), model.opt.timestep, stream_rng)
    return _Started(request, prepared, physics, twintac, fsr, layout, replay_t0, calibration_t0, stream_rng)


def _settle(
    started: _Started | ValueError, sim: SimConfig, twin: TwinConfig
) -> ReplayOutcome | ValueError | LostPhysicsError:
    if isinstance(started, ValueError):
        return started
    try:
        return _write(started, sim, twin)
    except LostPhysicsError as error:
        return error
    finally:
        started.physics.stop()  # a no-op once its physics is done; else the worker goes on to the next


def _write(started: _Started, sim: SimConfig, twin: TwinConfig) -> ReplayOutcome:
    """Write a started replay's calibration, then its replay as its physics arrives."""
    request, prepared, rng = started.request, started.prepared, started.stream_rng
    rig, model = prepared.rig, prepared.rig.model
    # the calibration is written and closed while the physics runs, and removed again if the replay fails: a
    # replay appears only after its calibration, and neither stays without the other
    calibration_metadata = {"rig": request.metadata.get("rig", ""), "sensor": "twintac"}
    with RecordingWriter(request.calibration_path, RecordingKind.ROBOT_CALIBRATION, calibration_metadata) as writer:
        _write_calibration(writer, started.twintac, started.calibration_t0, twin.calibration_s, rng)
    try:
        # chunks of a few physics pieces are compressed while the physics runs (one 1 MiB chunk per replay was
        # compressed after it: bench/twin.py 0.63 -> 0.70)
        with RecordingWriter(
            request.replay_path, RecordingKind.ROBOT_REPLAY, request.metadata, chunk_size=1 << 15
        ) as w:
            region_force = _write_replay(
                w,
                started.physics,
                started.layout,
                prepared.commands,
                rig,
                started.twintac,
                started.fsr,
                prepared.scene,
                started.replay_t0,
                rng,
            )
    except BaseException:
        Path(request.calibration_path).unlink(missing_ok=True)
        raise
    n_steps = len(prepared.control)
    contact = region_force > sim.contact_threshold_n
    return ReplayOutcome(
        replay_path=Path(request.replay_path),
        calibration_path=Path(request.calibration_path),
        steps=n_steps,
        duration_s=n_steps * model.opt.timestep,
        peak_region_force=tuple(float(v) for v in region_force.max(axis=0)),
        contact_fraction=tuple(float(v) for v in contact.mean(axis=0)),
        perturbation={**rig.perturbation, **sensor_summary(started.twintac, started.fsr)},
    )


def _write_calibration(
    writer: RecordingWriter, twintac: TwinTac, t0_ns: int, duration: float, rng: np.random.Generator
) -> None:
    """The unloaded TwinTac recording: the same sensor set, at this recording's own offset."""
    t = clock.stamps(duration, RATE_HZ[TWINTAC], rng)
    raw = twintac.read(np.zeros((len(t), 4)), t, twintac.recording_offset(rng), twintac.white_noise(len(t), rng))
    stamp = clock.to_ns(t0_ns, t)
    order = np.stack([np.zeros(len(stamp), np.int64), np.arange(len(stamp))], 1)
    writer.write_batch([(TWINTAC, stamp, streams.encode_tactile(stamp, "twintac", raw))], order)


@dataclass(frozen=True)
class _Layout:
    """When every message of a replay is sent (recording time, s) and which physics step it reads."""

    start_s: float  # recording time of physics time 0 (command 0 sent)
    times: dict[str, np.ndarray]  # per stream, sample times
    steps: dict[str, np.ndarray]  # per stream, the physics step (index of ``states`` / ``sensordata``) read
    order: np.ndarray  # (messages, 2): (stream index, sample index), in time order
    order_steps: np.ndarray  # physics step each message of ``order`` needs (non-decreasing)

    @classmethod
    def plan(cls, sim: SimConfig, n_steps: int, dt: float, rng: np.random.Generator) -> _Layout:
        start = rng.uniform(*COMMAND_START_S)
        end = start + n_steps * dt
        times = {name: clock.stamps(end, RATE_HZ[name], rng) for name in (TWINTAC, FSR, JOINT_STATES)}
        n_commands = -(-n_steps // sim.substeps)
        times[JOINT_TARGETS] = (
            start + np.arange(n_commands) * sim.control_dt + rng.uniform(0.0, COMMAND_JITTER_S, n_commands)
        )
        steps = {
            name: np.clip(np.floor((t - start) / dt).astype(np.int64), 0, n_steps - 1) for name, t in times.items()
        }
        stream = np.concatenate([np.full(len(times[n]), i) for i, n in enumerate(_STREAMS)])
        sample = np.concatenate([np.arange(len(times[n])) for n in _STREAMS])
        at = np.concatenate([times[n] for n in _STREAMS])
        order = np.lexsort((stream, at))
        needs = np.concatenate([steps[n] for n in _STREAMS])[order]
        return cls(start, times, steps, np.stack([stream[order], sample[order]], 1), needs)


def _write_replay(
    writer: RecordingWriter,
    physics: _Physics,
    layout: _Layout,
    cmd: _Commands,
    rig: TwinModel,
    twintac: TwinTac,
    fsr: PalmFsr,
    scene: Scene,
    t0_ns: int,
    rng: np.random.Generator,
) -> np.ndarray:
    """Write the replay's messages in time order, each chunk as soon as its physics is done; returns the
    region forces (N) at the 100 Hz TwinTac samples."""
    model = rig.model
    nq = model.nq
    times, steps = layout.times, layout.steps
    n_tt, n_fsr, n_js = (len(times[name]) for name in (TWINTAC, FSR, JOINT_STATES))
    offset, white = twintac.recording_offset(rng), twintac.white_noise(n_tt, rng)
    fsr_factor = fsr.noise_factor(n_fsr, rng)
    encoder_noise = rng.normal(0.0, rig.encoder_noise_rad, (n_js, len(scene.hand_qpos)))
    last = len(cmd.joint_target) - 1
    sent = np.minimum(np.arange(len(times[JOINT_TARGETS])), last)
    stamp = {name: clock.to_ns(t0_ns, t) for name, t in times.items()}
    region_force = np.empty((n_tt, len(scene.region_sensors)))

    def messages(stream: str, lo: int, hi: int) -> np.ndarray:
        """Encoded messages ``lo:hi`` of a stream (their physics is done), one a row."""
        j = steps[stream][lo:hi]
        s = stamp[stream][lo:hi]
        if stream == TWINTAC:
            force = physics.sensordata[j][:, scene.region_sensors]
            region_force[lo:hi] = force
            return streams.encode_tactile(
                s, "twintac", twintac.read(force[:, :4], times[stream][lo:hi], offset, white[lo:hi])
            )
        if stream == FSR:
            force = physics.sensordata[j][:, scene.region_sensors[4:]]
            return streams.encode_tactile(s, "fsr_palm", fsr.read(force, fsr_factor[lo:hi]))
        if stream == JOINT_STATES:
            state = physics.states[j]
            q = state[:, 1 + scene.hand_qpos]
            qdot = state[:, 1 + nq + scene.hand_dof]
            effort = _effort(model, physics.control[j, : model.nu], q, qdot)
            return streams.encode_joint_state(s, "leap", RIG.robot.joint_names, q + encoder_noise[lo:hi], qdot, effort)
        return streams.encode_joint_state(s, "leap", RIG.robot.joint_names, cmd.joint_target[sent[lo:hi]])

    targets = _STREAMS.index(JOINT_TARGETS)
    reference = len(_STREAMS)  # the reference time, published right after each command
    written = pieces = 0
    cursor = np.zeros(len(_STREAMS), dtype=np.int64)
    while written < len(layout.order):
        if pieces == len(physics.bounds) - 1:
            writer.flush()  # compressed while the last piece of physics runs, not after it
        end = int(np.searchsorted(layout.order_steps, physics.ready(), side="left"))
        pieces += 1
        chunk = layout.order[written:end]
        upto = cursor + np.bincount(chunk[:, 0], minlength=len(_STREAMS))
        batch = [
            (name, stamp[name][cursor[i] : upto[i]], messages(name, int(cursor[i]), int(upto[i])))
            for i, name in enumerate(_STREAMS)
        ]
        lo, hi = int(cursor[targets]), int(upto[targets])
        sent_at = stamp[JOINT_TARGETS][lo:hi]
        batch.append((REFERENCE_TIME, sent_at, streams.encode_reference_time(sent_at, "leap", cmd.t_ref[sent[lo:hi]])))
        # rows relative to the batch; each command's reference time follows it
        is_command = chunk[:, 0] == targets
        relative = np.stack([chunk[:, 0], chunk[:, 1] - cursor[chunk[:, 0]]], 1)
        order = np.repeat(relative, 1 + is_command, axis=0)
        order[np.cumsum(1 + is_command)[is_command] - 1, 0] = reference
        writer.write_batch(batch, order)
        cursor, written = upto, end
    return region_force
