"""Student retargeter: demonstration split, paired and augmented sequences, distillation that
learns and resumes, streaming = batched inference, execution in MuJoCo that reproduces a
teacher from its own commands, and the `student` flow end to end (smoke profile)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
import torch

from schemas.tables import unseeded
from touch2robot import lake as lake_io
from touch2robot.datasets import with_seed
from touch2robot.ingest import recording_rows
from touch2robot.settings import DataLayout
from touch2robot.sim.config import SimConfig
from touch2robot.sim.env import BatchEnv
from touch2robot.sim.scene import build_scene
from touch2robot.student import StudentConfig
from touch2robot.student.augment import augment, paired_sequences, per_task_counts, split_demonstrations
from touch2robot.student.execute import execute
from touch2robot.student.features import reference_inputs, wrist_residual
from touch2robot.student.infer import StreamingStudent, StudentOutput, predict_recording
from touch2robot.student.model import ServingStudent, StudentNet
from touch2robot.student.train import CHECKPOINT, train, windows_from_table
from touch2robot.teachers import rollouts as ro
from touch2robot.teachers.config import TeacherConfig
from touch2robot.teachers.objective import NUM_ACTIONS, DemoTracking, stack_references
from touch2robot.teachers.reference import load_reference

TEACHER = TeacherConfig(sim=SimConfig(n_envs=2, threads=1))
TINY = StudentConfig(
    augmented_rollouts=16,
    d_model=32,
    ff_dim=64,
    pointnet_hidden=(32,),
    batch_size=16,
    steps=60,
    lr=1e-3,
    eval_interval=20,
    checkpoint_interval=30,
)
TASKS = ["drawer", "pick", "rotate", "wipe"]


FINGER_OFFSET_RAD, WRIST_DROP_M = 0.05, 0.01


def scripted_teacher(obs: dict[str, np.ndarray]) -> np.ndarray:
    """A stand-in teacher with a learnable rule: fingers 0.05 rad beyond the kinematic
    reference, wrist 1 cm lower."""
    a = np.zeros((len(obs["actor"]), NUM_ACTIONS))
    a[:, :16] = FINGER_OFFSET_RAD / TEACHER.action_scale
    a[:, 18] = -WRIST_DROP_M / TEACHER.wrist_pos_scale_m
    return a


@pytest.fixture(scope="module")
def student_lake(demo_lake: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The demo lake plus two rollouts per task of the scripted teacher, written as the
    teachers flow writes touch2robot's (origin teacher)."""
    root = tmp_path_factory.mktemp("student") / "data"
    shutil.copytree(demo_lake, root)
    lake = DataLayout(root).lake
    for rec in recording_rows(lake).to_pylist():
        refs = stack_references([load_reference(lake, rec)])
        env = BatchEnv(build_scene(rec["task"], TEACHER.sim), TEACHER.sim, 2)
        rows, contacts = ro.record(
            env, DemoTracking(refs, TEACHER, "touch2robot"), scripted_teacher, "touch2robot", "teacher"
        )
        env.close()
        rows, contacts = with_seed(rows, 0), with_seed(contacts, 0)
        lake_io.write_rows(lake, "rollouts", f"teacher-{rec['task']}-seed0", rows, {"method": "touch2robot"})
        contacts_id = "teacher-touch2robot-seed0"
        lake_io.write_rows(lake, "contacts", contacts_id, contacts, {"source": "sim", "task": rec["task"]})
    return root


@pytest.fixture(scope="module")
def references(student_lake: Path) -> dict:
    lake = DataLayout(student_lake).lake
    return {r["recording_id"]: load_reference(lake, r) for r in recording_rows(lake).to_pylist()}


def _teacher_rows(root: Path, task: str) -> pa.Table:
    return pq.read_table(
        lake_io.file_path(DataLayout(root).lake, "rollouts", f"teacher-{task}-seed0", {"method": "touch2robot"})
    )


@pytest.fixture(scope="module")
def dataset(student_lake: Path, references: dict) -> pa.Table:
    """All four tasks' sequences; pick's demonstration validates, the others train."""
    tables = []
    for task in TASKS:
        seqs = paired_sequences(_teacher_rows(student_lake, task), references, 0.5)
        table = augment(seqs, 4, 0.1, 0, val=seqs)
        tables.append(table.filter(pc.equal(table["split"], "val" if task == "pick" else "train")))  # pyright: ignore[reportAttributeAccessIssue]
    return pa.concat_tables(tables)


# ---------------------------------------------------------------- split and augmentation
def test_split_is_by_demonstration_and_flags_in_sample() -> None:
    demos = {"pick": [f"p{i}" for i in range(8)], "wipe": [f"w{i}" for i in range(8)]}
    s = split_demonstrations(demos, 0.25, 0.2, seed=0)
    for task, ids in demos.items():
        parts = [set(s.train[task]), set(s.val[task]), set(s.held_out[task])]
        assert sum(len(p) for p in parts) == len(ids) and set().union(*parts) == set(ids)
        assert (len(s.held_out[task]), len(s.val[task])) == (2, 1)
    assert not s.in_sample
    assert split_demonstrations(demos, 0.25, 0.2, seed=0) == s
    one = split_demonstrations({"pick": ["a"], "wipe": ["b"]}, 0.25, 0.2, seed=0)
    assert one.in_sample and one.held_out == {"pick": ["a"], "wipe": ["b"]}
    assert sum(map(len, one.val.values())) == 1 and sum(map(len, one.train.values())) == 1


def test_paired_steps_follow_the_teacher(student_lake: Path, references: dict) -> None:
    rows = _teacher_rows(student_lake, "wipe")
    seq = paired_sequences(rows, references, 0.5)[0]
    first = rows.filter(pc.equal(rows["rollout_id"], seq.source_rollout_id))  # pyright: ignore[reportAttributeAccessIssue]
    target = ro.column(first, "joint_target")
    # step j pairs frame j's kinematic joints with the command of row j - 1 (aimed at frame j)
    np.testing.assert_allclose(seq.target_joints, target[:-1])
    np.testing.assert_allclose(seq.joints, ro.column(first, "reference_joints")[1:])
    np.testing.assert_allclose(
        seq.target_joints - seq.joints, FINGER_OFFSET_RAD, atol=1e-5
    )  # the scripted teacher's rule
    np.testing.assert_array_equal(seq.contact, ro.column(first, "region_force")[1:] > 0.5)
    np.testing.assert_allclose(
        wrist_residual(seq.wrist_pose, seq.target_wrist)[:, :3], [[0, 0, -WRIST_DROP_M]] * len(seq.step), atol=1e-9
    )


def test_augmentation_shares_the_noise_and_is_seeded(student_lake: Path, references: dict) -> None:
    seqs = paired_sequences(_teacher_rows(student_lake, "drawer"), references, 0.5)
    table = augment(seqs, 7, 0.1, seed=3)
    assert table.schema == unseeded("student_dataset")  # the stage adds the sweep seed
    ids = table["sample_id"].unique().to_pylist()
    assert len(ids) == 7 and table["augment"].to_pylist()[-1] == 3  # 2 unchanged, then copies
    inputs, targets = ro.column(table, "kinematic_joints"), ro.column(table, "target_joints")
    augmented = pc.greater(table["augment"], 0).to_numpy(zero_copy_only=False)  # pyright: ignore[reportAttributeAccessIssue]
    noise = inputs - np.concatenate([seqs[0].joints, seqs[1].joints] * 4)[: len(inputs)]
    assert not augmented[: 2 * len(seqs[0].step)].any()
    assert 0.08 < noise[augmented].std() < 0.12 and np.abs(noise[~augmented]).max() < 1e-6
    # frame-wise correspondence holds: input and target share the noise, so their difference is the teacher's
    # (the scripted 0.05 rad, less where a target met its joint limit)
    offset = np.concatenate([s.target_joints - s.joints for s in seqs] * 4)[: len(inputs)]
    np.testing.assert_allclose(targets - inputs, offset, atol=1e-5)
    assert np.mean(np.isclose(offset, FINGER_OFFSET_RAD, atol=1e-5)) > 0.9
    assert augment(seqs, 7, 0.1, seed=3).equals(table)
    assert per_task_counts(400, TASKS) == {"pick": 100, "rotate": 100, "wipe": 100, "drawer": 100}
    assert sum(per_task_counts(10, ["pick", "wipe", "drawer"]).values()) == 10


# ---------------------------------------------------------------- model and training
def _clouds() -> torch.Tensor:
    return torch.as_tensor(np.stack([build_scene(t).point_cloud for t in TASKS]), dtype=torch.float32)


@pytest.fixture(scope="module")
def trained(dataset: pa.Table, tmp_path_factory: pytest.TempPathFactory):
    torch.set_num_threads(1)
    part = lambda s: windows_from_table(dataset.filter(pc.equal(dataset["split"], s)), TASKS, TINY.history)  # noqa: E731  # pyright: ignore[reportAttributeAccessIssue]
    folder = tmp_path_factory.mktemp("student-ckpt")
    logged: dict[int, dict[str, float]] = {}

    def log(step: int, metrics: dict[str, float]) -> None:
        logged.setdefault(step, metrics)

    result = train(
        part("train"),
        part("val"),
        _clouds(),
        TINY,
        folder,
        on_log=log,
    )
    return result, part, folder, logged


def test_training_lowers_the_validation_loss(trained) -> None:
    result, _, _, _ = trained
    assert result.steps == TINY.steps and result.resumed_from == 0
    assert result.final_val["loss"] < 0.7 * result.initial_val["loss"]
    assert [c["step"] for c in result.curve] == [0, 20, 40, 60]


def test_training_resumes_from_its_checkpoint(trained, tmp_path: Path) -> None:
    result, part, folder, _ = trained
    shutil.copytree(folder, tmp_path / "run")
    longer = TINY.model_copy(update={"steps": 80})
    resumed = train(part("train"), part("val"), _clouds(), longer, tmp_path / "run")
    assert resumed.resumed_from == 60 and resumed.steps == 80
    assert resumed.initial_val == result.initial_val and [c["step"] for c in resumed.curve] == [0, 20, 40, 60, 80]


def test_a_training_stopped_midway_resumes_to_the_one_never_stopped(trained, tmp_path: Path) -> None:
    """``should_stop`` at update 25 (between validations and checkpoints): the call checkpoints
    there and returns; resumed, it ends with the uninterrupted training's weights and logs the
    same figures, the train loss of the interrupted window included."""
    result, part, _, logged = trained
    updates = iter(range(1, TINY.steps + 1))
    folder = tmp_path / "run"
    stopped = train(part("train"), part("val"), _clouds(), TINY, folder, should_stop=lambda: next(updates) >= 25)
    assert stopped.steps == 25 and torch.load(folder / CHECKPOINT, weights_only=False)["step"] == 25
    resumed_log: dict[int, dict[str, float]] = {}

    def log_resumed(step: int, metrics: dict[str, float]) -> None:
        resumed_log.setdefault(step, metrics)

    resumed = train(
        part("train"),
        part("val"),
        _clouds(),
        TINY,
        folder,
        on_log=log_resumed,
    )
    assert resumed.resumed_from == 25 and resumed.steps == TINY.steps
    assert resumed_log == {step: logged[step] for step in (40, 60)}
    assert resumed.curve == result.curve
    expected = result.net.state_dict()
    assert [k for k, v in resumed.net.state_dict().items() if not torch.equal(v, expected[k])] == []


def test_streaming_equals_batched_inference(trained, references: dict) -> None:
    net = trained[0].net
    ref = next(r for r in references.values() if r.task == "rotate")
    inputs, points = reference_inputs(ref), build_scene("rotate").point_cloud
    batched = predict_recording(net, inputs, points, batch=37)
    for compiled in (True, False):  # the frozen TorchScript trace (the default) and the eager modules
        streamed = StreamingStudent(net, points, compiled=compiled).run(inputs)
        for a, b in (
            (batched.joints, streamed.joints),
            (batched.wrist_residual, streamed.wrist_residual),
            (batched.contact_logits, streamed.contact_logits),
        ):
            np.testing.assert_allclose(a, b, atol=1e-5)
    # the served single-tensor form gives the newest step of the same window
    window = np.concatenate([np.repeat(inputs[:1], net.history - 5, axis=0), inputs[:5]])
    packed = torch.as_tensor(np.concatenate([window.ravel(), points.ravel()])[None], dtype=torch.float32)
    with torch.inference_mode():
        served = StudentOutput.from_raw(ServingStudent(net, len(points))(packed).numpy())
    np.testing.assert_allclose(served.joints[0], batched.joints[4], atol=1e-5)


def test_ablation_switches_change_what_the_model_sees(references: dict) -> None:
    ref = next(r for r in references.values() if r.task == "pick")
    x = torch.as_tensor(reference_inputs(ref)[None, :16])
    points = torch.as_tensor(build_scene("pick").point_cloud[None], dtype=torch.float32)
    blind = reference_inputs(ref, tactile=False)[None, :16]
    for name, same_without_glove in (("no_tactile", True), ("full", False)):
        torch.manual_seed(0)
        net = StudentNet(TINY.variant(name)).eval()
        with torch.inference_mode():
            a, b = net(x, net.geometry(points)), net(torch.as_tensor(blind), net.geometry(points))
        assert torch.allclose(a, b) == same_without_glove, name
    assert not torch.any(StudentNet(TINY.variant("no_geometry")).geometry(points))
    assert TINY.variant("no_dropout").tactile_dropout == 0 and TINY.variant("full") is TINY
    with pytest.raises(KeyError, match="no_such"):
        TINY.variant("no_such")


# ---------------------------------------------------------------- execution
def test_executing_the_teachers_own_commands_reproduces_its_rollout(student_lake: Path, references: dict) -> None:
    """A perfect student (its outputs = the teacher's commands) executed through the student
    path gives the teacher's trajectory back: the conversion to teacher actions is exact."""
    rows = _teacher_rows(student_lake, "pick")
    seq = paired_sequences(rows, references, 0.5)[0]
    ref = references[seq.reference_id]
    T = ref.length
    joints, wrist = np.repeat(ref.joints[:1], T, axis=0), np.zeros((T, 6))
    joints[seq.step] = seq.target_joints
    wrist[seq.step] = wrist_residual(seq.wrist_pose, seq.target_wrist)
    perfect = StudentOutput(joints, wrist, np.zeros((T, 8)))
    env = BatchEnv(build_scene("pick", TEACHER.sim), TEACHER.sim, 1)
    student_rows, contacts = execute(
        env, DemoTracking(stack_references([ref]), TEACHER, "touch2robot"), [perfect], TEACHER, "touch2robot"
    )
    env.close()
    teacher = rows.filter(pc.equal(rows["rollout_id"], seq.source_rollout_id))  # pyright: ignore[reportAttributeAccessIssue]
    assert student_rows.num_rows == teacher.num_rows and student_rows["origin"][0].as_py() == "student"
    np.testing.assert_allclose(
        ro.column(student_rows, "joint_position"), ro.column(teacher, "joint_position"), atol=1e-6
    )
    assert set(contacts["source"].to_pylist()) == {"reconstructed"}
    assert student_rows["rollout_id"][0].as_py() == "student-touch2robot-pick-000"


def test_reconstruction_runs_every_demonstration_and_scores_the_held_out_ones(
    trained, student_lake: Path, references: dict
) -> None:
    """The full model also turns trained-on demonstrations into robot ones (rollouts for the
    policy stage); contacts, predictions and figures cover only the evaluated (held-out) ones."""
    import dataclasses

    from touch2robot.student.execute import reconstruct_task

    ref = next(r for r in references.values() if r.task == "wipe")
    seen = dataclasses.replace(ref, recording_id="trained-on")
    teacher = _teacher_rows(student_lake, "wipe")
    both = reconstruct_task(
        trained[0].net, "wipe", [ref, seen], TEACHER, "touch2robot", "full", teacher, evaluated=[ref.recording_id]
    )
    alone = reconstruct_task(trained[0].net, "wipe", [ref], TEACHER, "touch2robot", "full", teacher)
    assert set(both.rollouts["reference_id"].to_pylist()) == {ref.recording_id, "trained-on"}
    for table in (both.contacts, both.predictions):
        assert set(table["reference_id"].to_pylist()) == {ref.recording_id}
    assert both.contacts.num_rows == alone.contacts.num_rows and both.figures == alone.figures
    assert np.isfinite(both.figures["joint_error_student"])
    with pytest.raises(ValueError, match="nobody"):
        reconstruct_task(trained[0].net, "wipe", [ref], TEACHER, "touch2robot", "full", evaluated=["nobody"])


# ---------------------------------------------------------------- the flow
@pytest.mark.slow
def test_student_flow_end_to_end(student_lake: Path, tmp_path: Path) -> None:
    """Smoke profile: dataset, four trained variants, in-sample reconstructions (one demo per
    task) in the lake, scored by the evaluation as source reconstructed; a re-run hits the cache."""
    import mlflow

    from flows.student import student
    from tasks import tracking
    from touch2robot.evaluate import contact_metrics_table, evaluated_sources, read_contacts

    root = tmp_path / "data"
    shutil.copytree(student_lake, root)
    layout = DataLayout(root)
    out = student(profile="smoke", data=str(root))
    trained = {t["variant"]: t for t in out["trained"]}
    assert set(trained) == {"full", "no_tactile", "no_geometry", "no_dropout"}
    # validation here is drawer's one demonstration, a task the smoke student never trains on, so
    # its loss may rise (it did in CI); learning is shown on a seen-task split by
    # test_training_lowers_the_validation_loss
    assert all(
        t["steps"] == 80 and np.isfinite([t["initial_val_loss"], t["final_val_loss"]]).all() for t in trained.values()
    )
    assert out["split"]["in_sample"] and {r["task"] for r in out["heldout"]} == set(TASKS)

    data = pa.concat_tables([pq.read_table(p) for p in lake_io.files(layout.lake, "student_dataset")])
    train_rows = data.filter(pc.equal(data["split"], "train"))  # pyright: ignore[reportAttributeAccessIssue]
    assert len(train_rows["sample_id"].unique()) == 16  # balanced over the 3 trained tasks; drawer validates
    for task in TASKS:
        assert lake_io.file_path(layout.lake, "rollouts", f"student-{task}-seed0", {"method": "touch2robot"}).is_file()
        assert lake_io.file_path(layout.lake, "student_predictions", f"touch2robot-{task}-seed0").is_file()
    assert "reconstructed" in evaluated_sources(layout.lake)
    metrics = contact_metrics_table(read_contacts(layout.lake, ["human", "reconstructed"]), "reconstructed")
    assert set(metrics["method"]) == {"touch2robot"} and metrics["n"].sum() > 0
    # every variant's per-demonstration sums, the full model's equal to the evaluation's own counts
    from touch2robot.evaluate import ablation_sums

    variants = pa.concat_tables([pq.read_table(p) for p in lake_io.files(layout.lake, "student_variants")]).to_pandas()
    assert set(variants["variant"]) == set(trained) and set(variants["method"]) == {"touch2robot"}
    overall = metrics[(metrics["task"] == "*") & (metrics["region"] == "*")].iloc[0]
    full_sums = variants[variants["variant"] == "full"]
    assert [int(full_sums[c].sum()) for c in ("tp", "fp", "fn", "tn")] == [
        int(overall[c]) for c in ("tp", "fp", "fn", "tn")
    ]
    assert set(ablation_sums(layout.lake)["variant"]) == {"no_tactile", "no_geometry", "no_dropout"}

    tracking.experiment(layout, "student")
    runs = mlflow.search_runs(experiment_names=["touch2robot/student"], output_format="list")
    assert len(runs) == 5 and all(r.data.tags["held_out"].startswith("in-sample") for r in runs)
    full = trained["full"]["mlflow_run"]
    assert any(k.startswith("heldout/pick/") for k in mlflow.get_run(full).data.metrics)
    model = mlflow.pyfunc.load_model(f"runs:/{full}/model")
    schema = model.metadata.get_input_schema()
    assert schema is not None
    example = np.zeros((2, schema.inputs[0].shape[1]), dtype=np.float32)
    assert model.predict(example).shape == (2, 30)

    again = student(profile="smoke", data=str(root))
    assert again["trained"] == out["trained"]
