"""The PRL hand: generated URDF, agent in ManiSkill/SAPIEN, PD hold, contact sensors, IK."""

from __future__ import annotations

import numpy as np
import pytest

from envs import hand_model
from prl.constants import JOINT_NAMES, N_ANCHORS, SENSOR_NAMES


# ----------------------------------------------------------------------------- fast
def test_urdf_regenerates_identically(tmp_path):
    urdf, srdf = hand_model.generate(hand_model.KINEMATICS_PATH, tmp_path / "prl_hand.urdf")
    assert urdf.read_bytes() == hand_model.URDF_PATH.read_bytes()
    assert srdf.read_bytes() == hand_model.SRDF_PATH.read_bytes()


def test_spec_matches_published_numbers():
    spec = hand_model.load_spec()
    limits = spec.joint_limits()
    assert tuple(limits) == JOINT_NAMES
    assert limits["WRJ2"] == (-0.524, 0.175)
    assert limits["WRJ1"] == (-0.698, 0.489)
    assert limits["FFJ3"] == (-0.262, 1.571)
    assert limits["LFJ5"] == (0.0, 0.785)
    assert limits["THJ5"] == (-1.047, 1.047)
    assert limits["THJ4"] == (0.0, 1.222)
    joints = {link["joint"]["name"]: link["joint"] for link in spec.links if link.get("joint")}
    assert joints["FFJ4"]["origin"] == [0.033, 0.0, 0.095]
    assert joints["MFJ4"]["origin"] == [0.011, 0.0, 0.099]
    assert joints["FFJ2"]["origin"] == [0.0, 0.0, 0.045]  # proximal length
    assert joints["FFJ1"]["origin"] == [0.0, 0.0, 0.025]  # middle length
    assert joints["THJ5"]["origin"] == [0.034, -0.009, 0.029]
    assert joints["WRJ2"]["origin"] == [0.0, 0.0, 0.213]
    assert hand_model.palm_anchors().shape == (N_ANCHORS, 3)
    # all anchors on the palm's front face (y = -palm half thickness)
    assert np.allclose(hand_model.palm_anchors()[:, 1], -0.011)


def test_load_spec_rejects_wrong_joint_order(tmp_path):
    text = hand_model.KINEMATICS_PATH.read_text().replace("name: FFJ3,", "name: FFJ3x,")
    bad = tmp_path / "bad.yaml"
    bad.write_text(text)
    with pytest.raises(hand_model.HandModelError, match="FFJ3x"):
        hand_model.load_spec(bad)


def test_ik_round_trip():
    from envs import ik

    rng = np.random.default_rng(0)
    for _ in range(20):
        q_true = np.zeros(len(JOINT_NAMES))
        q_true[:3] = rng.uniform(-0.3, 0.3, 3)
        q_true[3:6] = rng.uniform(-2.5, 2.5, 3)
        q_true[6] = rng.uniform(-0.5, 0.15)
        q_true[7] = rng.uniform(-0.6, 0.45)
        q_true[8:] = rng.uniform(0.0, 0.3, 22)
        pos, rot = ik.palm_pose(q_true)
        anchor = hand_model.palm_anchors()[2]
        q_init = q_true.copy()
        q_init[:6] = 0.0
        q = ik.solve_palm_pose(pos + rot @ anchor, rot, q_init, point=anchor)
        pos2, rot2 = ik.palm_pose(q)
        assert np.linalg.norm(pos2 + rot2 @ anchor - (pos + rot @ anchor)) < 1e-3
        assert np.rad2deg(ik.rotation_error(rot, rot2)) < 1.0
        assert np.allclose(q[6:], q_init[6:])
        assert np.allclose(ik.anchor_world(q, 2), pos + rot @ anchor, atol=1e-3)


def test_ik_rejects_unreachable_target():
    from envs import ik

    q = np.zeros(len(JOINT_NAMES))
    with pytest.raises(ValueError, match="outside the limits"):
        ik.solve_palm_pose([5.0, 0.0, 0.2], np.eye(3), q)


# ----------------------------------------------------------------------------- simulation
@pytest.fixture(scope="module")
def hammer_env():
    pytest.importorskip("mani_skill")
    import envs.agents  # noqa: F401  (registers prl_hand)
    from envs.tasks import make_env

    env = make_env("hammer")
    yield env.unwrapped
    env.close()


def _set_targets(agent, named_targets):
    art = agent.robot._objs[0]
    for joint, target in zip(art.get_active_joints(), agent.to_articulation_order(named_targets), strict=True):
        joint.set_drive_target(float(target))


@pytest.mark.sim
def test_articulation_joints_and_limits(hammer_env):
    agent = hammer_env.agent
    names = [j.name for j in agent.joints_named]
    assert tuple(names) == JOINT_NAMES
    assert tuple(j.name for j in agent.controller.joints) == JOINT_NAMES
    limits = agent.robot.get_qlimits()[0].numpy()[agent.joint_perm]
    spec_limits = hand_model.load_spec().joint_limits()
    for i, name in enumerate(JOINT_NAMES):
        assert np.allclose(limits[i], spec_limits[name], atol=1e-6), name
    links = {link.name for link in agent.robot.get_links()}
    assert set(SENSOR_NAMES) <= links


@pytest.mark.sim
def test_fk_matches_simulator(hammer_env):
    from envs import ik

    agent = hammer_env.agent
    rng = np.random.default_rng(1)
    q = agent.keyframes["home"].qpos.copy()
    q[3:6] = rng.uniform(-0.5, 0.5, 3)
    q[6:] = rng.uniform(0.0, 0.3, 24)
    hammer_env.reset(seed=0)
    agent.reset(q)
    pose = agent.palm_link.pose.raw_pose[0].numpy()
    pos, rot = ik.palm_pose(q)
    import sapien

    sim_rot = sapien.Pose(pose[:3], pose[3:]).to_transformation_matrix()[:3, :3]
    assert np.linalg.norm(pos - pose[:3]) < 1e-4
    assert ik.rotation_error(rot, sim_rot) < 1e-3


@pytest.mark.sim
def test_pd_holds_home_pose(hammer_env):
    hammer_env.reset(seed=0)
    agent = hammer_env.agent
    start = agent.palm_link.pose.raw_pose[0, :3].numpy().copy()
    q_start = agent.named_qpos()
    assert np.allclose(q_start, agent.keyframes["home"].qpos, atol=1e-5)
    for _ in range(500):  # 1 s at 500 Hz
        hammer_env.scene.step()
    drift = np.linalg.norm(agent.palm_link.pose.raw_pose[0, :3].numpy() - start)
    assert drift < 0.002
    assert np.abs(agent.named_qpos() - q_start).max() < 0.01


@pytest.mark.sim
def test_sensors_free_space_and_contact(hammer_env):
    import sapien

    from envs.sensors import ContactSensors

    hammer_env.reset(seed=0)
    agent = hammer_env.agent
    sensors = ContactSensors(hammer_env.scene, agent.sensor_links, exclude=agent.robot)
    for _ in range(20):
        hammer_env.scene.step()
    force, pos, normal = sensors.read()
    assert force.shape == (17,) and pos.shape == (17, 3) and normal.shape == (17, 3)
    assert np.all(force == 0) and np.all(pos == 0) and np.all(normal == 0)

    # a static bar under the palm centre, middle and ring fingers (clear of the thumb, which
    # sits lower than the palm face), above the hammer; then drive the palm down onto it
    home = agent.keyframes["home"].qpos
    builder = hammer_env.scene.create_actor_builder()
    builder.add_box_collision(half_size=[0.08, 0.02, 0.02])
    builder.initial_pose = sapien.Pose(p=[home[0] + 0.03, home[1], 0.18])
    builder.build_static(name="probe_block")
    target = home.copy()
    for i in range(400):
        target[2] = home[2] - min(1.0, i / 200) * 0.06  # palm face 0.25 -> 0.19; block top at 0.20
        _set_targets(agent, target)
        hammer_env.scene.step()
    force, pos, normal = sensors.read()
    palm = SENSOR_NAMES.index("palm")
    assert force[palm] > 1.0
    assert normal[palm, 2] > 0.9  # the block pushes the palm up
    assert abs(pos[palm, 2] - 0.20) < 0.01  # on the block's top face
    assert force[SENSOR_NAMES.index("th_proximal")] == 0.0
