"""The compiled differential-IK step (controllers.ik_kernel) solves mink's QP: same joint reference as mink + daqp."""

import mink
import mujoco
import numpy as np
import pytest

from assets import PANDA_XML
from controllers import ik_kernel
from controllers.ik import IKConfig, NullspaceReference


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(PANDA_XML))


def _mink_reference(model, site, q_start, q_nominal, targets, config=IKConfig(), iterations=3):
    """The same warm-started iterations with mink (frame + posture task, configuration limit, daqp)."""
    configuration = mink.Configuration(model)
    configuration.update(q_start.copy())
    frame = mink.FrameTask(site, "site", position_cost=1.0, orientation_cost=1.0, lm_damping=config.lm_damping)
    posture = mink.PostureTask(model, cost=config.posture_cost)
    posture.set_target(q_nominal)
    limits = [mink.ConfigurationLimit(model)]
    out = []
    for pos, quat in targets:
        frame.set_target(mink.SE3(wxyz_xyz=np.concatenate([quat, pos])))
        for _ in range(iterations):
            v = mink.solve_ik(configuration, [frame, posture], dt=1.0, solver="daqp", damping=1e-9, limits=limits)
            configuration.integrate_inplace(v, 1.0)
        out.append(configuration.q.copy())
    return np.array(out)


@pytest.mark.parametrize("seed", range(4))
def test_nullspace_reference_equals_mink(model, seed):
    rng = np.random.default_rng(seed)
    q_home = model.key("home").qpos.copy()
    start = np.clip(q_home + rng.uniform(-0.3, 0.3, model.nq), model.jnt_range[:, 0], model.jnt_range[:, 1])
    data = mujoco.MjData(model)
    data.qpos[:] = start
    mujoco.mj_kinematics(model, data)
    site = model.site("peg_mount").id
    quat0 = np.zeros(4)
    mujoco.mju_mat2Quat(quat0, data.site_xmat[site])
    offset, axis = rng.normal(0.0, 0.1, 3), rng.normal(size=3)
    targets = []
    for k in range(15):  # a target moving 10 cm and up to ~30 deg away, as a skill would command
        turn, quat = np.zeros(4), np.zeros(4)
        mujoco.mju_axisAngle2Quat(turn, axis / np.linalg.norm(axis), 0.5 * k / 15)
        mujoco.mju_mulQuat(quat, turn, quat0)
        targets.append((data.site_xpos[site] + offset * k / 15, quat))
    want = _mink_reference(model, "peg_mount", start, q_home, targets)
    reference = NullspaceReference(model, "peg_mount", q_home)
    reference.reset(start)
    got = np.array([reference.update(pos, quat) for pos, quat in targets])
    np.testing.assert_allclose(got, want, atol=1e-8, rtol=0)  # daqp's own tolerance is ~1e-10 here


@pytest.mark.parametrize("seed", range(30))
def test_box_qp_solution_satisfies_kkt(seed):
    rng = np.random.default_rng(seed)
    n = 9
    a = rng.normal(size=(n, n))
    h = a @ a.T + 1e-4 * np.eye(n)
    c = rng.normal(0.0, 3.0, n)
    lower, upper = -rng.uniform(0.0, 0.3, n), rng.uniform(0.0, 0.3, n)
    lower[0], upper[0] = -np.inf, np.inf  # an unlimited dof (free joint)
    x = np.zeros(n)
    assert ik_kernel.solve_box_qp(h, c, lower, upper, x)
    g = h @ x + c
    assert np.all(x >= lower - 1e-15) and np.all(x <= upper + 1e-15)
    at_lower, at_upper = x <= lower + 1e-12, x >= upper - 1e-12
    free = ~(at_lower | at_upper)
    np.testing.assert_allclose(g[free], 0.0, atol=1e-9)  # stationary in the free coordinates
    assert np.all(g[at_lower] >= -1e-9) and np.all(g[at_upper] <= 1e-9)  # multipliers of active bounds >= 0


def test_box_qp_starts_on_a_bound_that_excludes_zero():
    x = np.zeros(2)
    assert ik_kernel.solve_box_qp(np.eye(2), np.array([-1.0, 0.0]), np.array([0.5, -1.0]), np.array([2.0, 1.0]), x)
    np.testing.assert_allclose(x, [1.0, 0.0])


def _mink_solve_ik(model, site, pos, quat, q_nominal, config=IKConfig()):
    """solve_ik's two phases (choose the posture, then refine to tolerance) with mink + daqp."""
    configuration = mink.Configuration(model)
    configuration.update(q_nominal.copy())
    frame = mink.FrameTask(site, "site", position_cost=1.0, orientation_cost=1.0, lm_damping=config.lm_damping)
    frame.set_target(mink.SE3(wxyz_xyz=np.concatenate([quat, pos])))
    posture = mink.PostureTask(model, cost=config.posture_cost)
    posture.set_target(q_nominal)
    limits = [mink.ConfigurationLimit(model)]

    def iterate():
        v = mink.solve_ik(configuration, [frame, posture], dt=1.0, solver="daqp", damping=1e-9, limits=limits)
        configuration.integrate_inplace(v, 1.0)

    previous = configuration.q.copy()
    for _ in range(config.max_iterations):
        iterate()
        if np.max(np.abs(configuration.q - previous)) < 1e-6:
            break
        previous = configuration.q.copy()
    posture.set_cost(config.refine_posture_cost)
    for _ in range(20):
        iterate()
    return configuration.q.copy()


def _reachable_pose(model, seed):
    """The peg_mount pose of a random posture near "home" (reachable by construction), and the home joints."""
    rng = np.random.default_rng(seed)
    q_home = model.key("home").qpos.copy()
    data = mujoco.MjData(model)
    data.qpos[:] = np.clip(q_home + rng.uniform(-0.4, 0.4, model.nq), model.jnt_range[:, 0], model.jnt_range[:, 1])
    mujoco.mj_kinematics(model, data)
    site = model.site("peg_mount").id
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, data.site_xmat[site])
    return data.site_xpos[site].copy(), quat, q_home


@pytest.mark.parametrize("seed", range(3))
def test_solve_ik_reaches_the_posture_mink_reaches(model, seed):
    from controllers.ik import solve_ik

    pos, quat, q_home = _reachable_pose(model, seed)
    np.testing.assert_allclose(solve_ik(model, "peg_mount", pos, quat, q_home),
                               _mink_solve_ik(model, "peg_mount", pos, quat, q_home), atol=1e-5, rtol=0)


@pytest.mark.parametrize("seed", range(3))
def test_solve_ik_with_mink_is_the_compiled_solve(model, seed):
    from controllers.ik import solve_ik

    pos, quat, q_home = _reachable_pose(model, 10 + seed)
    compiled = solve_ik(model, "peg_mount", pos, quat, q_home)
    with_mink = solve_ik(model, "peg_mount", pos, quat, q_home, solver="mink")
    np.testing.assert_allclose(with_mink, compiled, atol=1e-9, rtol=0)  # the same iterates, to daqp's tolerance


def test_solve_ik_with_mink_reports_an_unreachable_pose(model):
    from controllers.errors import ControllerError
    from controllers.ik import solve_ik

    q_home = model.key("home").qpos.copy()
    with pytest.raises(ControllerError, match="unreachable"):
        solve_ik(model, "peg_mount", [2.0, 0.0, 0.5], [1.0, 0.0, 0.0, 0.0], q_home, solver="mink")
    with pytest.raises(ControllerError, match="solver"):
        solve_ik(model, "peg_mount", [0.5, 0.0, 0.5], [1.0, 0.0, 0.0, 0.0], q_home, solver="pinocchio")
