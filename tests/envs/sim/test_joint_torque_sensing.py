"""The joint-torque wrench sensing (envs.task.sensor_config, sensor_mode "joint_torque"): without sensor errors it reads
the wrench the wrist sensor reads, pressed into the sorter and with joint friction (which sits before the link-side
sensors and must not show); its noise maps through (J J^T)^-1 J as modelled; a payload error shows; the record
keeps the true wrench."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from envs.cell.scene import build_scene
from envs.cell.scene_config import SceneConfig
from envs.errors import EnvError
from envs.policies.interface import observe
from envs.poses import Pose
from envs.sim.env import PegInHoleEnv
from envs.sim.episode_config import EpisodeConfig
from envs.task.perturbation import Perturbation
from envs.task.sensor_config import WristSensorConfig

GRAVITY_M_S2 = 9.81


@pytest.fixture(scope="module")
def scene():
    return build_scene(SceneConfig(clearance_m=0.0002, chamfer_m=0.001, hole_depth_m=0.03))


def _env(scene, sensor: WristSensorConfig) -> PegInHoleEnv:
    return PegInHoleEnv(scene=scene, episode_config=EpisodeConfig(time_limit_s=5.0, wrist_sensor=sensor,
                                                                  force_limit_n=float("inf")))


def _above(env: PegInHoleEnv) -> Pose:
    return Pose(env.nominal_goal.pos + 0.06 * env.hole_axis, env.nominal_goal.quat)


@pytest.mark.parametrize("friction_scale", [0.0, 1.0])
def test_a_noiseless_estimate_reads_the_wrist_wrench_pressed_into_the_sorter(scene, friction_scale) -> None:
    env = _env(scene, WristSensorConfig(sensor_mode="joint_torque"))
    start = _above(env)
    env.reset(start_pose=start, perturbation=Perturbation(joint_friction_scale=friction_scale))
    beside = Pose(start.pos + np.array([0.03, 0.0, 0.0]), start.quat)  # over the sorter's top, beside the hole
    for _ in range(50):
        env.step(beside)
    press = Pose(beside.pos - 0.08 * env.hole_axis, start.quat)
    for _ in range(150):
        env.step(press)
    true, sensed = env.observation.wrist_wrench, observe(env).wrist_wrench
    assert np.linalg.norm(true[:3]) > 50.0  # pressed hard (and sliding sideways on the top)
    assert np.abs(sensed - true).max() < 0.02 + 1e-3 * np.abs(true).max()
    assert env.stats.peak_wrist_force_n > 50.0  # the record keeps the true wrench


def test_a_payload_error_shows_in_the_estimate(scene) -> None:
    env = _env(scene, WristSensorConfig(sensor_mode="joint_torque"))
    start = _above(env)
    env.reset(start_pose=start, perturbation=Perturbation(payload_mass_error=0.3))
    for _ in range(60):
        env.step(start)
    sensed = observe(env).wrist_wrench
    world = env.data.site_xmat[env.scene.ids.ft_site].reshape(3, 3) @ sensed[:3]
    assert world[2] == pytest.approx(-0.3 * env.model_error.mass_kg * GRAVITY_M_S2, rel=0.05)


def test_the_estimate_noise_is_the_joint_noise_through_the_jacobian(scene) -> None:
    """sigma_tau = 0.1 N m per joint and reading, no filter: the force error's covariance is sigma^2 P P^T with
    P = (J J^T)^-1 J, in the sensor frame; 300 independent readings (one per control period) match it per axis."""
    sigma = 0.1
    env = _env(scene, WristSensorConfig(sensor_mode="joint_torque", joint_torque_noise_nm=sigma))
    quiet = _env(scene, WristSensorConfig(sensor_mode="joint_torque"))
    start = _above(env)
    errors = []
    for each in (env, quiet):
        each.reset(start_pose=start)
    for _ in range(300):
        env.step(start)
        quiet.step(start)
        errors.append(observe(env).wrist_wrench - observe(quiet).wrist_wrench)  # the same states: noise alone
    model, data = env.model, env.data
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    mujoco.mj_jacSite(model, data, jacp, jacr, env.scene.ids.ft_site)
    jac = np.vstack([jacp, jacr])[:, list(env.scene.ids.arm_dof_adr)]
    p = np.linalg.solve(jac @ jac.T, jac)
    rot = data.site_xmat[env.scene.ids.ft_site].reshape(3, 3)
    block = np.kron(np.eye(2), rot.T)
    predicted = np.sqrt(np.diag(block @ (sigma ** 2 * p @ p.T) @ block.T))
    measured = np.asarray(errors).std(axis=0)
    assert measured == pytest.approx(predicted, rel=0.15)


def test_a_bias_is_one_draw_per_episode(scene) -> None:
    env = _env(scene, WristSensorConfig(sensor_mode="joint_torque", joint_torque_bias_nm=0.3))
    start = _above(env)
    env.reset(start_pose=start)
    readings = []
    for _ in range(40):
        env.step(start)
        readings.append(observe(env).wrist_wrench - env.observation.wrist_wrench)
    readings = np.asarray(readings[10:])  # after the 100 Hz filter settled
    assert np.linalg.norm(readings[:, :3].mean(axis=0)) > 0.1  # a few tenths of N m per joint: ~N of force
    assert readings[:, :3].std(axis=0).max() < 0.1  # constant over the episode


@pytest.mark.parametrize("fields", [{"sensor_mode": "wrist", "joint_torque_noise_nm": 0.1},
                                    {"sensor_mode": "joint_torque", "force_bias_n": 0.5}])
def test_a_magnitude_of_the_other_mode_is_refused(fields) -> None:
    with pytest.raises(EnvError, match="is a magnitude of sensor_mode"):
        WristSensorConfig(**fields)
