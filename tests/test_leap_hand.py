"""The project's LEAP Hand model: one description, MJCF and URDF agree with the reference numbers
(public LEAP models, fingertip table derived there with MuJoCo FK) and with each other."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import mujoco
import numpy as np
import pytest

from touch2robot.leap import description as hd
from touch2robot.leap import hand_mjcf, hand_urdf
from touch2robot.leap.mjcf import REGION_SENSOR_PREFIX, add_hand, mjcf_root, section, sub

# Fingertip sites in the palm frame (m), reference table at q = 0 and at Playground's "home" pose.
TIPS_AT_ZERO = {
    "if_tip": (0.1322, 0.0076, -0.0195),
    "mf_tip": (0.1321, -0.0378, -0.0195),
    "rf_tip": (0.1321, -0.0832, -0.0195),
    "th_tip": (-0.0823, 0.1367, -0.0219),
}
TIPS_AT_HOME = {
    "if_tip": (-0.0085, 0.0076, -0.1272),
    "mf_tip": (-0.0086, -0.0378, -0.1272),
    "rf_tip": (-0.0086, -0.0832, -0.1272),
    "th_tip": (-0.0292, 0.0328, -0.1357),
}
HOME = {
    **{
        f"{f}_{j}": v
        for f in hd.FINGERS
        for j, v in zip(("mcp", "rot", "pip", "dip"), (0.8, 0.0, 0.8, 0.8), strict=True)
    },
    "th_cmc": 0.8,
    "th_axl": 0.8,
    "th_mcp": 0.8,
    "th_ipl": 0.0,
}
# Reference joint ranges; thumb axl/mcp from the URDFs (see description.THUMB_JOINTS for why)
RANGES = {
    "mcp": (-0.314, 2.23),
    "rot": (-1.047, 1.047),
    "pip": (-0.506, 1.885),
    "dip": (-0.366, 2.042),
    "th_cmc": (-0.349, 2.094),
    "th_axl": (-0.47, 2.443),
    "th_mcp": (-1.20, 1.90),
    "th_ipl": (-1.34, 1.88),
}


def _range(joint: str) -> tuple[float, float]:
    return RANGES[joint] if joint.startswith("th_") else RANGES[joint[3:]]


def _palm_frame_tips(model: mujoco.MjModel, q: dict[str, float], tip_body: bool = False) -> dict[str, np.ndarray]:
    data = mujoco.MjData(model)
    for name, value in q.items():
        data.joint(name).qpos = value
    mujoco.mj_kinematics(model, data)
    palm = data.body("palm")
    rot = palm.xmat.reshape(3, 3)
    return {s: rot.T @ ((data.body(s).xpos if tip_body else data.site(s).xpos) - palm.xpos) for s in hd.TIP_SITES}


def _urdf_model() -> mujoco.MjModel:
    # MuJoCo fuses fixed links into their parents by default; keep the tip links as bodies
    root = ET.fromstring(hand_urdf())
    root.insert(0, ET.fromstring('<mujoco><compiler fusestatic="false" discardvisual="false"/></mujoco>'))
    return mujoco.MjModel.from_xml_string(ET.tostring(root, encoding="unicode"))


@pytest.mark.parametrize(("q", "expected"), [({}, TIPS_AT_ZERO), (HOME, TIPS_AT_HOME)], ids=["zero", "bent"])
def test_fingertip_fk_matches_reference_within_1mm(q: dict[str, float], expected: dict) -> None:
    mjcf = _palm_frame_tips(mujoco.MjModel.from_xml_string(hand_mjcf()), q)
    own = hd.tip_positions_in_palm(q)
    for site, ref in expected.items():
        assert np.linalg.norm(mjcf[site] - ref) < 1e-3, (site, mjcf[site], ref)
        assert np.linalg.norm(own[site] - ref) < 1e-3, (site, own[site], ref)


def test_joint_names_order_ranges_and_servos_follow_the_reference() -> None:
    model = mujoco.MjModel.from_xml_string(hand_mjcf())
    assert hd.JOINT_NAMES == (
        "if_mcp",
        "if_rot",
        "if_pip",
        "if_dip",
        "mf_mcp",
        "mf_rot",
        "mf_pip",
        "mf_dip",
        "rf_mcp",
        "rf_rot",
        "rf_pip",
        "rf_dip",
        "th_cmc",
        "th_axl",
        "th_mcp",
        "th_ipl",
    )
    assert [model.actuator(i).name for i in range(model.nu)] == list(hd.JOINT_NAMES)
    for i, name in enumerate(hd.JOINT_NAMES):
        np.testing.assert_allclose(model.joint(name).range, _range(name))
        np.testing.assert_allclose(model.actuator_ctrlrange[i], _range(name))
        np.testing.assert_allclose(model.actuator_forcerange[i], (-0.2196, 0.2196))
        assert model.actuator_gainprm[i, 0] == pytest.approx(3.0)
        assert model.actuator(i).trnid[0] == model.joint(name).id
    assert model.body_mass[1:].sum() == pytest.approx(0.746, abs=2e-3)


def test_joint_limits_hold_under_commands_beyond_them() -> None:
    model = mujoco.MjModel.from_xml_string(hand_mjcf())
    data = mujoco.MjData(model)
    low, high = model.actuator_ctrlrange.T
    qadr = [model.jnt_qposadr[model.joint(n).id] for n in hd.JOINT_NAMES]
    for target in (high, low):
        data.ctrl[:] = target  # already at the limit: the servo pushes into it
        data.qfrc_applied[:] = 0.0
        for _ in range(150):
            mujoco.mj_step(model, data)
        q = data.qpos[qadr]
        assert (q >= low - 0.02).all() and (q <= high + 0.02).all()
    # an outside push harder than the servos: the joint limits still hold
    dof = [model.jnt_dofadr[model.joint(n).id] for n in hd.JOINT_NAMES]
    data.qfrc_applied[dof] = 0.5
    for _ in range(150):
        mujoco.mj_step(model, data)
    assert (data.qpos[qadr] <= high + 0.03).all()


def _probe_model() -> mujoco.MjModel:
    root = mjcf_root("probe_test")
    add_hand(root, np.array([0.0, 0.0, 0.3]), np.array([1.0, 0.0, 0.0, 0.0]))
    body = sub(section(root, "worldbody"), "body", name="probe", pos=(1.0, 1.0, 1.0), mocap="true")
    sub(body, "geom", name="probe", type="sphere", size=0.004)
    sub(root.find("option"), "flag", gravity="disable")  # type: ignore[arg-type]
    return mujoco.MjModel.from_xml_string(ET.tostring(root, encoding="unicode"))


@pytest.mark.parametrize("region", hd.REGION_NAMES)
def test_each_region_fires_when_and_only_when_its_pad_is_pressed(region: str) -> None:
    model = _probe_model()
    data = mujoco.MjData(model)
    sensors = {r: model.sensor_adr[model.sensor(f"{REGION_SENSOR_PREFIX}{r}").id] for r in hd.REGION_NAMES}
    for _ in range(10):
        mujoco.mj_step(model, data)
    assert max(data.sensordata[a] for a in sensors.values()) == 0.0  # nothing touches: all quiet
    box = next(r.box for r in hd.REGIONS if r.name == region)
    body = data.body(box.body)
    centre = body.xpos + body.xmat.reshape(3, 3) @ np.asarray(box.pos)
    data.mocap_pos[model.body("probe").mocapid[0]] = centre  # push a sphere into the pad
    for _ in range(10):
        mujoco.mj_step(model, data)
    assert {r for r, a in sensors.items() if data.sensordata[a] > 0.5} == {region}


def test_palm_pads_follow_the_glove_layout() -> None:
    # P1/P2 distal (toward the fingers, palm +x), P3/P4 proximal; P1/P3 radial (thumb side, +y)
    c = {name: np.asarray(pos) for name, (pos, _) in hd.PALM_PADS.items()}
    assert c["P1"][0] > c["P3"][0] and c["P2"][0] > c["P4"][0]
    assert c["P1"][1] > c["P2"][1] and c["P3"][1] > c["P4"][1]
    index_y, ring_y = 0.023, -0.0678
    assert c["P1"][1] > (index_y + ring_y) / 2 > c["P2"][1] - 0.02


def test_palm_sensing_volumes_do_not_overlap() -> None:
    model = mujoco.MjModel.from_xml_string(hand_mjcf())
    boxes = []
    for name in ("P1", "P2", "P3", "P4"):
        site = model.site(f"{name}_zone")
        np.testing.assert_allclose(site.quat, (1, 0, 0, 0))  # axis-aligned in the palm frame
        boxes.append((site.pos - site.size, site.pos + site.size))
    for i, (lo_a, hi_a) in enumerate(boxes):
        for lo_b, hi_b in boxes[i + 1 :]:
            assert (np.minimum(hi_a, hi_b) - np.maximum(lo_a, lo_b) <= 0).any()  # disjoint along some axis


def test_urdf_parses_and_gives_the_same_fingertip_fk() -> None:
    model = _urdf_model()
    assert model.body(1).name == "base"
    names = {model.joint(i).name for i in range(model.njnt)}
    assert names == set(hd.JOINT_NAMES)
    for name in hd.JOINT_NAMES:
        np.testing.assert_allclose(model.joint(name).range, _range(name))
    mjcf = mujoco.MjModel.from_xml_string(hand_mjcf())
    for q in ({}, HOME, {n: 0.5 * sum(_range(n)) for n in hd.JOINT_NAMES}):
        a, b = _palm_frame_tips(model, q, tip_body=True), _palm_frame_tips(mjcf, q)
        for site in hd.TIP_SITES:
            assert np.linalg.norm(a[site] - b[site]) < 1e-5, (site, q)  # 10 µm: rpy round trip of unnormalised quats


def test_urdf_base_is_dex_urdf_wrist_frame() -> None:
    model = _urdf_model()
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    base, palm = data.body("base"), data.body("palm")
    rot_palm = base.xmat.reshape(3, 3).T @ palm.xmat.reshape(3, 3)  # palm axes in the base frame
    np.testing.assert_allclose(rot_palm[:, 0], (0, 0, 1), atol=1e-6)  # base +z = palm +x
    np.testing.assert_allclose(rot_palm[:, 2], (-1, 0, 0), atol=1e-6)  # base +x = palm -z
    origin_in_palm = palm.xmat.reshape(3, 3).T @ (base.xpos - palm.xpos)
    np.testing.assert_allclose(origin_in_palm, (-0.098, -0.038, 0.0), atol=1e-6)
    assert math.isclose(float(np.linalg.det(rot_palm)), 1.0, abs_tol=1e-9)


def test_urdf_visuals_sit_where_the_mjcf_collision_geometry_is() -> None:
    """Foxglove draws the URDF's visuals: each capsule (a cylinder there) and box lies where the MJCF's does."""
    urdf, mjcf = _urdf_model(), mujoco.MjModel.from_xml_string(hand_mjcf())
    placed = []
    for model in (urdf, mjcf):
        data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, data)
        palm = data.body("palm")
        rows: dict[str, list] = {}
        for g in range(model.ngeom):
            body = model.body(model.geom_bodyid[g]).name
            kind = model.geom_type[g]
            if kind not in (mujoco.mjtGeom.mjGEOM_CYLINDER, mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_BOX):
                continue
            rel = palm.xmat.reshape(3, 3).T @ (data.geom_xpos[g] - palm.xpos)
            axis = palm.xmat.reshape(3, 3).T @ data.geom_xmat[g].reshape(3, 3)[:, 2]
            rows.setdefault(body, []).append((kind == mujoco.mjtGeom.mjGEOM_BOX, rel, axis))
        placed.append(rows)
    urdf_rows, mjcf_rows = placed
    assert set(urdf_rows) <= set(mjcf_rows)
    for body, geoms in mjcf_rows.items():
        assert len(urdf_rows.get(body, [])) == len(geoms), body
        for is_box, rel, axis in geoms:
            match = [(b, r, a) for b, r, a in urdf_rows[body] if b == is_box and np.linalg.norm(r - rel) < 1e-5]
            assert match, (body, rel)
            if not is_box:  # a cylinder's axis is the capsule's, either way round
                assert abs(abs(float(match[0][2] @ axis)) - 1.0) < 1e-6, body
