"""The imperfections of the cell (envs.task.perturbation, envs.sim.model_error, envs.sim.joint_friction, the in-hand pose
of envs.sim.env) have the physical effect they model: an in-hand offset and tilt stay in the grasp, a payload error
sags the arm by e m g / K and shows on the zeroed wrist sensor, joint friction stops a compliant arm short of its
target. The plant's effects are measured under a controller without the friction observer (`bare`), which would
compensate the friction, the payload error its tare sees and the torque noise; what the observer does about them is
tests/controllers/test_friction_observer.py's."""

from __future__ import annotations

import math

import numpy as np
import pytest

from envs.cell.scene import build_scene
from envs.cell.scene_config import SceneConfig
from envs.poses import Pose
from envs.poses import quat_conj, quat_mul, quat_to_rotvec
from envs.sim.env import PegInHoleEnv
from envs.sim.episode_config import EpisodeConfig
from controllers.impedance import ImpedanceConfig
from envs.sim.joint_friction import PANDA_COULOMB_NM, PANDA_VISCOUS_NM_S, smooth_parameters
from envs.task.perturbation import Perturbation, PerturbationRanges
from numerics.quaternion import quat_to_mat

GRAVITY_M_S2 = 9.81


@pytest.fixture(scope="module")
def env() -> PegInHoleEnv:
    return PegInHoleEnv(scene=build_scene(SceneConfig()), episode_config=EpisodeConfig(time_limit_s=5.0))


def _bare(law: str = "stick_slip") -> PegInHoleEnv:
    """An environment whose impedance controller has no friction observer (the plant's effects as they are)."""
    return PegInHoleEnv(scene=build_scene(SceneConfig()),
                        episode_config=EpisodeConfig(time_limit_s=5.0,
                                                     perturbations=PerturbationRanges(joint_friction_model=law)),
                        controller_config=ImpedanceConfig(friction_observer_time_s=0.0))


@pytest.fixture(scope="module")
def bare() -> PegInHoleEnv:
    return _bare()


def _above(env: PegInHoleEnv) -> Pose:
    return Pose(env.nominal_goal.pos + 0.06 * env.hole_axis, env.nominal_goal.quat)


PULL_STIFFNESS = np.diag([300.0] * 3 + [30.0] * 3)
"""A compliant arm's stiffness (N/m, N m/rad) for the pulls of the joint-friction tests."""


def _pulled(env: PegInHoleEnv, start: Pose, scale: float) -> Pose:
    """Reset at ``start`` with joint friction x ``scale`` and pull the compliant arm 20 mm along x for 30 periods;
    the pull's target."""
    env.reset(start_pose=start, perturbation=Perturbation(joint_friction_scale=scale))
    target = Pose(start.pos + [0.02, 0.0, 0.0], start.quat)
    for _ in range(30):
        env.step(target, PULL_STIFFNESS)
    return target


def _peg_in_hand(env: PegInHoleEnv) -> tuple[np.ndarray, float, float]:
    """(the peg top's offset in the tcp frame (m), tilt about the hand's y (deg), turn about its axis (deg))."""
    data, adr = env.data, env.scene.ids.peg_qpos_adr
    hand = data.site_xmat[env.tcp_site].reshape(3, 3)
    relative = hand.T @ quat_to_mat(data.qpos[adr + 3:adr + 7])
    offset = hand.T @ (data.qpos[adr:adr + 3] - data.site_xpos[env.tcp_site])
    return (offset, math.degrees(math.atan2(relative[0, 2], relative[2, 2])),
            math.degrees(math.atan2(relative[1, 0], relative[0, 0])))


def test_an_in_hand_offset_and_tilt_stay_in_the_grasp(env) -> None:
    start = _above(env)
    env.reset(start_pose=start)
    nominal, _, _ = _peg_in_hand(env)
    env.reset(start_pose=start, perturbation=Perturbation(grasp_lateral_m=0.002, grasp_tilt_deg=3.0,
                                                          grasp_yaw_deg=2.0))
    for _ in range(100):  # 1 s held in free space after the grasp settled
        env.step(start)
    offset, tilt, yaw = _peg_in_hand(env)
    assert offset[0] - nominal[0] == pytest.approx(0.002, abs=2e-5)
    assert abs(offset[1] - nominal[1]) < 1e-4  # across the pads: the yawed peg rests on its corners
    assert tilt == pytest.approx(3.0, abs=0.02)
    assert 1.8 < yaw <= 2.0  # the flat pads turn a yawed square peg back a little (3.0 -> 2.9 deg measured)


@pytest.mark.parametrize("error", [0.5, -0.3])
def test_a_payload_error_sags_the_arm_by_e_m_g_over_k_and_shows_on_the_sensor(bare, error) -> None:
    env = bare
    start, k_n_m = _above(env), 500.0
    stiffness = np.diag([k_n_m] * 3 + [50.0] * 3)
    mass_kg = env.model_error.mass_kg
    heights = []
    for e in (0.0, error):
        env.reset(start_pose=start, perturbation=Perturbation(payload_mass_error=e))
        for _ in range(150):
            env.step(start, stiffness)
        heights.append(env.observation.tcp.pos[2])
        sensor = env.data.site_xmat[env.scene.ids.ft_site].reshape(3, 3) @ env.observation.wrist_wrench[:3]
    weight_n = error * mass_kg * GRAVITY_M_S2
    assert heights[1] - heights[0] == pytest.approx(-weight_n / k_n_m, rel=0.02)
    assert sensor[2] == pytest.approx(-weight_n, rel=0.02)  # the sensor was zeroed for the nominal payload
    env.model_error.apply(Perturbation())
    assert env.model.body_mass[env.scene.ids.peg_body] == mass_kg


def test_joint_friction_stops_a_compliant_arm_short_of_its_target(bare) -> None:
    """A 10 mm move at 300 N/m: within 0.2 mm without friction, more than 2 mm short with the identified stick-slip
    friction doubled (0.3-0.72 N m per joint: the harsh cell's)."""
    env = bare
    start = _above(env)
    target = Pose(start.pos + [0.01, 0.0, 0.0], start.quat)
    stiffness = np.diag([300.0] * 3 + [30.0] * 3)
    errors = []
    for scale in (0.0, 2.0):
        env.reset(start_pose=start, perturbation=Perturbation(joint_friction_scale=scale))
        arm = list(env.scene.ids.arm_dof_adr)
        assert np.allclose(env.model.dof_frictionloss[arm], scale * np.asarray(PANDA_COULOMB_NM))
        for _ in range(200):
            env.step(target, stiffness)
        errors.append(float(np.linalg.norm(env.observation.tcp.pos - target.pos)))
    assert errors[0] < 2e-4 and errors[1] > 2e-3
    env.joint_friction.apply(Perturbation())
    assert not env.model.dof_frictionloss.any()


def test_a_payload_centre_of_mass_error_turns_the_compliant_wrist(bare) -> None:
    """The peg's centre of mass off its axis, unknown to the controller's tool load: its weight's moment c x m g
    turns the wrist (held at 2 N m/rad) about the horizontal axis perpendicular to c, by an angle proportional to |c|
    and at most |c| m g / K_rot (the arm's posture stiffness takes some of the moment; 67 % of it measured)."""
    env = bare
    start, k_rot = _above(env), 2.0
    stiffness = np.diag([500.0] * 3 + [k_rot] * 3)
    quats, moments = [], []
    for com_x in (0.0, 0.004, 0.008):
        env.reset(start_pose=start, perturbation=Perturbation(payload_com_x_m=com_x))
        for _ in range(200):
            env.step(start, stiffness)
        quats.append(env.observation.tcp.quat.copy())
        peg_x = env.data.xmat[env.scene.ids.peg_body].reshape(3, 3)[:, 0]
        moments.append(np.cross(com_x * peg_x, [0.0, 0.0, -env.model_error.mass_kg * GRAVITY_M_S2]))
    turns = [quat_to_rotvec(quat_mul(q, quat_conj(quats[0]))) for q in quats[1:]]
    assert np.linalg.norm(turns[1]) == pytest.approx(2.0 * np.linalg.norm(turns[0]), rel=0.05)
    for turn, moment in zip(turns, moments[1:]):
        cosine = turn @ moment / (np.linalg.norm(turn) * np.linalg.norm(moment))
        assert cosine > np.cos(np.radians(10.0))  # turned the way the weight's moment turns it
        assert 0.5 < np.linalg.norm(turn) / (np.linalg.norm(moment) / k_rot) <= 1.0
    env.model_error.apply(Perturbation())
    assert env.model.body_ipos[env.scene.ids.peg_body, 0] == 0.0


def test_viscous_joint_friction_is_in_the_simulated_arm_and_slows_it(bare) -> None:
    """The identified viscous friction, scaled by 10 (up to 2.3 N m s/rad): the simulated joints are held back by
    -(d_0 + s f_v) qdot, and a compliant arm pulled 20 mm along x travels less in 0.3 s than without it (the Coulomb
    part slows it too)."""
    env = bare
    start = _above(env)
    arm = list(env.scene.ids.arm_dof_adr)
    base_damping = env.model.dof_damping[arm].copy()
    travelled = []
    for scale in (0.0, 10.0):
        _pulled(env, start, scale)
        data = env.data
        damping = base_damping + scale * np.asarray(PANDA_VISCOUS_NM_S)
        # (qfrc_passive is of the state the last step started from, qvel of the one it ended in: 2 %)
        assert np.allclose(data.qfrc_passive[arm], -damping * data.qvel[arm], rtol=0.05, atol=1e-4)
        travelled.append(float(env.observation.tcp.pos[0] - start.pos[0]))
    assert travelled[1] < 0.9 * travelled[0]
    env.joint_friction.apply(Perturbation())
    assert np.array_equal(env.model.dof_damping[arm], base_damping)


def test_the_smooth_joint_friction_is_delivered_less_by_the_joints() -> None:
    """The identified smooth law (scaled by 2): each arm joint delivers its command less tau_f(qdot) of eq. (4) at
    its speed (the law's own command does not contain it), zero at rest; a compliant arm pulled 20 mm travels less."""
    env = _bare("smooth")
    start = _above(env)
    arm = list(env.scene.ids.arm_dof_adr)
    phi = smooth_parameters(2.0)
    travelled = []
    for scale in (0.0, 2.0):
        target = _pulled(env, start, scale)
        travelled.append(float(env.observation.tcp.pos[0] - start.pos[0]))
        for _ in range(5):  # single physics steps: the speed each starts from is the one the actuator sees
            qdot = env.data.qvel[arm].copy()
            env.controller.step(env.data, target.pos, target.quat, PULL_STIFFNESS, None, 1)
            delivered = env.data.ctrl[:len(arm)] - env.controller.last_torque
            want = -scale / 2.0 * (phi[:, 0] / (1.0 + np.exp(-phi[:, 1] * (qdot + phi[:, 2])))
                                   - phi[:, 0] / (1.0 + np.exp(-phi[:, 1] * phi[:, 2])))
            np.testing.assert_allclose(delivered, want, rtol=1e-9, atol=1e-12)
            assert scale == 0.0 or np.abs(want).max() > 1e-3  # moving: the law delivers a friction
        assert not env.model.dof_frictionloss[arm].any()  # no stick-slip with the smooth law
    assert travelled[1] < 0.95 * travelled[0]


def test_torque_noise_is_delivered_by_the_joints_and_jitters_a_held_arm(bare) -> None:
    """Each arm joint delivers its command plus the episode's noise (the law's own command does not contain it),
    and the held tcp's jitter grows in proportion to sigma (1.0 vs 0.5 N m: 2x within 20 %); the same episode
    draws the same noise."""
    env = bare
    start = _above(env)
    arm = list(env.scene.ids.arm_dof_adr)
    jitters, traces = {}, {}
    for sigma in (0.0, 0.5, 1.0, 1.0):
        env.reset(start_pose=start, perturbation=Perturbation(actuator_noise_nm=sigma))
        positions = []
        for _ in range(100):
            env.step(start)
            positions.append(env.observation.tcp.pos.copy())
            delivered = env.data.qfrc_actuator[arm] - env.controller.last_torque
            if sigma == 0.0:
                assert np.array_equal(delivered, np.zeros(len(arm)))
            else:
                assert np.abs(delivered).max() > 0.0
        positions = np.asarray(positions[20:])
        jitters[sigma] = float(np.linalg.norm(positions.std(axis=0)))
        traces.setdefault(sigma, []).append(positions)
    assert jitters[0.0] < 0.1 * jitters[0.5]
    assert jitters[1.0] == pytest.approx(2.0 * jitters[0.5], rel=0.2)
    assert np.array_equal(traces[1.0][0], traces[1.0][1])
    env.reset(start_pose=start)  # no noise after a noiseless reset
    env.step(start)
    assert np.array_equal(env.data.qfrc_actuator[arm], env.controller.last_torque)


def test_the_realistic_preset_is_the_contact_task_with_every_imperfection() -> None:
    from envs.evaluation.sensitivity import IMPERFECTIONS, realistic
    from envs.task.task import Task, preset

    assert preset("realistic") == realistic(preset("contact"))
    assert preset("contact") == Task()
    for name in IMPERFECTIONS:  # each imperfection changes the task (none is a no-op at its magnitude)
        from envs.evaluation.sensitivity import with_imperfection
        assert with_imperfection(Task(), name) != Task()


def test_the_policy_sees_the_hole_where_the_cell_believes_it(env) -> None:
    """An observation error moves what the policy is told (nominal_hole, nominal_goal), not the real hole."""
    from envs.policies.interface import observe

    start = _above(env)
    env.reset(start_pose=start, perturbation=Perturbation(hole_dx_m=0.0005))
    true_hole, told = env.hole, observe(env)
    assert np.array_equal(told.nominal_hole.pos, env.nominal_hole.pos)
    env.reset(start_pose=start, perturbation=Perturbation(hole_dx_m=0.0005, observed_hole_dx_m=0.001,
                                                          observed_hole_yaw_deg=2.0))
    seen = observe(env)
    assert np.array_equal(env.hole.pos, true_hole.pos) and np.array_equal(env.hole.quat, true_hole.quat)
    assert np.linalg.norm(seen.nominal_hole.pos - env.nominal_hole.pos) == pytest.approx(0.001, abs=1e-9)
    turned = math.degrees(2.0 * math.acos(min(1.0, abs(float(np.dot(seen.nominal_hole.quat, env.nominal_hole.quat))))))
    assert turned == pytest.approx(2.0, abs=1e-6)
    assert np.linalg.norm(seen.nominal_goal.pos - env.nominal_goal.pos) == pytest.approx(0.001, abs=1e-6)


def test_a_measured_hole_observation_is_the_true_hole_moved_by_the_sensor_error() -> None:
    """hole_observation = "measured": the policy is told the true (perturbed) hole, off by the observation error only;
    "nominal" tells it the nominal hole, whatever the true one."""
    from dataclasses import replace

    from envs.policies.interface import observe
    from envs.task.perturbation import PerturbationRanges

    measured = PegInHoleEnv(scene=build_scene(SceneConfig()), episode_config=EpisodeConfig(
        time_limit_s=5.0, perturbations=PerturbationRanges(hole_observation="measured")))
    start = _above(measured)
    error = Perturbation(hole_dx_m=0.0008, hole_dy_m=-0.0003, hole_yaw_deg=0.7, hole_tilt_deg=0.5, hole_tilt_dir_deg=40.0)
    measured.reset(start_pose=start, perturbation=error)
    seen = observe(measured)
    assert np.linalg.norm(measured.goal.pos - measured.nominal_goal.pos) > 5e-4  # the true hole moved
    for told, true in ((seen.nominal_hole, measured.hole), (seen.nominal_goal, measured.goal)):
        assert np.array_equal(told.pos, true.pos) and np.array_equal(told.quat, true.quat)
    sensed = replace(error, observed_hole_dx_m=0.0001, observed_hole_tilt_deg=0.2, observed_hole_tilt_dir_deg=90.0)
    measured.reset(start_pose=start, perturbation=sensed)
    seen = observe(measured)
    assert np.linalg.norm(seen.nominal_hole.pos - measured.hole.pos) == pytest.approx(1e-4, abs=1e-9)
    tilted = math.degrees(2.0 * math.acos(min(1.0, abs(float(np.dot(seen.nominal_hole.quat, measured.hole.quat))))))
    assert tilted == pytest.approx(0.2, abs=1e-6)
    nominal = PegInHoleEnv(scene=build_scene(SceneConfig()), episode_config=EpisodeConfig(time_limit_s=5.0))
    nominal.reset(start_pose=start, perturbation=error)
    seen = observe(nominal)
    assert np.array_equal(seen.nominal_goal.pos, nominal.nominal_goal.pos)


def test_the_observation_tilt_is_drawn_within_its_bound_and_only_with_an_observation_error() -> None:
    from envs.task.perturbation import PerturbationRanges, sample_perturbation

    rng = np.random.default_rng(3)
    draws = [sample_perturbation(PerturbationRanges(hole_observation_error_m=0.001, hole_observation_error_deg=0.3,
                                                    hole_observation_tilt_deg=0.5), rng) for _ in range(200)]
    tilts = np.array([d.observed_hole_tilt_deg for d in draws])
    directions = np.array([d.observed_hole_tilt_dir_deg for d in draws])
    assert tilts.min() >= 0.0 and tilts.max() <= 0.5 and tilts.max() > 0.4
    assert directions.min() >= 0.0 and directions.max() < 360.0 and np.ptp(directions) > 300.0
    plain = sample_perturbation(PerturbationRanges(hole_error_m=0.001, hole_error_deg=1.0,
                                                   hole_observation_error_deg=1.0), rng)
    assert (plain.observed_hole_tilt_deg, plain.observed_hole_tilt_dir_deg) == (0.0, 0.0)
    with pytest.raises(Exception, match="hole_observation"):
        PerturbationRanges(hole_observation="camera")


def test_the_observation_tilt_leaves_the_episode_noise_as_it_was() -> None:
    """The sensors' generator is seeded by the fields before the observation tilt (added later), so an episode reads
    the noise it read before; the other fields still tell episodes apart."""
    from dataclasses import replace

    from envs.sim.sensor_reading import episode_generator

    episode = Perturbation(hole_dx_m=0.0004, observed_hole_yaw_deg=0.3, actuator_noise_nm=0.05)
    first = episode_generator(episode).random(4)
    assert np.array_equal(episode_generator(replace(episode, observed_hole_tilt_deg=0.4,
                                                    observed_hole_tilt_dir_deg=20.0)).random(4), first)
    assert not np.array_equal(episode_generator(replace(episode, actuator_noise_nm=0.06)).random(4), first)


def test_a_payload_error_updates_the_constants_mujoco_derives_from_the_masses(env) -> None:
    """The contact solver's inverse weights follow the changed peg mass (mj_setConst on the changed model; without it
    10 of 300 realistic episodes blew up on the peg's free joint), and the nominal mass restores the compiled ones."""
    import mujoco

    from envs.sim.model_error import MASS_CONSTANTS

    model, peg = env.model, env.scene.ids.peg_body
    env.model_error.apply(Perturbation())
    compiled = {name: getattr(model, name).copy() for name in MASS_CONSTANTS}
    env.model_error.apply(Perturbation(payload_mass_error=0.3))
    reference = build_scene(SceneConfig()).model
    reference.body_mass[peg] *= 1.3
    reference.body_inertia[peg] *= 1.3
    mujoco.mj_setConst(reference, mujoco.MjData(reference))
    for name in ("body_invweight0", "dof_invweight0", "body_subtreemass"):
        assert np.allclose(getattr(model, name), getattr(reference, name), rtol=1e-12, atol=0.0), name
    assert not np.array_equal(model.body_invweight0, compiled["body_invweight0"])
    env.model_error.apply(Perturbation())
    for name, values in compiled.items():
        assert np.array_equal(getattr(model, name), values), name


def test_every_imperfection_a_record_writes_is_one_a_paired_comparison_may_add() -> None:
    """A record writes an imperfection's key only where it is set (Perturbation.to_dict), so pairing one side with
    an imperfection against one without must allow exactly those keys (envs.statistics.pairing.IMPERFECTION_KEYS)."""
    from dataclasses import fields

    from envs.statistics.pairing import IMPERFECTION_KEYS

    plain = Perturbation(hole_dx_m=0.001, hole_yaw_deg=0.5, hole_tilt_deg=0.2, hole_tilt_dir_deg=10.0,
                         grasp_offset_m=0.001)
    shared = {f.name for f in fields(Perturbation) if getattr(plain, f.name) != 0.0} | {"hole_dy_m"}
    every = Perturbation(**{f.name: 0.1 if f.name not in shared else getattr(plain, f.name)
                            for f in fields(Perturbation)})
    assert set(every.to_dict()) - set(plain.to_dict()) == IMPERFECTION_KEYS
