"""Kinematic retargeting (touch2robot.retarget) on demonstrator recordings with ground truth:
fingertip residuals, agreement with the clean human motion, joint limits, continuity, per-frame
failure fallback, bad hand-motion input, and the Prefect flow on a tiny data folder.

Bounds (defaults: scaling 1.15, 10 Hz low-pass; pick and rotate move the fingers the most;
measured on these recordings: mean 3.5-3.8 mm, p95 <= 10.5 mm, max <= 12 mm, max step 0.15 rad):
- fingertip residual, robot scale: mean < 6 mm, 95th percentile < 15 mm, max < 25 mm;
- robot fingertips scaled back to the human hand vs the clean (noise-free) human fingertips:
  mean < 6 mm, max < 25 mm;
- continuity: no joint moves more than 0.25 rad between consecutive frames (60 Hz), except at
  a recording's first frame, which starts from the middle of the joint ranges.
"""

from __future__ import annotations

from pathlib import Path

import nlopt
import numpy as np
import pyarrow.parquet as pq
import pytest

from touch2robot.geometry import quat_to_mat
from touch2robot.ingest import ingest_file
from touch2robot.leap import description as hd
from touch2robot.retarget import LEAP_DEFAULT, RetargetConfig
from touch2robot.retarget.lake import load_hand_motion, result_rows
from touch2robot.retarget.retargeter import (
    INVALID_INPUT,
    OK,
    PALM_IN_HUMAN_WRIST,
    RESIDUAL,
    SOLVER_ERROR,
    STATUS_NAMES,
    HandMotion,
    HandMotionError,
    Retargeter,
    RetargetResult,
    keypoints_in_wrist,
    retarget_motion,
    retarget_sequence,
)
from touch2robot.settings import DataLayout
from touch2robot.synth.config import SynthConfig
from touch2robot.synth.generate import RecordingJob, write_recording

RESIDUAL_MEAN, RESIDUAL_P95, RESIDUAL_MAX = 0.006, 0.015, 0.025
TRUTH_MEAN, TRUTH_MAX = 0.006, 0.025
MAX_STEP_RAD = 0.25
TASKS = ("pick", "rotate")


def _write_and_ingest(root: Path, tasks: tuple[str, ...], pace: float = 1.0) -> DataLayout:
    layout = DataLayout(root)
    config = SynthConfig(tasks=tasks, subjects=1, demos_per_subject=1, pace=pace)
    for task in tasks:
        path = write_recording(config, RecordingJob(task, 1, 1), layout.recordings, layout.groundtruth)
        assert ingest_file(path, layout.lake).status == "ingested"
    return layout


@pytest.fixture(scope="module")
def demos(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[HandMotion, RetargetResult, Path]]:
    """Per task: the ingested hand motion, its retargeting with the defaults, the ground truth."""
    layout = _write_and_ingest(tmp_path_factory.mktemp("retarget") / "data", TASKS)
    retargeter = Retargeter(LEAP_DEFAULT)
    out = {}
    for task in TASKS:
        stem = f"{task}_s01_d01_glove"
        rid = next(
            p.stem
            for p in (layout.lake / "recordings").glob("*.parquet")
            if stem in pq.read_table(p)["path"][0].as_py()
        )
        motion = load_hand_motion(layout.lake, rid)
        out[task] = (
            motion,
            retarget_motion(motion, LEAP_DEFAULT, retargeter),
            layout.groundtruth / f"{stem}.motion.parquet",
        )
    return out


@pytest.fixture(scope="module")
def retargeter() -> Retargeter:
    return Retargeter(LEAP_DEFAULT)


def test_urdf_kinematics_match_the_hand_description(retargeter: Retargeter) -> None:
    """Pinocchio on the emitted URDF and the description's own forward kinematics agree."""
    rng = np.random.default_rng(0)
    kin = retargeter.kinematics
    base_from_palm = quat_to_mat(np.asarray(hd.PALM_IN_WRIST_QUAT))
    for _ in range(5):
        q = rng.uniform(kin.lower, kin.upper)
        tips = hd.tip_positions_in_palm(dict(zip(hd.JOINT_NAMES, q, strict=True)))
        expected = np.stack(
            [
                base_from_palm @ tips[s] + np.asarray(hd.PALM_IN_WRIST_POS)
                for s in ("th_tip", "if_tip", "mf_tip", "rf_tip")
            ]
        )
        np.testing.assert_allclose(kin.tip_positions(q), expected, atol=2e-5)


@pytest.mark.parametrize("task", TASKS)
def test_fingertip_residuals_are_small(demos: dict, task: str) -> None:
    _, result, _ = demos[task]
    assert (result.status == OK).all(), np.bincount(result.status)
    assert result.residual.mean() < RESIDUAL_MEAN
    assert np.percentile(result.residual, 95) < RESIDUAL_P95
    assert result.residual.max() < RESIDUAL_MAX


@pytest.mark.parametrize("task", TASKS)
def test_robot_fingertips_follow_the_clean_human_motion(demos: dict, task: str) -> None:
    """Ground truth: the demonstrator's noise-free joints through its hand model (which the
    retargeter never sees) give the true fingertips; the robot's, scaled back, stay close."""
    from touch2robot.synth.hand import HumanHand

    _, result, truth_path = demos[task]
    truth = pq.read_table(truth_path).to_pandas()
    scale = float(pq.read_schema(truth_path.with_name(truth_path.name.replace(".motion", ""))).metadata[b"hand_scale"])
    np.testing.assert_allclose(truth["t"].to_numpy(), result.t, atol=1e-6)
    true_tips = HumanHand(scale).forward(np.stack(truth["joints"])).keypoints[:, [4, 8, 12, 16]]  # wrist frame
    robot = Retargeter(LEAP_DEFAULT).kinematics
    base_from_palm = quat_to_mat(np.asarray(hd.PALM_IN_WRIST_QUAT))
    robot_tips = np.stack([robot.tip_positions(q) for q in result.joints]) @ base_from_palm / result.scaling
    error = np.linalg.norm(robot_tips - true_tips, axis=-1)
    assert error.mean() < TRUTH_MEAN
    assert error.max() < TRUTH_MAX


@pytest.mark.parametrize("task", TASKS)
def test_joint_limits_hold_and_motion_is_continuous(demos: dict, retargeter: Retargeter, task: str) -> None:
    _, result, _ = demos[task]
    assert (result.joints >= retargeter.kinematics.lower).all() and (result.joints <= retargeter.kinematics.upper).all()
    assert np.abs(np.diff(result.joints, axis=0)).max() < MAX_STEP_RAD


def test_robot_wrist_pose_puts_the_palm_on_the_human_wrist_frame(demos: dict) -> None:
    motion, result, _ = demos["pick"]
    np.testing.assert_allclose(result.wrist_pos, motion.wrist_pos)
    # robot palm orientation (world) = base orientation * palm-in-base = human wrist orientation
    palm = quat_to_mat(result.wrist_quat) @ quat_to_mat(np.asarray(hd.PALM_IN_WRIST_QUAT))
    np.testing.assert_allclose(palm, quat_to_mat(motion.wrist_quat), atol=1e-9)
    rows = result_rows(result)
    assert rows.num_rows == len(result.t) and set(rows["status"].to_pylist()) == {"ok"}


def test_the_simulated_hand_reproduces_the_retargeted_fingertips(demos: dict, retargeter: Retargeter) -> None:
    """What the teachers will do with a ``retargeted`` row: put the MJCF hand's ``wrist`` body at
    the row's pose and its joints at the row's angles; the fingertip sites land where Pinocchio
    put the URDF's fingertips (world frame)."""
    import mujoco

    from touch2robot.leap import hand_mjcf

    motion, result, _ = demos["rotate"]
    model = mujoco.MjModel.from_xml_string(hand_mjcf())
    data = mujoco.MjData(model)
    free = model.joint("wrist_free").qposadr[0]
    hinges = [model.joint(name).qposadr[0] for name in hd.JOINT_NAMES]
    sites = [model.site(name).id for name in ("th_tip", "if_tip", "mf_tip", "rf_tip")]
    for i in np.linspace(0, len(result.t) - 1, 7).astype(int):
        data.qpos[free : free + 3] = result.wrist_pos[i]
        data.qpos[free + 3 : free + 7] = result.wrist_quat[i]
        data.qpos[hinges] = result.joints[i]
        mujoco.mj_kinematics(model, data)
        expected = (
            result.wrist_pos[i]
            + retargeter.kinematics.tip_positions(result.joints[i]) @ quat_to_mat(result.wrist_quat[i]).T
        )
        np.testing.assert_allclose(data.site_xpos[sites], expected, atol=1e-4)
        # the documented offset: the robot palm origin sits at PALM_IN_HUMAN_WRIST in the human wrist frame
        palm = motion.wrist_pos[i] + quat_to_mat(motion.wrist_quat[i]) @ PALM_IN_HUMAN_WRIST
        np.testing.assert_allclose(data.body("palm").xpos, palm, atol=1e-6)
    np.testing.assert_allclose(PALM_IN_HUMAN_WRIST, (0.098, 0.038, 0.0), atol=1e-6)


def _frames(motion: HandMotion) -> np.ndarray:
    return keypoints_in_wrist(motion.keypoints, motion.wrist_pos, motion.wrist_quat)


class _FailingOptimizer:
    """NLopt's optimizer with a switch that makes ``optimize`` raise (a mocked solver error)."""

    def __init__(self, opt: nlopt.opt, error: Exception) -> None:
        self._opt, self._error, self.fail = opt, error, False

    def optimize(self, x0: list[float]) -> np.ndarray:
        if self.fail:
            raise self._error
        return self._opt.optimize(x0)

    def __getattr__(self, name: str) -> object:
        return getattr(self._opt, name)


@pytest.mark.parametrize(
    "failure",
    ["nan_keypoints", "solver_runtime_error", "solver_roundoff"],
    ids=["nan-input", "runtime-error", "roundoff"],
)
def test_a_failed_frame_holds_the_previous_solution_and_is_flagged(demos: dict, failure: str) -> None:
    motion, _, _ = demos["rotate"]
    frames, k = _frames(motion), 40
    rt = Retargeter(LEAP_DEFAULT)
    if failure != "nan_keypoints":
        proxy = _FailingOptimizer(
            rt.optimizer.opt,
            RuntimeError("nlopt failure") if failure == "solver_runtime_error" else nlopt.RoundoffLimited(),
        )
        rt.optimizer.opt = proxy  # pyright: ignore[reportAttributeAccessIssue]  a test double in its place
    out, status = [], []
    for i in range(k + 3):
        kp = frames[i].copy()
        if failure == "nan_keypoints" and i == k:
            kp[8] = np.nan
        elif failure != "nan_keypoints":
            proxy.fail = i == k
        q, s, _, _ = rt.step(kp, float(motion.t[i]))
        out.append(q)
        status.append(s)
    assert status[k] == (INVALID_INPUT if failure == "nan_keypoints" else SOLVER_ERROR)
    assert all(s == OK for i, s in enumerate(status) if i != k)
    np.testing.assert_array_equal(out[k], out[k - 1])
    assert not np.array_equal(out[k + 1], out[k])  # and the next frame moves on


def test_residual_explosion_is_a_failed_frame(demos: dict) -> None:
    full, _, _ = demos["rotate"]
    n = 120  # the fingers start moving around frame 90
    motion = HandMotion(full.recording_id, full.t[:n], full.keypoints[:n], full.wrist_pos[:n], full.wrist_quat[:n])
    config = RetargetConfig(max_residual=0.006)  # below the largest residuals of this demo
    result = retarget_motion(motion, config)
    flagged = np.flatnonzero(result.status == RESIDUAL)
    assert 0 < len(flagged) < len(result.t) and flagged[0] > 0
    np.testing.assert_array_equal(result.joints[flagged], result.joints[flagged - 1])
    assert STATUS_NAMES[RESIDUAL] in result_rows(result)["status"].to_pylist()


def _arrays(motion: HandMotion) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return motion.keypoints.copy(), np.concatenate([motion.wrist_pos, motion.wrist_quat], axis=1), motion.t.copy()


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        ("nan", "non-finite keypoints at frame 7"),
        ("non_monotonic", "not strictly increasing at frame 11"),
        ("gap", "missing frames"),
        ("keypoint_count", "expected 21 keypoints"),
        ("frame_count", "frame counts differ"),
        ("quaternion", "not a unit quaternion"),
        ("empty", "no hand-motion frames"),
    ],
)
def test_bad_hand_motion_is_a_clear_error_naming_the_recording(demos: dict, damage: str, message: str) -> None:
    keypoints, pose, t = _arrays(demos["pick"][0])
    if damage == "nan":
        keypoints[7, 3, 1] = np.nan
    elif damage == "non_monotonic":
        t[11] = t[10]
    elif damage == "gap":
        t[50:] += 1.0
    elif damage == "keypoint_count":
        keypoints = keypoints[:, :20]
    elif damage == "frame_count":
        pose = pose[:-1]
    elif damage == "quaternion":
        pose[3, 3:] *= 2.0
    elif damage == "empty":
        keypoints, pose, t = keypoints[:0], pose[:0], t[:0]
    with pytest.raises(HandMotionError, match=rf"recording bad-rec-7: .*{message}"):
        retarget_sequence(keypoints, pose, t, recording_id="bad-rec-7")


def test_scaling_follows_the_hand_size(demos: dict) -> None:
    """The factor is ``scaling`` x reference / hand length from the keypoints; keypoints that are
    not in metres are refused by name."""
    from touch2robot.retarget.retargeter import hand_length, motion_scaling

    motion, result, truth_path = demos["pick"]
    scale = float(pq.read_schema(truth_path.with_name(truth_path.name.replace(".motion", ""))).metadata[b"hand_scale"])
    assert hand_length(motion) == pytest.approx(0.199 * scale, rel=0.01)  # the demonstrator's hand: 0.199 m at scale 1
    assert result.scaling == pytest.approx(LEAP_DEFAULT.scaling * 0.2 / hand_length(motion))
    assert motion_scaling(motion, RetargetConfig(reference_hand_length=None)) == LEAP_DEFAULT.scaling
    keypoints, pose, t = _arrays(motion)
    with pytest.raises(
        HandMotionError, match=r"recording mm-rec: hand length \d+\.\d+ m from the keypoints is outside"
    ):
        retarget_sequence(keypoints * 1000.0, pose, t, recording_id="mm-rec")


def test_lake_input_whose_streams_disagree_is_an_error(tmp_path: Path) -> None:
    import pyarrow as pa

    from touch2robot import lake as lake_io

    layout = _write_and_ingest(tmp_path / "data", ("drawer",), pace=0.3)
    rid = lake_io.files(layout.lake, "hand_keypoints")[0].stem
    path = lake_io.file_path(layout.lake, "wrist_pose", rid)
    table = pq.read_table(path)
    pq.write_table(table.slice(0, table.num_rows - 1), path)
    with pytest.raises(HandMotionError, match=rf"recording {rid}: .* keypoint frames but .* wrist poses"):
        load_hand_motion(layout.lake, rid)
    shifted = table.set_column(1, "t", pa.array(table["t"].to_numpy() + 0.01))
    pq.write_table(shifted, path)
    with pytest.raises(HandMotionError, match=rf"recording {rid}: keypoints at t = .* but wrist pose at"):
        load_hand_motion(layout.lake, rid)
    path.unlink()
    with pytest.raises(HandMotionError, match=rf"recording {rid}: no wrist_pose rows"):
        load_hand_motion(layout.lake, rid)


def test_config_is_strict_and_round_trips_yaml(tmp_path: Path) -> None:
    from importlib import resources

    text = (resources.files("touch2robot.retarget") / "leap.yaml").read_text()
    path = tmp_path / "leap.yaml"
    path.write_text(text)
    assert RetargetConfig.from_yaml(path) == LEAP_DEFAULT
    path.write_text(LEAP_DEFAULT.to_yaml() + "unknown_key: 1\n")
    with pytest.raises(ValueError, match="unknown_key"):
        RetargetConfig.from_yaml(path)
    with pytest.raises(ValueError, match="equal length"):
        RetargetConfig(task_links=("th_tip",))
    with pytest.raises(ValueError, match="keypoint indices"):
        RetargetConfig(task_keypoints=(4, 8, 12, 21))


def test_flow_writes_the_table_tracks_and_caches(tmp_path: Path) -> None:
    """The Prefect flow on a one-recording data folder: lake rows, catalog view, one MLflow run
    with the residual metrics and the comparison drawing; a second run is served from the cache."""
    import mlflow

    from flows.retarget import retarget
    from tasks import tracking
    from touch2robot import catalog

    layout = _write_and_ingest(tmp_path / "data", ("drawer",), pace=0.3)
    first = retarget(profile="smoke", data=str(layout.root))
    assert first["recordings"] == 1 and first["failed_frames"] == 0 and first["not_retargeted"] == 0
    assert first["residual_mean_mm"] < 1e3 * RESIDUAL_MEAN
    n = catalog.query(layout, "SELECT count(*) AS n FROM retargeted WHERE status = 'ok'")["n"][0].as_py()
    assert n == first["frames"] > 0
    runs = mlflow.search_runs([tracking.experiment(layout, "retarget")], output_format="list")
    assert len(runs) == 1 and runs[0].data.metrics["residual_p95_mm"] < 1e3 * RESIDUAL_P95
    assert "solve_ms_mean" in runs[0].data.metrics
    artefacts = list((layout.mlartifacts / "retarget").rglob("retarget_*.png"))
    assert len(artefacts) == 1
    assert retarget(profile="smoke", data=str(layout.root)) == first
    assert len(mlflow.search_runs([tracking.experiment(layout, "retarget")], output_format="list")) == 1
