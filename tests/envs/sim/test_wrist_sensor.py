"""envs.task.sensor_config in the episode: the policy sees the sensed wrench, the record keeps the true one, the force
limit reads the sensor, and the readings are a function of the episode alone."""

from __future__ import annotations

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

NOISY = WristSensorConfig(sensor_mode="wrist", force_noise_n=0.3, torque_noise_nm=0.02, force_bias_n=1.0,
                          torque_bias_nm=0.05)


@pytest.fixture(scope="module")
def scene():
    return build_scene(SceneConfig())


def _held(scene, sensor: WristSensorConfig, perturbation: Perturbation = Perturbation(), periods: int = 100):
    """An env holding the peg in free space above the hole; the (true, sensed) wrench of each period."""
    env = PegInHoleEnv(scene=scene, episode_config=EpisodeConfig(time_limit_s=5.0, wrist_sensor=sensor))
    start = Pose(env.nominal_goal.pos + 0.06 * env.hole_axis, env.nominal_goal.quat)
    env.reset(start_pose=start, perturbation=perturbation)
    rows = []
    for _ in range(periods):
        if env.done:
            break
        env.step(start)
        rows.append((env.observation.wrist_wrench.copy(), observe(env).wrist_wrench.copy()))
    return env, np.array(rows)


def test_the_policy_sees_the_sensor_and_the_record_the_truth(scene) -> None:
    env, rows = _held(scene, NOISY)
    true, sensed = rows[:, 0], rows[:, 1]
    assert np.abs(true[:, :3]).max() < 0.05  # at rest in free space the true wrench is ~0
    errors = sensed - true
    spread = errors[:, :3].std(axis=0)  # sigma 0.3 N per reading, white at 1 kHz, sampled at 100 Hz
    assert np.all((0.2 < spread) & (spread < 0.4)), spread
    assert np.abs(errors[:, :3].mean(axis=0)).max() > 0.1  # the episode's bias (beta 1 N)
    assert env.stats.peak_wrist_force_n < 0.05  # the record's peaks are the true wrench's


def test_the_same_episode_reads_the_same_noise_and_another_other_noise(scene) -> None:
    _, a = _held(scene, NOISY, Perturbation(hole_dx_m=0.0005), periods=20)
    _, b = _held(scene, NOISY, Perturbation(hole_dx_m=0.0005), periods=20)
    _, c = _held(scene, NOISY, Perturbation(hole_dx_m=0.0006), periods=20)
    assert np.array_equal(a, b) and not np.array_equal(a[:, 1], c[:, 1])


def test_a_noiseless_wrist_sensor_reads_the_ideal_sensor_bit_for_bit(scene) -> None:
    _, ideal = _held(scene, WristSensorConfig(), periods=30)
    _, wrist = _held(scene, WristSensorConfig(sensor_mode="wrist"), periods=30)
    assert np.array_equal(ideal, wrist)


def test_a_large_sensor_bias_trips_the_force_limit_in_free_space(scene) -> None:
    env, _ = _held(scene, WristSensorConfig(sensor_mode="wrist", force_bias_n=300.0), periods=10)
    assert env.reason == "force_limit" and env.stats.peak_wrist_force_n < 1.0


def test_bad_sensor_settings_are_refused() -> None:
    with pytest.raises(EnvError, match="sensor_mode"):
        WristSensorConfig(sensor_mode="perfect")
    with pytest.raises(EnvError, match="force_noise_n"):
        WristSensorConfig(force_noise_n=-1.0)
    with pytest.raises(EnvError, match="sensor_cutoff_hz"):
        WristSensorConfig(sensor_cutoff_hz=-100.0)
