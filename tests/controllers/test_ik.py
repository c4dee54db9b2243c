"""mink inverse kinematics of the Panda's sites: one-shot solves and the nullspace reference."""

import mujoco
import numpy as np
import pytest

from controllers.errors import ControllerError
from controllers.ik import IKConfig, NullspaceReference, pose_residual, solve_ik
from tests.helpers.panda_fixtures import arm_model, arm_spec  # noqa: F401


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return arm_model()


@pytest.fixture(scope="module")
def q_home(model) -> np.ndarray:
    return model.key("home").qpos.copy()


def _site_pose(model, q, site="peg_mount"):
    data = mujoco.MjData(model)
    data.qpos[:] = q
    mujoco.mj_kinematics(model, data)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, data.site(site).xmat)
    return data.site(site).xpos.copy(), quat


def _residual(model, q, pos, quat, site="peg_mount"):
    data = mujoco.MjData(model)
    data.qpos[:] = q
    mujoco.mj_kinematics(model, data)
    return pose_residual(data, model.site(site).id, pos, quat)


def test_reaches_random_reachable_poses_within_limits(model, q_home):
    rng = np.random.default_rng()
    config = IKConfig()
    for _ in range(20):
        q_true = np.clip(q_home + rng.uniform(-0.6, 0.6, 7), *model.jnt_range.T)
        pos, quat = _site_pose(model, q_true)
        q = solve_ik(model, "peg_mount", pos, quat, q_home)
        position_m, orientation_deg = _residual(model, q, pos, quat)
        assert position_m <= config.position_tolerance_m and orientation_deg <= config.orientation_tolerance_deg
        assert np.all(q >= model.jnt_range[:, 0]) and np.all(q <= model.jnt_range[:, 1])


def test_prefers_the_nominal_posture(model, q_home):
    pos, quat = _site_pose(model, q_home)
    q = solve_ik(model, "peg_mount", pos, quat, q_home + 0.05)
    np.testing.assert_allclose(q, q_home, atol=0.02)


def test_far_target_raises_one_line_error_with_residual(model, q_home):
    with pytest.raises(ControllerError, match=r"unreachable: residual .* mm, .* deg") as error:
        solve_ik(model, "peg_mount", [2.0, 0.0, 0.5], [0.0, 1.0, 0.0, 0.0], q_home)
    assert "\n" not in str(error.value)


def test_target_below_the_floor_raises(model, q_home):
    with pytest.raises(ControllerError, match="below the floor"):
        solve_ik(model, "peg_mount", [0.5, 0.0, -0.05], [0.0, 1.0, 0.0, 0.0], q_home)


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (("nope", [0.5, 0.0, 0.3], [0.0, 1.0, 0.0, 0.0]), "nope"),
        (("peg_mount", [0.5, 0.0], [0.0, 1.0, 0.0, 0.0]), "target_pos"),
        (("peg_mount", [0.5, 0.0, 0.3], [0.0, 0.0, 0.0, 0.0]), "target_quat"),
    ],
)
def test_bad_inputs_raise_controller_error(model, q_home, args, match):
    with pytest.raises(ControllerError, match=match):
        solve_ik(model, *args, q_home)


def test_works_on_a_scene_with_extra_fixed_bodies(q_home):
    spec = arm_spec()
    fixture = spec.worldbody.add_body()
    fixture.pos = [0.5, 0.0, 0.05]
    fixture.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.05, 0.05, 0.05])
    peg = spec.body("hand").add_body()
    peg.pos = spec.site("peg_mount").pos
    peg.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.01, 0.01, 0.04], pos=[0.0, 0.0, 0.04])
    peg.add_site(name="peg_tip", pos=[0.0, 0.0, 0.08])
    scene = spec.compile()
    assert scene.nq == 7
    pos, quat = _site_pose(scene, q_home + 0.2, site="peg_tip")
    q = solve_ik(scene, "peg_tip", pos, quat, q_home)
    assert _residual(scene, q, pos, quat, site="peg_tip")[0] <= IKConfig().position_tolerance_m


def test_nullspace_reference_follows_a_moving_target(model, q_home):
    start_pos, quat = _site_pose(model, q_home)
    reference = NullspaceReference(model, "peg_mount", q_home)
    worst_m = 0.0
    for k in range(150):  # 1.5 s of 100 Hz commands along a curve at up to 0.15 m/s
        t = 0.01 * k
        pos = start_pos + np.array([0.1 * np.sin(t), 0.15 * np.sin(0.7 * t), -0.05 * t])
        q = reference.update(pos, quat)
        worst_m = max(worst_m, _residual(model, q, pos, quat)[0])
        assert np.all(q >= model.jnt_range[:, 0]) and np.all(q <= model.jnt_range[:, 1])
    assert worst_m < 2e-3


def test_nullspace_reference_reset_returns_to_nominal(model, q_home):
    reference = NullspaceReference(model, "peg_mount", q_home)
    pos, quat = _site_pose(model, q_home)
    reference.update(pos + [0.1, 0.0, 0.0], quat)
    reference.reset()
    np.testing.assert_allclose(reference.q, q_home)
