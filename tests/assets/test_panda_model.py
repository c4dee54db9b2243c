"""Physical and kinematic properties of assets/panda/panda.xml."""

import mujoco
import numpy as np
import pytest

from assets import PANDA_XML
from tests.helpers.panda_fixtures import arm_model, arm_spec  # noqa: F401

# Franka's modified DH (Craig): a_{i-1}, d_i, alpha_{i-1}; flange = TransZ(0.107) from frame 7.
DH_A_M = (0.0, 0.0, 0.0, 0.0825, -0.0825, 0.0, 0.088)
DH_D_M = (0.333, 0.0, 0.316, 0.0, 0.384, 0.0, 0.0)
DH_ALPHA = (0.0, -np.pi / 2, np.pi / 2, np.pi / 2, -np.pi / 2, np.pi / 2, np.pi / 2)
FLANGE_D_M = 0.107
JOINT_LIMITS = (
    (-2.8973, 2.8973),
    (-1.7628, 1.7628),
    (-2.8973, 2.8973),
    (-3.0718, -0.0698),
    (-2.8973, 2.8973),
    (-0.0175, 3.7525),
    (-2.8973, 2.8973),
)


def _rot_x(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def _rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def _trans(x: float, z: float) -> np.ndarray:
    t = np.eye(4)
    t[0, 3], t[2, 3] = x, z
    return t


def dh_flange(q: np.ndarray) -> np.ndarray:
    """Flange pose from T_i = RotX(alpha_{i-1}) TransX(a_{i-1}) RotZ(q_i) TransZ(d_i)."""
    pose = np.eye(4)
    for a, d, alpha, qi in zip(DH_A_M, DH_D_M, DH_ALPHA, q):
        pose = pose @ _rot_x(alpha) @ _trans(a, 0.0) @ _rot_z(qi) @ _trans(0.0, d)
    return pose @ _trans(0.0, FLANGE_D_M)


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return arm_model()


def _random_configurations(model: mujoco.MjModel, count: int) -> np.ndarray:
    rng = np.random.default_rng()
    return rng.uniform(model.jnt_range[:, 0], model.jnt_range[:, 1], size=(count, model.nq))


def test_flange_matches_dh_chain(model):
    data = mujoco.MjData(model)
    site = model.site("flange").id
    worst_mm, worst_deg = 0.0, 0.0
    for q in _random_configurations(model, 200):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        expected = dh_flange(q)
        worst_mm = max(worst_mm, 1e3 * np.linalg.norm(data.site_xpos[site] - expected[:3, 3]))
        rel = expected[:3, :3].T @ data.site_xmat[site].reshape(3, 3)
        worst_deg = max(worst_deg, np.degrees(np.arccos(np.clip((np.trace(rel) - 1) / 2, -1, 1))))
    assert worst_mm < 0.5 and worst_deg < 0.1, (worst_mm, worst_deg)


def test_only_seven_hinges(model):
    assert (model.nq, model.nv) == (7, 7)
    assert all(model.jnt_type == mujoco.mjtJoint.mjJNT_HINGE)
    assert [model.joint(i).name for i in range(7)] == [f"joint{i}" for i in range(1, 8)]


def test_joint_limits_are_frankas(model):
    assert model.jnt_limited.all()
    np.testing.assert_allclose(model.jnt_range, JOINT_LIMITS)


def test_actuators_are_torque_motors_with_frankas_limits(model):
    assert [model.actuator(i).name for i in range(7)] == [f"actuator{i}" for i in range(1, 8)]
    np.testing.assert_array_equal(model.jnt_dofadr[model.actuator_trnid[:, 0]], np.arange(7))
    np.testing.assert_allclose(model.actuator_gear[:, 0], 1.0)
    assert model.actuator_ctrllimited.all()
    np.testing.assert_allclose(model.actuator_ctrlrange[:, 1], [87, 87, 87, 87, 12, 12, 12])
    np.testing.assert_allclose(model.actuator_ctrlrange[:, 0], -model.actuator_ctrlrange[:, 1])


def test_total_mass_is_plausible(model):
    # Gaz et al. links 1-7 weigh 16.1 kg; the Panda arm is ~18 kg with its base, the hand ~0.7 kg.
    assert 17.0 < model.body_subtreemass[model.body("link0").id] < 21.0
    assert 0.6 < model.body_subtreemass[model.body("hand").id] < 1.0


def test_physics_rate_is_one_kilohertz(model):
    assert model.opt.timestep == pytest.approx(0.001)
    assert model.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST


def test_home_keyframe_points_flange_down_in_front(model):
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    mujoco.mj_kinematics(model, data)
    flange = data.site("flange")
    assert 0.4 < flange.xpos[0] < 0.6 and abs(flange.xpos[1]) < 1e-6
    assert flange.xmat.reshape(3, 3)[:, 2] @ np.array([0.0, 0.0, -1.0]) > np.cos(np.radians(1.0))


def test_hand_is_rotated_minus_45_deg_about_flange_z(model):
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    flange = data.site("flange").xmat.reshape(3, 3)
    hand = data.body("hand").xmat.reshape(3, 3)
    rel = flange.T @ hand
    np.testing.assert_allclose(rel, _rot_z(-np.pi / 4)[:3, :3], atol=1e-9)


def test_peg_mount_sits_between_the_fingers_along_hand_z():
    model = mujoco.MjModel.from_xml_path(str(PANDA_XML))  # with the finger joints
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)  # fingers 20 mm open each
    mujoco.mj_kinematics(model, data)
    hand = data.body("hand")
    mount = data.site("peg_mount")
    np.testing.assert_allclose(mount.xmat, hand.xmat, atol=1e-12)
    in_hand = hand.xmat.reshape(3, 3).T @ (mount.xpos - hand.xpos)
    left = hand.xmat.reshape(3, 3).T @ (data.body("left_finger").xpos - hand.xpos)
    right = hand.xmat.reshape(3, 3).T @ (data.body("right_finger").xpos - hand.xpos)
    assert in_hand[2] > 0.05 and abs(in_hand[0]) < 1e-9 and abs(in_hand[1]) < 1e-9
    assert left[1] == pytest.approx(0.02) and right[1] == pytest.approx(-0.02)  # finger joints open along hand y
    assert left[2] < in_hand[2]  # the pads reach past the peg's top face


def test_finger_joints_are_prismatic_0_to_40_mm_along_the_hand_y_axis():
    model = mujoco.MjModel.from_xml_path(str(PANDA_XML))
    for name, sign in (("finger_joint1", 1.0), ("finger_joint2", -1.0)):
        joint = model.joint(name)
        assert joint.type == mujoco.mjtJoint.mjJNT_SLIDE
        np.testing.assert_allclose(joint.range, [0.0, 0.04])
        np.testing.assert_allclose(model.jnt_axis[joint.id], [0.0, sign, 0.0])


def test_arm_never_collides_with_itself(model):
    data = mujoco.MjData(model)
    for q in _random_configurations(model, 200):
        data.qpos[:] = q
        mujoco.mj_forward(model, data)
        assert data.ncon == 0


def test_fingers_collide_with_a_default_world_geom(model):
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    mujoco.mj_kinematics(model, data)
    spec = arm_spec()
    probe = spec.worldbody.add_geom()  # contype = conaffinity = 1 by default
    probe.type = mujoco.mjtGeom.mjGEOM_BOX
    probe.size = [0.01, 0.01, 0.01]
    probe.pos = data.geom("left_finger_pad").xpos.copy()
    with_probe = spec.compile()
    probe_data = mujoco.MjData(with_probe)
    mujoco.mj_resetDataKeyframe(with_probe, probe_data, with_probe.key("home").id)
    mujoco.mj_forward(with_probe, probe_data)
    assert probe_data.ncon > 0
