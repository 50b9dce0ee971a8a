"""The four task scenes built from the shared specs: layout, physics at rest, the drawer slide,
success criteria, object point clouds, and rendered images from both cameras."""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

from touch2robot import scenes
from touch2robot.geometry import body_sdf, quat_from_axis_angle, twist_angle
from touch2robot.scenes.pick import PickSuccess
from touch2robot.sim.config import SimConfig
from touch2robot.sim.scene import CAMERAS, Scene, build_scene
from touch2robot.sim.success import SuccessTracker

TASKS = tuple(scenes.REGISTRY)


@pytest.fixture(scope="module", params=TASKS)
def scene(request: pytest.FixtureRequest) -> Scene:
    return build_scene(request.param, SimConfig(point_cloud_size=256))


def _settle(scene: Scene, steps: int = 100) -> mujoco.MjData:
    data = mujoco.MjData(scene.model)
    data.qpos[:] = scene.home_qpos
    data.ctrl[:] = scene.home_qpos[scene.hand_qpos]
    data.mocap_pos[0], data.mocap_quat[0] = scene.home_wrist_pos, scene.home_wrist_quat
    for _ in range(steps):
        mujoco.mj_step(scene.model, data)
    return data


MUJOCO_SOLREF, MUJOCO_SOLIMP = (0.02, 1.0), (0.9, 0.95, 0.001)  # MuJoCo's defaults: a rigid contact


def test_scene_layout_comes_from_the_spec(scene: Scene) -> None:
    model, spec = scene.model, scene.spec
    table = model.geom("table")
    assert model.geom_pos[table.id][2] + model.geom_size[table.id][2] == pytest.approx(0.0)  # top at z = 0
    np.testing.assert_allclose(model.geom_size[table.id][:2], spec.table_half_extent)
    body = model.body("object")
    assert model.body_subtreemass[body.id] == pytest.approx(spec.object.mass)
    np.testing.assert_allclose(model.body_pos[body.id], spec.object.init_pos)
    geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] == body.id]
    assert len(geoms) == len(spec.object.geoms)
    assert {model.geom_friction[g][0] for g in geoms} == {spec.object.friction}
    obj = spec.object
    for g in geoms:
        np.testing.assert_allclose(model.geom_solref[g], obj.solref or MUJOCO_SOLREF)
        np.testing.assert_allclose(model.geom_solimp[g][:3], obj.solimp or MUJOCO_SOLIMP)
    # a table friction of its own wins the table's contacts; otherwise MuJoCo's max rule decides
    assert model.geom_priority[table.id] == (obj.table_friction is not None)
    if obj.table_friction is not None:
        assert model.geom_friction[table.id][0] == obj.table_friction
    assert model.opt.noslip_iterations == spec.noslip_iterations
    for cam in CAMERAS:
        assert model.camera(cam).id >= 0
    assert model.ncam == 2


def test_object_rests_and_hand_is_clear_at_reset(scene: Scene) -> None:
    data = _settle(scene)
    adr = scene.object_qpos
    if scene.is_drawer:
        assert abs(data.qpos[adr]) < 1e-3
    else:
        np.testing.assert_allclose(data.qpos[adr : adr + 3], scene.spec.object.init_pos, atol=1e-3)
    assert np.all(data.sensordata[scene.region_sensors] == 0.0)  # hand touches nothing at reset
    lowest_tip = data.sensordata[scene.tip_sensors][:, 2].min()
    assert lowest_tip > 0.02


def test_point_cloud_lies_on_the_object_surface(scene: Scene) -> None:
    pts = scene.point_cloud
    assert pts.shape == (256, 3)
    assert np.abs(body_sdf(scene.spec.object.geoms, pts)).max() < 1e-5


def test_drawer_slides_along_its_axis_within_its_range() -> None:
    scene = build_scene("drawer")
    data = _settle(scene, 10)
    slide = scene.spec.slide
    assert slide is not None
    drawer = scene.model.body("object").id
    data.xfrc_applied[drawer, :3] = 20.0 * np.asarray(slide.axis)  # pull it open, hard
    for _ in range(200):
        mujoco.mj_step(scene.model, data)
    opening = data.qpos[scene.object_qpos]
    assert slide.range[1] - 0.005 < opening < slide.range[1] + 0.005
    moved = data.xpos[drawer] - np.asarray(scene.spec.object.init_pos)
    np.testing.assert_allclose(moved, opening * np.asarray(slide.axis), atol=1e-6)


def test_pick_success_needs_lift_and_goal() -> None:
    spec = scenes.get("pick")
    tr = SuccessTracker(spec, 3)
    start = np.tile(spec.object.init_pos, (3, 1))
    tr.reset(np.arange(3), start, np.tile([1.0, 0, 0, 0], (3, 1)))
    goal = np.asarray(spec.goal_pos)
    lifted = start + [0.0, 0.0, 0.08]
    tr.update(np.stack([lifted[0], start[1], lifted[2]]), np.tile([1.0, 0, 0, 0], (3, 1)), np.zeros(3))
    tr.update(np.stack([goal, goal, goal + [0.05, 0.0, 0.0]]), np.tile([1.0, 0, 0, 0], (3, 1)), np.zeros(3))
    assert tr.success.tolist() == [True, False, False]  # lifted+placed; slid without lift; placed 5 cm off
    assert tr.progress[0] == pytest.approx(1.0)


def test_rotate_success_is_the_angle_about_the_axis() -> None:
    spec = scenes.get("rotate")
    assert spec.rotation_axis is not None
    tr = SuccessTracker(spec, 4)
    pos = np.tile(spec.object.init_pos, (4, 1))
    tr.reset(np.arange(4), pos, np.tile([1.0, 0, 0, 0], (4, 1)))
    angles = np.array([math.pi / 2, math.radians(60), math.pi / 2, -math.pi / 2])
    quat = quat_from_axis_angle(np.asarray(spec.rotation_axis), angles)
    moved = pos + np.array([[0, 0, 0], [0, 0, 0], [0.1, 0, 0], [0, 0, 0]])
    tr.update(moved, quat, np.zeros(4))
    assert tr.success.tolist() == [True, False, False, False]
    # a tilt about another axis does not count as rotation about the vertical
    tilt = quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), 0.4)
    assert twist_angle(tilt, np.array([1.0, 0, 0, 0]), np.array([0.0, 0.0, 1.0])) == pytest.approx(0.0)


def test_wipe_success_is_path_coverage() -> None:
    spec = scenes.get("wipe")
    path = np.asarray(spec.wipe_path)
    tr = SuccessTracker(spec, 2)
    tr.reset(np.arange(2), np.zeros((2, 3)), np.tile([1.0, 0, 0, 0], (2, 1)))
    for i, (x, y) in enumerate(path):
        near = [x + 0.01, y, 0.015]
        pos = np.array([near, near if i < 3 else [x, y + 0.1, 0.015]])
        tr.update(pos, np.tile([1.0, 0, 0, 0], (2, 1)), np.zeros(2))
    np.testing.assert_allclose(tr.progress, [1.0, 3 / len(path)])
    assert tr.success.tolist() == [True, False]


def test_drawer_success_is_the_opening() -> None:
    spec = scenes.get("drawer")
    tr = SuccessTracker(spec, 2)
    tr.reset(np.arange(2), np.zeros((2, 3)), np.tile([1.0, 0, 0, 0], (2, 1)))
    tr.update(np.zeros((2, 3)), np.tile([1.0, 0, 0, 0], (2, 1)), np.array([0.13, 0.06]))
    assert tr.success.tolist() == [True, False]
    np.testing.assert_allclose(tr.progress, [1.0, 0.5])


def test_render_saves_both_cameras_of_every_scene(tmp_path: Path) -> None:
    from PIL import Image

    from touch2robot.sim.render import render_scenes

    paths = render_scenes(tmp_path, width=64, height=64)
    assert sorted(p.name for p in paths) == sorted(f"{t}_{c}.png" for t in TASKS for c in CAMERAS)
    for path in paths:
        image = np.asarray(Image.open(path))
        assert image.shape == (64, 64, 3)
        assert image.std() > 10  # not a blank frame


def _fingertip_ik(targets: dict[str, np.ndarray], q0: np.ndarray) -> np.ndarray:
    """Joint angles (within limits) putting the given fingertip sites at palm-frame points."""
    from scipy.optimize import least_squares

    from touch2robot.leap import description as hd

    joints = {lk.joint.name: lk.joint for lk in hd.LINKS if lk.joint is not None}
    low = np.array([joints[n].lower for n in hd.JOINT_NAMES])
    high = np.array([joints[n].upper for n in hd.JOINT_NAMES])

    def residual(q: np.ndarray) -> np.ndarray:
        tips = hd.tip_positions_in_palm(dict(zip(hd.JOINT_NAMES, q, strict=True)))
        return np.concatenate([tips[s] - t for s, t in targets.items()] + [0.01 * (q - q0)])

    return least_squares(residual, q0, bounds=(low, high)).x


def test_pick_box_can_be_grasped_and_lifted_by_the_servos() -> None:
    """The spec's box (mass, friction) is liftable within the servos' 0.22 N·m: a scripted
    thumb-index-middle grasp from above lifts it past the success lift height."""
    from touch2robot.geometry import quat_to_mat
    from touch2robot.leap import description as hd
    from touch2robot.sim.env import BatchEnv

    cfg = SimConfig(n_envs=1, threads=1)
    env = BatchEnv(build_scene("pick", cfg), cfg)
    centre = np.array([-0.04, -0.015, -0.085])  # where the box sits in the palm frame when grasped
    q0 = np.array([0.8, 0.0, 0.8, 0.8] * 3 + [0.8, 0.8, 0.8, 0.0])

    def grip(reach: float, lift: float = 0.0) -> np.ndarray:
        c = centre + [0.0, 0.0, lift]
        return _fingertip_ik(
            {"if_tip": c + [reach, 0.02, 0.0], "mf_tip": c + [reach, -0.02, 0.0], "th_tip": c - [reach, 0.0, 0.0]}, q0
        )

    q_open, q_close = grip(0.063, 0.01), grip(0.015)  # open around the 6 cm box; squeeze through it
    wrist_rot, palm_rot = quat_to_mat(env.scene.home_wrist_quat), quat_to_mat(np.asarray(hd.PALM_IN_WRIST_QUAT))
    at_box = np.asarray(env.scene.spec.object.init_pos) - wrist_rot @ (
        np.asarray(hd.PALM_IN_WRIST_POS) + palm_rot @ centre
    )
    start = env.wrist_pos[0].copy()
    for k in range(90):
        if k < 35:  # approach from above, open
            wrist, q = (
                start + min(k / 20, 1.0) * (at_box + [0, 0, 0.04] - start) - [0, 0, 0.04 * max(k - 20, 0) / 15],
                q_open,
            )
        elif k < 55:  # close
            wrist, q = at_box, q_open + min((k - 35) / 15, 1.0) * (q_close - q_open)
        else:  # lift 10 cm
            wrist, q = at_box + [0, 0, 0.10 * min((k - 55) / 20, 1.0)], q_close
        env.step(q[None], wrist[None])
    criterion = env.tracker.criterion
    assert isinstance(criterion, PickSuccess) and criterion.max_lift[0] > scenes.get("pick").success["lift_m"]
    assert env.region_contact[0, 0] and env.region_contact[0, 1:3].any()  # held by thumb and fingers
