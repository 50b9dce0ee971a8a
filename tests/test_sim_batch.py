"""The LEAP model and the batched environment: fingertip kinematics against the reference
table, joint limits, tactile regions, determinism whatever N, per-copy resets."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import mujoco
import numpy as np
import pytest

from touch2robot.leap import description as hd
from touch2robot.leap.mjcf import REGION_SENSOR_PREFIX, add_hand, mjcf_root, section, sub
from touch2robot.sim.config import SimConfig
from touch2robot.sim.env import BatchEnv
from touch2robot.sim.scene import build_scene

# Fingertip sites in the palm frame (reference table: public LEAP models, derived FK).
TIPS_AT_ZERO = {"if_tip": (0.1322, 0.0076, -0.0195), "mf_tip": (0.1321, -0.0378, -0.0195), "rf_tip": (0.1321, -0.0832, -0.0195), "th_tip": (-0.0823, 0.1367, -0.0219)}
HOME = {"mcp": 0.8, "rot": 0.0, "pip": 0.8, "dip": 0.8, "th_cmc": 0.8, "th_axl": 0.8, "th_mcp": 0.8, "th_ipl": 0.0}
TIPS_AT_HOME = {"if_tip": (-0.0085, 0.0076, -0.1272), "mf_tip": (-0.0086, -0.0378, -0.1272), "rf_tip": (-0.0086, -0.0832, -0.1272), "th_tip": (-0.0292, 0.0328, -0.1357)}


def _hand_model(probe: bool = False) -> mujoco.MjModel:
    root = mjcf_root("hand_test")
    add_hand(root, np.array([0.0, 0.0, 0.3]), np.array([1.0, 0.0, 0.0, 0.0]))
    if probe:  # a mocap sphere that can be pushed into any part of the hand
        body = sub(section(root, "worldbody"), "body", name="probe", pos=(1.0, 1.0, 1.0), mocap="true")
        sub(body, "geom", name="probe", type="sphere", size=0.004, rgba=(1, 0, 0, 1))
    sub(section(root, "option"), "flag", gravity="disable")
    return mujoco.MjModel.from_xml_string(ET.tostring(root, encoding="unicode"))


def _tips_in_palm(model: mujoco.MjModel, q: dict[str, float]) -> dict[str, np.ndarray]:
    data = mujoco.MjData(model)
    for name in hd.JOINT_NAMES:
        key = name if name.startswith("th_") else name[3:]
        data.joint(name).qpos = q.get(key, 0.0)
    mujoco.mj_kinematics(model, data)
    palm = data.body("palm")
    rot = palm.xmat.reshape(3, 3)
    return {s: rot.T @ (data.site(s).xpos - palm.xpos) for s in hd.TIP_SITES}


@pytest.mark.parametrize(("q", "expected"), [({}, TIPS_AT_ZERO), (HOME, TIPS_AT_HOME)], ids=["zero", "bent"])
def test_fingertip_kinematics_match_reference_within_1mm(q: dict, expected: dict) -> None:
    tips = _tips_in_palm(_hand_model(), q)
    for site, ref in expected.items():
        assert np.linalg.norm(tips[site] - np.asarray(ref)) < 1e-3, (site, tips[site], ref)


def test_urdf_has_the_same_chain() -> None:
    from touch2robot.leap import hand_urdf

    model = mujoco.MjModel.from_xml_string(hand_urdf())
    assert {model.joint(i).name for i in range(model.njnt)} >= set(hd.JOINT_NAMES)


def _env(task: str = "pick", n: int = 4, seed: int = 0) -> BatchEnv:
    cfg = SimConfig(n_envs=n, seed=seed)
    return BatchEnv(build_scene(task, cfg), cfg)


def _closing_targets(env: BatchEnv, k: int) -> np.ndarray:
    close = np.array([1.0, 0.0, 1.0, 0.8] * 3 + [1.0, 1.0, 0.6, 0.4])
    home = env.home_state[env.layout.qpos][env.scene.hand_qpos]
    return np.tile(home + min(k / 10, 1.0) * close, (env.n, 1))


def test_joint_limits_respected_under_extreme_commands() -> None:
    env = _env(n=3)
    low, high = env.ctrl_low, env.ctrl_high
    for k in range(30):
        env.step(np.tile(np.where(k % 10 < 5, high + 1.0, low - 1.0), (3, 1)))
        q = env.hand_qpos
        assert (q >= low - 0.02).all() and (q <= high + 0.02).all()


def test_same_state_same_next_state_whatever_n() -> None:
    rng = np.random.default_rng(3)
    commands = [rng.uniform(-0.3, 1.2, 16) for _ in range(15)]
    one, many = _env(n=1), _env(n=7)
    many.state[4] = one.state[0]
    for k, c in enumerate(commands):
        one.step(c[None])
        targets = np.tile(c, (7, 1)) + rng.normal(0, 0.2, (7, 16)) * (np.arange(7) != 4)[:, None]
        many.step(targets)
    np.testing.assert_array_equal(one.state[0], many.state[4])
    np.testing.assert_array_equal(one.sensordata[0], many.sensordata[4])


def test_reset_touches_only_the_given_copies() -> None:
    env = _env(n=4)
    for k in range(8):
        env.step(_closing_targets(env, k))
    before = env.state.copy()
    env.reset(np.array([1, 3]))
    np.testing.assert_array_equal(env.state[[0, 2]], before[[0, 2]])
    np.testing.assert_array_equal(env.state[[1, 3]], np.tile(env.home_state, (2, 1)))
    assert list(env.time_step) == [8, 0, 8, 0]


def test_closing_on_the_box_makes_fingertip_contacts() -> None:
    env = _env(n=2)
    for k in range(25):
        env.step(_closing_targets(env, k), env.wrist_pos - [0.0, 0.0, 0.0025 * min(k, 20)])
    assert env.region_contact[:, :4].any(axis=1).all()
    assert ((env.region_force > 0.5) == env.region_contact).all()


@pytest.mark.parametrize("region", hd.REGION_NAMES)
def test_each_region_fires_when_and_only_when_pressed(region: str) -> None:
    model = _hand_model(probe=True)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    box = next(r.box for r in hd.REGIONS if r.name == region)
    body = data.body(box.body)
    centre = body.xpos + body.xmat.reshape(3, 3) @ np.asarray(box.pos)
    sensors = {r: model.sensor(f"{REGION_SENSOR_PREFIX}{r}").adr[0] for r in hd.REGION_NAMES}
    for _ in range(20):  # probe far away: nothing fires
        mujoco.mj_step(model, data)
    assert all(data.sensordata[a] < 0.5 for a in sensors.values())
    data.mocap_pos[model.body("probe").mocapid[0]] = centre
    for _ in range(20):
        mujoco.mj_step(model, data)
    fired = {r for r, a in sensors.items() if data.sensordata[a] > 0.5}
    assert fired == {region}
