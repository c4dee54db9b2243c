"""The episode environment: reset, stepping, validation, instability and end reasons."""

from __future__ import annotations

import numpy as np
import pytest

from controllers.action import Action
from envs.cell.scene import build_scene
from envs.cell.scene_config import SceneConfig
from envs.errors import EnvError
from envs.poses import Pose, quat_from_rotvec, quat_mul
from envs.sim.env import PegInHoleEnv
from envs.sim.episode_config import EpisodeConfig
from envs.sim.observation import REASON_INSTABILITY, REASON_TIME_LIMIT


@pytest.fixture(scope="module")
def scene():
    return build_scene(SceneConfig())


@pytest.fixture()
def env(scene) -> PegInHoleEnv:
    return PegInHoleEnv(episode_config=EpisodeConfig(time_limit_s=5.0), scene=scene)


def above_hole(env: PegInHoleEnv, height_m: float = 0.05) -> Pose:
    """A start on the hole axis, ``height_m`` above the opening, tilted 5 deg."""
    quat = quat_mul(quat_from_rotvec([np.deg2rad(5.0), 0.0, 0.0]), env.goal.quat)
    return Pose(env.hole.pos + height_m * env.hole_axis, quat)


def test_reset_puts_the_tcp_and_the_grasped_peg_tip_at_start(env: PegInHoleEnv) -> None:
    start = above_hole(env)
    obs = env.reset(start_pose=start)
    assert np.linalg.norm(obs.tcp.pos - start.pos) < 1e-3
    assert np.linalg.norm(obs.peg_tip.pos - start.pos) < 1e-3
    assert np.all(np.abs(obs.qvel) < 1e-3)  # at rest after the grasp settled


def test_reset_with_seed_is_reproducible(env: PegInHoleEnv) -> None:
    first = env.reset(seed=3).peg_tip.pos
    np.testing.assert_array_equal(env.reset(seed=3).peg_tip.pos, first)


def test_unreachable_start_raises_naming_the_pose(env: PegInHoleEnv) -> None:
    with pytest.raises(EnvError, match=r"start pose pos \[2\.0000, 0\.0000, 0\.5000\] m.*unreachable"):
        env.reset(start_pose=([2.0, 0.0, 0.5], env.goal.quat))


def test_step_moves_toward_target(env: PegInHoleEnv) -> None:
    start = above_hole(env)
    env.reset(start_pose=start)
    target = Pose(start.pos + [0.0, 0.0, 0.02], env.goal.quat)
    for _ in range(30):
        result = env.step(target)
    assert np.linalg.norm(result.obs.tcp.pos - target.pos) < 0.005


@pytest.mark.parametrize("pos, quat, match", [
    ([np.nan, 0.0, 0.3], [0.0, 1.0, 0.0, 0.0], "NaN"),
    ([0.5, 0.0, 0.3], [0.0, 1.2, 0.0, 0.0], "not unit"),
    ([0.5, 0.0], [0.0, 1.0, 0.0, 0.0], "shape"),
])
def test_bad_target_is_rejected(env: PegInHoleEnv, pos: list, quat: list, match: str) -> None:
    env.reset(start_pose=above_hole(env))
    with pytest.raises(EnvError, match=match):
        env.step((pos, quat))


def test_bad_stiffness_is_rejected(env: PegInHoleEnv) -> None:
    env.reset(start_pose=above_hole(env))
    with pytest.raises(EnvError, match="stiffness"):
        env.step(above_hole(env), stiffness=-np.eye(6))


def test_instability_is_recorded_not_raised(env: PegInHoleEnv) -> None:
    env.reset(start_pose=above_hole(env))
    env.data.qvel[2] = np.nan
    result = env.step(above_hole(env))
    assert result.done and result.reason.startswith(REASON_INSTABILITY)


def test_huge_joint_speed_is_an_instability(env: PegInHoleEnv) -> None:
    env.reset(start_pose=above_hole(env))
    env.data.qvel[0] = 40.0  # rad/s; the torque limit cannot brake it below 10 rad/s within 10 ms
    result = env.step(above_hole(env))
    assert result.done and "joint speed" in result.reason


def test_step_after_the_end_raises(env: PegInHoleEnv) -> None:
    env.reset(start_pose=above_hole(env))
    env.data.qvel[2] = np.nan
    env.step(above_hole(env))
    with pytest.raises(EnvError, match="call reset"):
        env.step(above_hole(env))


def test_time_limit_ends_the_episode(scene) -> None:
    env = PegInHoleEnv(episode_config=EpisodeConfig(time_limit_s=0.05), scene=scene)
    env.reset(start_pose=above_hole(env))
    results = [env.step(above_hole(env)) for _ in range(5)]
    assert [r.done for r in results] == [False] * 4 + [True]
    assert results[-1].reason == REASON_TIME_LIMIT


def test_wrist_sensor_reads_the_push_on_the_sorter(env: PegInHoleEnv) -> None:
    """Pressed 1 cm into the plate at 1500 N/m, the wrist reads ~15 N pointing up (world), equal to the sum of
    the contact normal forces on the peg."""
    beside = env.hole.pos + [0.0, 0.0, 0.01] + [0.05, 0.0, 0.0]  # over solid plate, away from every hole
    env.reset(start_pose=(beside, env.goal.quat))
    pressed = Pose(beside - [0.0, 0.0, 0.02], env.goal.quat)
    for _ in range(100):
        result = env.step(pressed)
    rot = env.data.site_xmat[env.scene.ids.ft_site].reshape(3, 3)
    force = rot @ result.obs.wrist_wrench[:3]
    assert 10.0 < force[2] < 20.0 and force[2] > 5 * np.hypot(force[0], force[1])  # normal, plus friction
    assert result.obs.contact_force_n == pytest.approx(force[2], rel=0.1)
    assert env.stats.peak_contact_force_n >= result.obs.contact_force_n


def test_free_space_wrist_wrench_is_near_zero(env: PegInHoleEnv) -> None:
    obs = env.reset(start_pose=above_hole(env))
    for _ in range(20):
        obs = env.step(above_hole(env)).obs
    assert np.linalg.norm(obs.wrist_wrench[:3]) < 0.2 and obs.contact_force_n == 0.0


def test_a_pose_is_the_action_of_that_pose_and_its_stiffness(env: PegInHoleEnv) -> None:
    start = above_hole(env)
    stiffness = np.diag([800.0, 800.0, 2000.0, 60.0, 60.0, 60.0])
    targets = [Pose(start.pos + [0.0, 0.001 * k, -0.002 * k], start.quat) for k in range(5)]
    runs = []
    for as_action in (False, True):
        env.reset(start_pose=start)
        for target in targets:
            env.step(Action(target, stiffness) if as_action else target, None if as_action else stiffness)
        runs.append(env.data.qpos.copy())
    assert np.array_equal(runs[0], runs[1])


def test_the_controller_leads_an_action_with_a_twist(env: PegInHoleEnv) -> None:
    start = above_hole(env)
    env.reset(start_pose=start)
    action = Action(start, twist=np.array([0.0, 0.0, -0.05, 0.0, 0.0, 0.0]))
    led, _ = env.controller.command(env.data, action, 1.0)
    result = env.step(action)
    assert np.array_equal(result.info["target"].pos, led.pos) and led.pos[2] < start.pos[2] - 1e-4
    assert np.array_equal(env.step(action, feedforward_gain=0.0).info["target"].pos, start.pos)
    with pytest.raises(EnvError, match="carries its own stiffness"):
        env.step(action, np.eye(6) * 1000.0)
    with pytest.raises(EnvError, match="cannot command this action: twist"):
        env.step(Action(start, twist=np.zeros(5)))
