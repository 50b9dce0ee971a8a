"""The hardware twin: scripted grasp rollouts (real physics) replayed on the twin, written as MCAPs, taken
through the real ingest and contact extraction, and compared with the rollouts' own sim contacts."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import pyarrow as pa
import pytest
from conftest import scripted_rollout_rows
from mujoco import rollout as mj_rollout
from pydantic import ValidationError

from schemas.messages import LEAP_JOINT_NAMES
from schemas.rig import DEFAULT_RIG
from schemas.tables import ROBOT_REGIONS
from schemas.vocabulary import Method, RecordingKind
from touch2robot.contacts import ContactsConfig
from touch2robot.contacts.extract import replay_contacts
from touch2robot.ingest import ingest_file, link_replays, read_recording, recording_rows
from touch2robot.metrics import ContactScores, contact_scores
from touch2robot.recording import cdr
from touch2robot.sim.config import SimConfig
from touch2robot.sim.env import CONTROL_SPEC
from touch2robot.sim.guard import LostPhysicsError
from touch2robot.sim.scene import home_joint_targets
from touch2robot.twin import streams
from touch2robot.twin.config import TwinConfig
from touch2robot.twin.replay import (
    ReplayOutcome,
    ReplayRequest,
    _Physics,
    _PhysicsWorker,
    replay_rollout,
    replay_rollouts,
    twin_physics,
)

SIM = SimConfig(threads=1)
TASKS = ("pick", "drawer")
ROLLOUTS = 3


@pytest.fixture(scope="module")
def rollouts() -> dict[str, list[pa.Table]]:
    """Per task, three scripted grasps (60 control steps: reach, grasp, lift or pull), one table each."""
    out: dict[str, list[pa.Table]] = {}
    for task in TASKS:
        rows = scripted_rollout_rows(task, Method.TOUCH2ROBOT, ROLLOUTS, 60)
        ids = np.asarray(rows["rollout_id"].to_pylist())
        out[task] = [rows.filter(pa.array(ids == rid)) for rid in sorted(set(ids))]
    return out


def _metadata(task: str) -> dict[str, str]:
    return {
        "task": task,
        "subject": "s00",
        "method": Method.TOUCH2ROBOT,
        "reference_recording": f"{task}_s00_d01_glove.mcap",
        "calibration_recording": "calibration.mcap",
        "rig": DEFAULT_RIG.name,
    }


def _replay(rows: pa.Table, twin: TwinConfig, seed: int | list[int], folder: Path) -> ReplayOutcome:
    folder.mkdir(parents=True, exist_ok=True)
    task = rows["task"][0].as_py() if rows.num_rows else "pick"
    return replay_rollout(rows, SIM, twin, seed, folder / "replay.mcap", folder / "calibration.mcap", _metadata(task))


def _measured(outcome: ReplayOutcome, folder: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ingest both files with the project's ingest and extract the replay's real contacts; returns per
    region (region order of ROBOT_REGIONS) the sample reference times and contacts, and the FSR values."""
    lake = folder / "lake"
    for path in (outcome.calibration_path, outcome.replay_path):
        result = ingest_file(path, lake)
        assert result.status in ("ingested", "unchanged"), result.reason
    _, links, problems = link_replays(recording_rows(lake).to_pylist())
    assert not problems and len(links) == 1
    link = links[0]
    rows, _ = replay_contacts(lake, link.replay, link.calibration_id, None, ContactsConfig())
    region = np.asarray(rows["region"].to_pylist())
    t_ref = rows["t_ref"].to_numpy()
    contact = rows["contact"].to_numpy(zero_copy_only=False)
    return region, t_ref, contact


def _fidelity(rows: pa.Table, outcome: ReplayOutcome, folder: Path) -> ContactScores:
    """Tactile fidelity of a rollout against its replay: reference = the twin's measured contacts, evaluated =
    the rollout's own sim contacts (region force > 0.5 N) per control step, each compared with the last
    measured sample at or before its reference time."""
    region, t_ref, contact = _measured(outcome, folder)
    rows = rows.sort_by("step")
    sim_contact = np.array(rows["region_force"].to_pylist()) > SIM.contact_threshold_n
    step_t_ref = rows["t_ref"].to_numpy()
    reference = np.zeros_like(sim_contact)
    for k, name in enumerate(ROBOT_REGIONS):
        times, values = t_ref[region == name], contact[region == name]
        at = np.searchsorted(times, step_t_ref, side="right") - 1
        reference[:, k] = np.where(at >= 0, values[np.maximum(at, 0)], False)
    return contact_scores(reference, sim_contact)


def _pooled(scores: list[ContactScores]) -> float:
    tp = sum(s.tp for s in scores)
    return 2 * tp / (2 * tp + sum(s.fp for s in scores) + sum(s.fn for s in scores))


def _with_column(rows: pa.Table, name: str, values: np.ndarray) -> pa.Table:
    width = values.shape[1]
    column = pa.FixedSizeListArray.from_arrays(pa.array(values.reshape(-1)), width)
    return rows.set_column(rows.column_names.index(name), name, column)


def test_nominal_twin_reproduces_the_sim_contacts(rollouts, tmp_path):
    """Every perturbation zero: the replay measures (TwinTac thresholds from its calibration, FSR > 0) the
    contacts the rollout had in simulation."""
    scores = []
    for task in TASKS:
        for i, rows in enumerate(rollouts[task]):
            folder = tmp_path / f"{task}{i}"
            outcome = _replay(rows, TwinConfig.nominal(), i, folder)
            assert outcome.perturbation["latency_s"] == 0.0 and outcome.perturbation["kp_scale.if_mcp"] == 1.0
            scores.append(_fidelity(rows, outcome, folder))
    assert _pooled(scores) >= 0.95, [round(s.f1, 3) for s in scores]


@pytest.mark.parametrize("broken", ["fingers_open", "wrist_lifted"])
def test_a_broken_trajectory_measures_no_contact(rollouts, tmp_path, broken):
    """What a scripted result would get wrong: the same rollout with its fingers held open, or its wrist
    15 cm above the object, does not touch the object on the twin, so its sim contacts find no support."""
    scores, touched = [], []
    for i, rows in enumerate(rollouts["pick"]):
        if broken == "fingers_open":
            broken_rows = _with_column(rows, "joint_target", np.tile(home_joint_targets(), (rows.num_rows, 1)))
        else:
            wrist = np.array(rows["wrist_pose"].to_pylist())
            wrist[:, 2] += 0.15
            broken_rows = _with_column(rows, "wrist_pose", wrist)
        folder = tmp_path / f"{broken}{i}"
        outcome = _replay(broken_rows, TwinConfig(), i, folder)
        touched.append(_measured(outcome, folder)[2].mean())
        scores.append(_fidelity(rows, outcome, folder))
    supported = sum(s.tp for s in scores) / sum(s.tp + s.fp for s in scores)
    assert _pooled(scores) < 0.2 and supported < 0.2, [round(s.f1, 3) for s in scores]
    # in the air the closing hand still presses a fingertip on itself (self-contact, which TwinTac feels too)
    assert max(touched) < (0.02 if broken == "fingers_open" else 0.2), touched


def test_default_twin_perturbs_and_still_agrees(rollouts, tmp_path):
    """A perturbed twin (default ranges) measures contacts that agree substantially with the sim's (not
    exactly: friction, gains, latency and sensors differ), with every drawn value reported and seeded."""
    scores, nominal_scores = [], []
    for task in TASKS:
        for i, rows in enumerate(rollouts[task]):
            outcome = _replay(rows, TwinConfig(), i, tmp_path / f"{task}{i}")
            scores.append(_fidelity(rows, outcome, tmp_path / f"{task}{i}"))
            nominal = _replay(rows, TwinConfig.nominal(), i, tmp_path / f"n{task}{i}")
            nominal_scores.append(_fidelity(rows, nominal, tmp_path / f"n{task}{i}"))
            drawn = outcome.perturbation
            assert drawn["hand_friction_scale"] != 1.0 and drawn["kp_scale.th_cmc"] != 1.0
            assert drawn.keys() == nominal.perturbation.keys()
            assert outcome.peak_region_force != nominal.peak_region_force
    # measured on this data: 0.88..0.94 per rollout (nominal 0.95..1.0)
    assert _pooled(scores) >= 0.7, [round(s.f1, 3) for s in scores]
    assert _pooled(scores) < _pooled(nominal_scores)


def test_same_seed_same_files_other_seed_other_rig(rollouts, tmp_path):
    rows = rollouts["drawer"][0]
    first = _replay(rows, TwinConfig(), [7, 1], tmp_path / "a")
    again = _replay(rows, TwinConfig(), [7, 1], tmp_path / "b")
    other = _replay(rows, TwinConfig(), [7, 2], tmp_path / "c")
    assert first.replay_path.read_bytes() == again.replay_path.read_bytes()
    assert first.calibration_path.read_bytes() == again.calibration_path.read_bytes()
    assert first.perturbation == again.perturbation
    assert first.replay_path.read_bytes() != other.replay_path.read_bytes()
    changed = [k for k in first.perturbation if first.perturbation[k] != other.perturbation[k]]
    assert len(changed) > 0.9 * len(first.perturbation)


def test_recordings_follow_the_contract(rollouts, tmp_path):
    """Topics, rates, array lengths and metadata as the rig writes them; the time map carries the rollout's
    reference times; the calibration is the same sensor set, unloaded."""
    rows = rollouts["pick"][1]
    twin = TwinConfig()
    outcome = _replay(rows, twin, 3, tmp_path)
    replay, calibration = read_recording(outcome.replay_path), read_recording(outcome.calibration_path)
    assert replay.kind == RecordingKind.ROBOT_REPLAY and calibration.kind == RecordingKind.ROBOT_CALIBRATION
    assert {k: replay.metadata[k] for k in _metadata("pick")} == _metadata("pick")
    assert calibration.metadata["rig"] == DEFAULT_RIG.name and calibration.metadata["sensor"] == "twintac"
    duration = (replay.end_ns - replay.start_ns) / 1e9
    assert duration == pytest.approx(outcome.duration_s, abs=0.06)
    assert outcome.steps == 60 * SIM.substeps + round(outcome.perturbation["latency_s"] / SIM.timestep) + 50
    for topic, rate in [
        ("/twintac/raw", 100),
        ("/fsr/palm", 50),
        ("/leap/joint_states", 50),
        ("/leap/joint_targets", 20),
        ("/replay/reference_time", 20),
    ]:
        assert replay.message_counts[topic] == pytest.approx(rate * duration, abs=2), topic
    assert calibration.message_counts["/twintac/raw"] == pytest.approx(100 * twin.calibration_s, abs=2)
    t_ref = replay.topics["/replay/reference_time"].fields["reference_time"][:, 0]
    expected = rows.sort_by("step")["t_ref"].to_numpy()
    assert np.array_equal(t_ref[: len(expected)], expected) and (t_ref[len(expected) :] == expected[-1]).all()
    targets = replay.topics["/leap/joint_targets"].fields["position"]
    assert np.allclose(targets[: len(expected)], np.array(rows.sort_by("step")["joint_target"].to_pylist()))
    states = replay.topics["/leap/joint_states"].fields
    assert all(states[name].shape[1] == len(LEAP_JOINT_NAMES) for name in ("position", "velocity", "effort"))
    assert np.abs(states["effort"]).max() <= 0.2196 * 1.2 + 1e-9  # the torque limit, at most +20 %
    # same TwinTac set: the calibration's level and the replay's unloaded start agree to within the offset drift
    replay_tt = replay.topics["/twintac/raw"].fields["values"]
    calibration_tt = calibration.topics["/twintac/raw"].fields["values"]
    assert np.abs(replay_tt[:5].mean(0) - calibration_tt.mean(0)).max() < 30
    assert calibration_tt.std(0).max() < 12
    assert replay.start_ns > calibration.end_ns
    assert max(outcome.contact_fraction[:4]) > 0.2 and max(outcome.peak_region_force) > 1.0


def test_physics_in_chunks_equals_one_rollout(rollouts):
    """The replay steps its physics in chunks with the warm start carried over: the same states as MuJoCo's
    rollout over every step in one call (what the bench's ceiling runs)."""
    prepared = twin_physics(rollouts["pick"][0], SIM, TwinConfig(), 5)
    model, control = prepared.rig.model, prepared.control
    with mj_rollout.Rollout(nthread=0) as pool:
        state, sensordata = pool.rollout(
            model, mujoco.MjData(model), prepared.initial_state[None], control[None], control_spec=CONTROL_SPEC
        )
    worker = _PhysicsWorker()
    try:
        physics = _Physics("pick", model, worker.data("pick", SIM, model), prepared.initial_state, control)
        worker.submit(physics)
        while physics.ready() < len(control):
            pass
    finally:
        worker.close()
    assert np.array_equal(physics.states[1:], state[0]) and np.array_equal(physics.sensordata, sensordata[0])


def test_a_batch_writes_what_each_replay_alone_writes_and_a_bad_one_stops_none(rollouts, tmp_path):
    """``replay_rollouts`` (the replay stage's batches: one replay's physics while the one before is written)
    writes byte for byte the files of ``replay_rollout`` one by one; rows that are no rollout and a rollout that
    loses physics come back as their errors, in place, and the replays after them are written all the same."""
    good = [*rollouts["pick"][:2], rollouts["drawer"][0]]
    targets = np.array(good[0]["joint_target"].to_pylist())
    targets[30:] = np.nan
    lost = _with_column(good[0], "joint_target", targets)
    batch = [good[0], good[0].slice(0, 0), good[1], lost, good[2]]

    def request(k: int, rows: pa.Table, folder: Path) -> ReplayRequest:
        task = rows["task"][0].as_py() if rows.num_rows else "pick"
        return ReplayRequest(rows, [3, k], folder / f"replay{k}.mcap", folder / f"calib{k}.mcap", _metadata(task))

    (tmp_path / "batch").mkdir()
    requests = [request(k, rows, tmp_path / "batch") for k, rows in enumerate(batch)]
    together = list(replay_rollouts(requests, SIM, TwinConfig()))
    assert [type(o).__name__ for o in together] == [
        "ReplayOutcome",
        "ValueError",
        "ReplayOutcome",
        "LostPhysicsError",
        "ReplayOutcome",
    ]
    assert sorted(p.name for p in (tmp_path / "batch").iterdir()) == [
        f"{kind}{k}.mcap" for kind in ("calib", "replay") for k in (0, 2, 4)
    ]
    (tmp_path / "alone").mkdir()
    for k in (0, 2, 4):
        alone = request(k, batch[k], tmp_path / "alone")
        outcome = replay_rollout(
            alone.rollout, SIM, TwinConfig(), alone.seed, alone.replay_path, alone.calibration_path, alone.metadata
        )
        batched = together[k]
        assert isinstance(batched, ReplayOutcome)
        assert outcome == replace(batched, replay_path=alone.replay_path, calibration_path=alone.calibration_path)
        for name in (f"replay{k}.mcap", f"calib{k}.mcap"):
            assert (tmp_path / "alone" / name).read_bytes() == (tmp_path / "batch" / name).read_bytes()


def test_lost_physics_raises_and_leaves_no_files(rollouts, tmp_path):
    rows = rollouts["pick"][0]
    targets = np.array(rows["joint_target"].to_pylist())
    targets[30:] = np.nan
    with pytest.raises(LostPhysicsError, match="pick: env 0 at t = "):
        _replay(_with_column(rows, "joint_target", targets), TwinConfig(), 0, tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_batch_encoding_is_byte_identical_to_the_message_encoders():
    rng = np.random.default_rng(0)
    stamps = 1_767_225_600 * 10**9 + np.cumsum(rng.integers(1, 10**9, 5))
    values, position = rng.normal(size=(5, 16)), rng.normal(size=(5, 16, 3))
    assert [row.tobytes() for row in streams.encode_tactile(stamps, "twintac", values)] == [
        cdr.encode_tactile(int(s), "twintac", v) for s, v in zip(stamps, values, strict=True)
    ]
    assert [row.tobytes() for row in streams.encode_reference_time(stamps, "leap", values[:, 0])] == [
        cdr.encode_reference_time(int(s), "leap", float(v)) for s, v in zip(stamps, values[:, 0], strict=True)
    ]
    p, v, e = position[..., 0], position[..., 1], position[..., 2]
    assert [row.tobytes() for row in streams.encode_joint_state(stamps, "leap", LEAP_JOINT_NAMES, p, v, e)] == [
        cdr.encode_joint_state(int(s), "leap", LEAP_JOINT_NAMES, *x) for s, *x in zip(stamps, p, v, e, strict=True)
    ]
    assert [row.tobytes() for row in streams.encode_joint_state(stamps, "leap", LEAP_JOINT_NAMES, p)] == [
        cdr.encode_joint_state(int(s), "leap", LEAP_JOINT_NAMES, x) for s, x in zip(stamps, p, strict=True)
    ]


@pytest.mark.parametrize(
    ("values", "field"),
    [
        ({"kp_scale": (0.1, 1.0)}, "kp_scale"),
        ({"latency_s": (0.03, 0.01)}, "latency_s"),
        ({"twintac_noise_counts": (2.0, 500.0)}, "twintac_noise_counts"),
        ({"object_com_offset_m": -0.001}, "object_com_offset_m"),
        ({"calibration_s": 0.0}, "calibration_s"),
        ({"fsr_activation": (0.1, 0.2)}, "fsr_activation"),
    ],
)
def test_twin_config_rejects_values_out_of_range(values, field):
    with pytest.raises(ValidationError, match=field):
        TwinConfig(**values)


def test_bad_rollouts_are_refused_naming_the_problem(rollouts, tmp_path):
    rows = rollouts["pick"][0]
    with pytest.raises(ValueError, match="empty"):
        _replay(rows.slice(0, 0), TwinConfig(), 0, tmp_path)
    unknown = rows.set_column(rows.column_names.index("task"), "task", pa.array(["juggle"] * rows.num_rows))
    with pytest.raises(ValueError, match="unknown task 'juggle'"):
        _replay(unknown, TwinConfig(), 0, tmp_path)
    with pytest.raises(ValueError, match="one rollout"):
        _replay(pa.concat_tables(rollouts["pick"][:2]), TwinConfig(), 0, tmp_path)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("task", ["wipe", "rotate"])
def test_the_objects_friction_draw_scales_its_own_friction_on_the_table(task):
    """Wipe's sponge has its own friction on the table (the table's geom, which wins that contact): the
    rig's object-friction draw scales it with the sponge's; a task at MuJoCo's max rule keeps its table."""
    from touch2robot.sim.scene import build_scene
    from touch2robot.twin.model import perturb

    sim = SimConfig(threads=1)
    scene = build_scene(task, sim)
    twin = TwinConfig.nominal().model_copy(update={"friction_scale": (1.5, 1.5)})
    rig = perturb(scene, twin, sim.timestep, np.random.default_rng(0), mujoco.MjData(scene.model))
    table = scene.model.geom("table").id
    scale = rig.model.geom_friction[table, 0] / scene.model.geom_friction[table, 0]
    assert rig.perturbation["object_friction_scale"] == 1.5
    assert scale == pytest.approx(1.5 if scene.spec.object.table_friction is not None else 1.0)
