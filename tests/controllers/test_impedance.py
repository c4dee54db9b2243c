"""Closed-loop behaviour of the Cartesian impedance controller on the Panda holding a peg."""

import mujoco
import numpy as np
import pytest

from controllers.errors import ControllerError
from controllers.impedance import CartesianImpedanceController, ImpedanceConfig, modal_factors
from tests.helpers.panda_fixtures import arm_model, arm_spec  # noqa: F401

PEG_LENGTH_M = 0.08


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    """The Panda with a 30 x 30 x 80 mm wooden peg held at peg_mount and a site at its tip."""
    spec = arm_spec()
    mount = spec.site("peg_mount")
    peg = spec.body("hand").add_body()
    peg.pos = mount.pos
    geom = peg.add_geom()
    geom.type = mujoco.mjtGeom.mjGEOM_BOX
    geom.size = [0.015, 0.015, PEG_LENGTH_M / 2]
    geom.pos = [0.0, 0.0, PEG_LENGTH_M / 2]
    geom.density = 700.0
    tip = peg.add_site()
    tip.name = "peg_tip"
    tip.pos = [0.0, 0.0, PEG_LENGTH_M]
    return spec.compile()


def _random_spd(rng, scale):
    basis, _ = np.linalg.qr(rng.normal(size=(6, 6)))
    return basis @ np.diag(scale * rng.uniform(0.1, 1.0, 6)) @ basis.T


def test_modal_factors_diagonalise_inertia_and_stiffness():
    rng = np.random.default_rng()
    lambda_inv, stiffness = _random_spd(rng, 10.0), _random_spd(rng, 1000.0)
    p, w = modal_factors(lambda_inv, stiffness)
    np.testing.assert_allclose(p @ p.T, np.linalg.inv(lambda_inv), rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(p @ np.diag(w) @ p.T, stiffness, rtol=1e-8, atol=1e-8)


def test_modal_damping_is_critical_for_decoupled_axes():
    mass_kg, stiffness = np.array([2.0, 3.0, 5.0, 0.1, 0.2, 0.3]), np.array([1e3, 2e3, 3e3, 50.0, 60.0, 70.0])
    p, w = modal_factors(np.diag(1.0 / mass_kg), np.diag(stiffness))
    damping = p @ np.diag(2.0 * np.sqrt(w)) @ p.T
    np.testing.assert_allclose(damping, np.diag(2.0 * np.sqrt(mass_kg * stiffness)), rtol=1e-9, atol=1e-9)


def _start(model, site="peg_tip", config=ImpedanceConfig()):
    """Data at the home keyframe, a controller reset to gravity compensation, and the site's pose."""
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    mujoco.mj_forward(model, data)
    controller = CartesianImpedanceController(model, site, config)
    controller.reset(data.qfrc_bias[controller.dof_slice])
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, data.site_xmat[controller.site_id])
    return data, controller, data.site_xpos[controller.site_id].copy(), quat


def _rotation_error_deg(data, site_id, quat):
    current = np.zeros(4)
    mujoco.mju_mat2Quat(current, data.site_xmat[site_id])
    error = np.zeros(3)
    mujoco.mju_subQuat(error, quat, current)
    return np.degrees(np.linalg.norm(error))


def test_holds_pose_under_gravity_within_1_mm(model):
    data, controller, pos, quat = _start(model)
    data.qvel[:] = 0.2  # start from a disturbed state so holding is not trivial
    controller.step(data, pos, quat, q_nullspace=model.key("home").qpos, n_substeps=4000)
    assert np.linalg.norm(data.site_xpos[controller.site_id] - pos) < 1e-3
    assert _rotation_error_deg(data, controller.site_id, quat) < 0.1


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_10_cm_step_settles_within_1_mm(model, axis):
    data, controller, pos, quat = _start(model)
    target = pos.copy()
    target[axis] -= 0.1
    errors_m = []
    for _ in range(2000):
        controller.step(data, target, quat, q_nullspace=model.key("home").qpos)
        errors_m.append(np.linalg.norm(data.site_xpos[controller.site_id] - target))
    outside = np.nonzero(np.asarray(errors_m) > 1e-3)[0]
    settling_s = (outside[-1] + 1) * model.opt.timestep
    print(f"axis {axis}: 10 cm step settles to 1 mm in {settling_s:.3f} s")
    assert settling_s < 1.5


def test_step_response_does_not_overshoot(model):
    data, controller, pos, quat = _start(model)
    progress_m = []
    for _ in range(1500):
        controller.step(data, pos + [0.1, 0.0, 0.0], quat, q_nullspace=model.key("home").qpos)
        progress_m.append(data.site_xpos[controller.site_id][0] - pos[0])
    assert max(progress_m) < 0.1 + 1e-3  # critical damping of the Cartesian modes


def test_torque_and_torque_rate_limits_hold_at_every_step(model):
    data, controller, pos, quat = _start(model)
    config = controller.config
    flipped = np.zeros(4)
    mujoco.mju_mulQuat(flipped, np.array([0.0, 0.0, 0.0, 1.0]), quat)  # 180 deg about world z: saturates
    previous = controller.last_torque
    max_rate, max_ratio = 0.0, 0.0
    for _ in range(1000):
        controller.step(data, pos + [0.3, 0.3, -0.2], flipped)
        max_rate = max(max_rate, np.max(np.abs(data.ctrl - previous)))
        max_ratio = max(max_ratio, np.max(np.abs(data.ctrl) / config.torque_limits))
        previous = data.ctrl.copy()
    assert max_rate <= config.torque_rate_limit * model.opt.timestep + 1e-9
    assert max_ratio <= 1.0 + 1e-12
    assert max_rate == pytest.approx(config.torque_rate_limit * model.opt.timestep)  # the limit was active


def test_torque_at_rest_on_target_is_gravity_compensation(model):
    data, controller, pos, quat = _start(model)
    mujoco.mj_step1(model, data)
    tau = controller.compute_torque(data, pos, quat, q_nullspace=data.qpos.copy())
    np.testing.assert_allclose(tau, data.qfrc_bias, atol=1e-9)


@pytest.mark.parametrize(
    "stiffness",
    [
        np.eye(3),
        np.eye(6)[:, :5],
        np.diag([1000.0, 1000.0, 1000.0, 50.0, 50.0, -1.0]),
        np.eye(6) + np.triu(np.ones((6, 6)), 1),
        np.full((6, 6), np.nan),
        "stiff",
    ],
    ids=["3x3", "6x5", "negative", "asymmetric", "nan", "string"],
)
def test_bad_stiffness_raises_controller_error(model, stiffness):
    data, controller, pos, quat = _start(model)
    with pytest.raises(ControllerError, match="stiffness"):
        controller.step(data, pos, quat, stiffness=stiffness)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"target_pos": [0.0, 0.0]}, "target_pos"),
        ({"target_quat": [0.0, 0.0, 0.0, 0.0]}, "target_quat"),
        ({"q_nullspace": np.zeros(6)}, "q_nullspace"),
        ({"n_substeps": 0}, "n_substeps"),
    ],
)
def test_bad_inputs_raise_controller_error(model, kwargs, match):
    data, controller, pos, quat = _start(model)
    call = {"target_pos": pos, "target_quat": quat, **kwargs}
    with pytest.raises(ControllerError, match=match):
        controller.step(data, **call)


def test_unknown_site_raises_controller_error(model):
    with pytest.raises(ControllerError, match="no_such_site"):
        CartesianImpedanceController(model, "no_such_site")


def test_non_positive_gain_raises_controller_error():
    with pytest.raises(ControllerError, match="translational_stiffness"):
        ImpedanceConfig(translational_stiffness=0.0)


def _deflection_under_force(model, stiffness, force_n):
    """Steady site deflection when a constant force pushes the peg at its centre of mass."""
    data, controller, pos, quat = _start(model)
    peg_body = model.site("peg_tip").bodyid[0]
    data.xfrc_applied[peg_body, :3] = force_n
    controller.step(data, pos, quat, stiffness=stiffness, q_nullspace=model.key("home").qpos, n_substeps=3000)
    return data.site_xpos[controller.site_id] - pos


@pytest.mark.parametrize("k_n_per_m", [800.0, 3000.0])
def test_deflection_follows_hookes_law(model, k_n_per_m):
    force = np.array([10.0, 0.0, 0.0])
    stiffness = np.diag([k_n_per_m] * 3 + [80.0] * 3)
    deflection = _deflection_under_force(model, stiffness, force)
    np.testing.assert_allclose(deflection, force / k_n_per_m, atol=0.2 * 10.0 / k_n_per_m)


def test_stiffer_gain_deflects_less(model):
    force = np.array([0.0, 10.0, 0.0])
    soft = _deflection_under_force(model, np.diag([800.0] * 3 + [80.0] * 3), force)
    stiff = _deflection_under_force(model, np.diag([3000.0] * 3 + [80.0] * 3), force)
    assert np.linalg.norm(stiff) < 0.5 * np.linalg.norm(soft)


def test_full_stiffness_matrix_deflects_along_its_compliance(model):
    rng = np.random.default_rng()
    basis, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    stiffness = np.zeros((6, 6))
    stiffness[:3, :3] = basis @ np.diag([600.0, 1500.0, 3000.0]) @ basis.T
    stiffness[3:, 3:] = 80.0 * np.eye(3)
    force = np.array([6.0, -8.0, 5.0])
    expected = np.linalg.solve(stiffness[:3, :3], force)
    deflection = _deflection_under_force(model, stiffness, force)
    assert np.linalg.norm(deflection - expected) < 0.2 * np.linalg.norm(expected)


@pytest.fixture(scope="module")
def model_with_free_peg() -> mujoco.MjModel:
    """The Panda beside a peg on a free joint (another kinematic tree): nv = 13, nu = 7."""
    spec = arm_spec()
    peg = spec.worldbody.add_body(pos=[0.3, -0.4, 0.2])
    peg.add_freejoint()
    peg.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.015, 0.015, 0.04])
    peg.add_site(name="free_peg_site")
    return spec.compile()


def test_holds_pose_beside_a_free_body(model_with_free_peg):
    model = model_with_free_peg
    data, controller, pos, quat = _start(model, site="peg_mount")
    controller.step(data, pos + [0.0, 0.0, 0.05], quat, n_substeps=2000)
    assert np.linalg.norm(data.site_xpos[controller.site_id] - pos - [0.0, 0.0, 0.05]) < 1e-3


def test_site_off_the_arm_raises_controller_error(model_with_free_peg):
    with pytest.raises(ControllerError, match="free_peg_site"):
        CartesianImpedanceController(model_with_free_peg, "free_peg_site")


def _cartesian_inertia_inv(model, data, site_id):
    jac = np.zeros((6, model.nv))
    mujoco.mj_jacSite(model, data, jac[:3], jac[3:], site_id)
    m_full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, m_full)
    return jac @ np.linalg.solve(m_full, jac.T)


def test_pose_lead_of_an_acceleration_is_k_inverse_lambda_accel(model):
    data, controller, _, _ = _start(model)
    accel = np.array([0.3, -0.2, 0.1, 0.5, 0.0, -0.4])
    lam = np.linalg.inv(_cartesian_inertia_inv(model, data, controller.site_id))
    expected = np.linalg.solve(controller.default_stiffness, lam @ accel)
    lead = controller.pose_lead(data, np.zeros(6), accel)
    np.testing.assert_allclose(lead, expected, rtol=1e-3, atol=1e-9)


def test_pose_lead_damping_squares_to_four_zeta_squared_lambda_inv_k(model):
    data, controller, _, _ = _start(model)
    k = controller.default_stiffness
    damping = np.column_stack([k @ controller.pose_lead(data, e) for e in np.eye(6)])
    lam_inv = _cartesian_inertia_inv(model, data, controller.site_id)
    zeta = controller.config.damping_ratio
    np.testing.assert_allclose(np.linalg.matrix_power(lam_inv @ damping, 2), 4 * zeta**2 * lam_inv @ k,
                               rtol=1e-3, atol=1e-6 * np.abs(lam_inv @ k).max())


def test_substep_hooks_run_around_every_physics_step(model):
    data, controller, pos, quat = _start(model)
    calls = []

    def before():
        calls.append(("before", data.time))

    def after():
        calls.append(("after", data.time))
        return False

    taken = controller.step(data, pos, quat, n_substeps=4, before_substep=before, after_substep=after)
    dt = model.opt.timestep
    assert taken == 4
    expected = [(kind, pytest.approx(dt * (k + (kind == "after")))) for k in range(4) for kind in ("before", "after")]
    assert calls == expected


def test_after_substep_returning_true_stops_the_loop(model):
    data, controller, pos, quat = _start(model)
    three_steps_s = 3 * model.opt.timestep
    taken = controller.step(data, pos, quat, n_substeps=10, after_substep=lambda: data.time >= three_steps_s - 1e-12)
    assert taken == 3
    assert data.time == pytest.approx(three_steps_s)


def test_a_stiffness_changed_in_place_is_checked_again(model):
    controller = CartesianImpedanceController(model, "peg_tip")
    k = np.diag([800.0, 800.0, 800.0, 30.0, 30.0, 30.0])
    np.testing.assert_array_equal(controller.checked_stiffness(k), k)
    k[2, 2] = -5.0  # the same array, no longer positive definite
    with pytest.raises(ControllerError, match="positive definite"):
        controller.checked_stiffness(k)
    k[2, 2] = np.nan
    with pytest.raises(ControllerError, match="non-finite"):
        controller.checked_stiffness(k)


def test_the_tool_load_is_minus_the_weight_through_the_jacobian_before_each_step(model):
    """qfrc_applied on the arm = -(m g)^T J_c at p_c = p_site - d z_site, from the kinematics the step starts
    with (those of the previous step, as a hook before mj_step1 sees them)."""
    data, controller, pos, quat = _start(model)
    mass, depth = 0.35, 0.04
    controller.set_tool_load(mass, depth)
    seen = []

    def before():  # the kinematics the tool load is computed from
        site = controller.site_id
        point = data.site_xpos[site] - data.site_xmat[site].reshape(3, 3)[:, 2] * depth
        jacp = np.zeros((3, model.nv))
        mujoco.mj_jac(model, data, jacp, None, point, model.site_bodyid[site])
        seen.append(-(jacp[:, controller.dof_slice].T @ (mass * model.opt.gravity)))

    def after():
        np.testing.assert_allclose(data.qfrc_applied[controller.dof_slice], seen[-1], rtol=1e-12, atol=1e-12)
        return False

    controller.step(data, pos, quat, n_substeps=3, before_substep=before, after_substep=after)
    assert len(seen) == 3 and np.abs(seen[-1]).max() > 0.1  # a real load: 0.35 kg at ~0.5 m from the base
    controller.set_tool_load(0.0, depth)  # removed: the arm's applied forces are left alone
    data.qfrc_applied[:] = 0.0
    controller.step(data, pos, quat, n_substeps=2)
    assert not data.qfrc_applied.any()


@pytest.mark.parametrize("mass, depth", [(-1.0, 0.0), (np.nan, 0.0), (1.0, np.inf)])
def test_a_bad_tool_load_raises_controller_error(model, mass, depth):
    with pytest.raises(ControllerError, match="tool load"):
        CartesianImpedanceController(model, "peg_tip").set_tool_load(mass, depth)


def _pose_lead_in_numpy(controller, data, twist, accel, stiffness):
    """The pose lead as it was computed before it was one compiled call: the bindings' mj_jacSite and mj_solveM,
    the kernel's Lambda^-1 and modal factors, then matvec and solve of numerics.small_linalg."""
    from controllers import impedance_kernel as kernel
    from numerics.small_linalg import matvec, solve

    model = controller.model
    jac, jac_minv = np.zeros((6, model.nv)), np.zeros((6, model.nv))
    mujoco.mj_jacSite(model, data, jac[:3], jac[3:], controller.site_id)
    mujoco.mj_solveM(model, data, jac_minv, jac)
    lambda_inv, p, w = np.zeros((6, 6)), np.zeros((6, 6)), np.zeros(6)
    kernel.inertia_inverse_into(jac, jac_minv, 1e-6, lambda_inv)
    assert kernel.modal_factors_into(lambda_inv, stiffness, p, w, np.zeros((3, 6, 6)))
    modal = (2.0 * controller.config.damping_ratio * np.sqrt(np.maximum(w, 0.0))) * matvec(p.T, twist)
    if accel is not None:
        modal += matvec(p.T, accel)
    return solve(stiffness, matvec(p, modal))


def test_the_compiled_pose_lead_equals_its_numpy_steps_bit_for_bit(model):
    """On random arm states, twists, accelerations and SPD stiffnesses (with and without an acceleration)."""
    data, controller, _, _ = _start(model)
    rng = np.random.default_rng(11)
    home = data.qpos.copy()
    for trial in range(60):
        data.qpos[:] = home + rng.normal(0.0, 0.3, model.nq)
        data.qvel[:] = rng.normal(0.0, 0.5, model.nv)
        mujoco.mj_forward(model, data)
        k = controller.default_stiffness if trial % 3 == 0 else _random_spd(rng, 3000.0)
        twist, accel = rng.normal(0.0, 0.2, 6), (None if trial % 2 else rng.normal(0.0, 1.0, 6))
        expected = _pose_lead_in_numpy(controller, data, twist, accel, k)
        got = controller.pose_lead(data, twist, accel, None if trial % 3 == 0 else k)
        assert np.array_equal(got, expected), (trial, got - expected)


def test_a_non_finite_twist_or_acceleration_is_refused_by_name(model):
    data, controller, _, _ = _start(model)
    with pytest.raises(ControllerError, match="twist"):
        controller.pose_lead(data, [0.0, np.nan, 0.0, 0.0, 0.0, 0.0])
    with pytest.raises(ControllerError, match="accel"):
        controller.pose_lead(data, np.zeros(6), [np.inf, 0.0, 0.0, 0.0, 0.0, 0.0])
