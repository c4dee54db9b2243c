"""The scripted expert: path planning (pure) and recorded demonstrations (physics)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import envs.demos.record as demos_module
from controllers.impedance import full_stiffness
from envs.demos.file import load_demos, save_demos
from envs.demos.record import (
    DemoAttempt,
    collect_demos,
    demo_episode_config,
    execute_demo,
    finalize_demo,
    scene_config_from_demos,
)
from envs.errors import EnvError
from envs.policies.expert_plan import ExpertConfig, plan_expert_path
from envs.policies.stiffness_schedule import StiffnessSchedule, expert_stiffness
from envs.poses import Pose, StartRegion, quat_angle_rad, quat_from_rotvec, quat_mul, rotate
from envs.sim.env import PegInHoleEnv

OPENING = np.array([0.6, 0.0, 0.2])
AXIS = np.array([0.0, 0.0, 1.0])
GOAL = Pose(OPENING - 0.03 * AXIS, np.array([0.0, 1.0, 0.0, 0.0]))
START = Pose(OPENING + [-0.12, 0.05, 0.17], quat_mul(quat_from_rotvec([0.2, -0.1, 0.1]), GOAL.quat))
CONFIG = ExpertConfig()
TIMES = np.linspace(0.0, CONFIG.duration_s, 6501)


@pytest.fixture(scope="module")
def path() -> tuple[np.ndarray, np.ndarray]:
    return plan_expert_path(START, OPENING, AXIS, GOAL, CONFIG, TIMES)


def test_path_starts_at_start_and_ends_at_goal(path) -> None:
    pos, quat = path
    np.testing.assert_allclose(pos[0], START.pos, atol=1e-12)
    np.testing.assert_allclose(pos[-1], GOAL.pos, atol=1e-12)
    assert quat_angle_rad(quat[0], START.quat) < 1e-9 and np.allclose(quat[-1], GOAL.quat)


def test_path_height_never_rises(path) -> None:
    assert np.all(np.diff(path[0] @ AXIS) <= 1e-12)


def test_path_is_on_the_axis_and_aligned_before_the_opening(path) -> None:
    pos, quat = path
    near = (pos - OPENING) @ AXIS <= 0.02
    lateral = np.linalg.norm((pos - OPENING) - np.outer((pos - OPENING) @ AXIS, AXIS), axis=1)
    assert np.all(lateral[near] < 1e-9) and np.all(quat_angle_rad(quat[near], GOAL.quat) < 1e-9)


def test_path_velocity_is_continuous(path) -> None:
    velocity = np.diff(path[0], axis=0) / np.diff(TIMES)[:, None]
    assert np.max(np.linalg.norm(np.diff(velocity, axis=0), axis=1)) < 1e-3  # m/s per 1 ms sample


def test_path_crosses_the_opening_at_the_entry_speed(path) -> None:
    height = path[0] @ AXIS - OPENING @ AXIS
    inside = (height <= CONFIG.entry_height_m - 1e-4) & (height >= -CONFIG.entry_depth_m + 1e-4)
    speed = -np.diff(height) / np.diff(TIMES)
    np.testing.assert_allclose(speed[inside[:-1]], CONFIG.entry_speed_m_s, rtol=1e-6)


def test_start_below_the_entry_height_is_refused() -> None:
    low = Pose(OPENING + [0.0, 0.0, 0.001], GOAL.quat)
    with pytest.raises(EnvError, match="entry height"):
        plan_expert_path(low, OPENING, AXIS, GOAL, CONFIG, TIMES)


@pytest.fixture(scope="module")
def collection():
    return collect_demos(2, seed=0, expert=ExpertConfig(num_samples=300))


@pytest.mark.slow
def test_quick_collection_succeeds_and_ends_at_the_goal(collection) -> None:
    demos = collection.demos
    assert demos.pos.shape == (2, 300, 3) and demos.quat.shape == (2, 300, 4)
    np.testing.assert_allclose(demos.pos[:, -1], np.tile(demos.goal_pos, (2, 1)), atol=1e-12)
    assert demos.dt == pytest.approx(CONFIG.duration_s / 299)


@pytest.mark.slow
def test_expert_enters_the_hole_on_its_axis(collection) -> None:
    """The expert's feed-forward keeps the compliant arm on its plan: from 5 mm above the opening to 5 mm in,
    the recorded tcp stays within 0.15 mm of the hole axis (0.105 mm measured; without the feed-forward 0.3-0.4 mm
    beside it, a bias the learned skill copies and which eats the chamfer's capture range under hole-pose error)."""
    demos = collection.demos
    into = rotate(demos.goal_quat, [0.0, 0.0, 1.0])  # the peg_tip z axis at the goal points down the hole
    rel = demos.pos - demos.goal_pos
    height = -(rel @ into) - 0.03  # height above the opening (the goal is 30 mm below it)
    lateral = np.linalg.norm(rel - (rel @ into)[..., None] * into, axis=-1)
    near_opening = np.abs(height) <= 0.005
    assert near_opening.sum() >= 4
    assert lateral[near_opening].max() < 1.5e-4


@pytest.mark.slow
def test_kept_demos_settled_within_tolerance(collection) -> None:
    assert np.all(collection.demos.residual_pos_m <= 1e-3)
    assert np.all(collection.demos.residual_rot_deg <= 1.0)


@pytest.mark.slow
def test_recorded_demos_start_at_the_sampled_starts(collection) -> None:
    starts = collection.demos.config["starts"]
    for n, start in enumerate(starts):
        assert np.linalg.norm(collection.demos.pos[n, 0] - start["pos"]) < 1e-3


@pytest.mark.slow
def test_collected_file_validates(collection, tmp_path: Path) -> None:
    loaded = load_demos(save_demos(tmp_path / "demos.npz", collection.demos))
    assert loaded.num_demos == 2 and loaded.shape == "square"
    assert scene_config_from_demos(loaded).clearance_m == pytest.approx(0.001)


@pytest.mark.slow
def test_failed_attempt_is_recorded_and_resampled(monkeypatch: pytest.MonkeyPatch) -> None:
    real = demos_module.execute_demo
    calls = []

    def fail_first(env, start, config, on_step=None) -> DemoAttempt:
        attempt = real(env, start, config, on_step)
        calls.append(start)
        if len(calls) == 1:
            return DemoAttempt(start, False, "injected failure", attempt.times, attempt.pos, attempt.quat,
                               attempt.commanded_pos, np.nan, np.nan, attempt.wall_s)
        return attempt

    monkeypatch.setattr(demos_module, "execute_demo", fail_first)
    result = collect_demos(1, seed=0, expert=ExpertConfig(num_samples=50))
    assert len(result.attempts) == 2 and result.demos.num_demos == 1
    assert result.demos.config["failures"][0]["reason"] == "injected failure"
    assert np.linalg.norm(result.demos.pos[0, 0] - calls[1].pos) < 1e-3


def test_collection_gives_up_when_no_start_is_reachable() -> None:
    far = StartRegion(height_above_opening_m=1.5, toward_base_m=0.0, pos_half_width_m=(0.0, 0.0, 0.0))
    expert = ExpertConfig(num_samples=50, max_failed_attempts=3, start_region=far)
    env = PegInHoleEnv(episode_config=demo_episode_config(expert))
    with pytest.raises(EnvError, match=r"gave up on the square after 3 attempts \(seed 0\): 0 of 1 demos kept; "
                                       r"failures reset failed: 3; last: reset failed: start pose"):
        collect_demos(1, seed=0, expert=expert, env=env)


@pytest.mark.slow
def test_collected_demos_carry_spd_stiffness_from_free_space_to_the_goal_stiffness(collection, tmp_path) -> None:
    demos = collection.demos
    goal_k = StiffnessSchedule().goal_stiffness([0.0, 0.0, 1.0])  # the default hole points up
    assert demos.stiffness.shape == (2, 300, 3, 3) and np.allclose(demos.goal_stiffness, goal_k)
    assert np.linalg.eigvalsh(demos.stiffness).min() > 0.0
    assert np.array_equal(demos.stiffness[:, -1], np.broadcast_to(goal_k, (2, 3, 3)))
    np.testing.assert_allclose(demos.stiffness[:, 0], np.broadcast_to(1500.0 * np.eye(3), (2, 3, 3)))
    loaded = load_demos(save_demos(tmp_path / "demos.npz", demos))
    assert np.array_equal(loaded.stiffness, demos.stiffness)


@pytest.mark.slow
def test_expert_commands_the_schedule_at_the_measured_pose_and_records_it(monkeypatch) -> None:
    expert = ExpertConfig(num_samples=50)
    env = PegInHoleEnv(episode_config=demo_episode_config(expert))
    commanded, measured = [], []
    real_command = env.controller.command

    def spy(data, action, feedforward_gain=1.0):
        measured.append(env.observation.tcp.pos.copy())
        pose, stiffness = real_command(data, action, feedforward_gain)
        commanded.append(stiffness)
        return pose, stiffness

    monkeypatch.setattr(env.controller, "command", spy)
    attempt = execute_demo(env, env.sample_start(np.random.default_rng(0)), expert)
    assert attempt.ok, attempt.reason
    schedule = np.stack([expert_stiffness(p, env.hole.pos, env.hole_axis, expert.stiffness) for p in measured])
    k_rot = env.controller.config.rotational_stiffness
    assert all(np.allclose(c, full_stiffness(k, k_rot)) for c, k in zip(commanded, schedule))
    assert np.allclose(attempt.stiffness[:-1], schedule) and attempt.stiffness.shape[0] == attempt.times.size
    assert np.linalg.eigvalsh(schedule).min() < 0.5 * expert.stiffness.free_n_m  # it did go compliant


def test_finalize_resamples_the_recorded_stiffness_and_ends_at_the_goal_stiffness() -> None:
    times = np.linspace(0.0, CONFIG.duration_s, 11)
    pos = np.tile(GOAL.pos, (11, 1))
    quat = np.tile(GOAL.quat, (11, 1))
    stiffness = np.stack([np.diag([1500.0 * (1 - s) + 300.0 * s] * 2 + [1000.0]) for s in np.linspace(0, 1, 11)])
    attempt = DemoAttempt(START, True, "ok", times, pos, quat, pos, 0.0, 0.0, 0.0, stiffness)
    goal_k = np.diag([300.0, 300.0, 1000.0])
    _, _, k = finalize_demo(attempt, GOAL, ExpertConfig(num_samples=101), goal_k)
    assert k.shape == (101, 3, 3) and np.array_equal(k[-1], goal_k) and np.allclose(k[0], stiffness[0])
    assert np.linalg.eigvalsh(k).min() >= 300.0 - 1e-9
    no_k = DemoAttempt(START, True, "ok", times, pos, quat, pos, 0.0, 0.0, 0.0)
    assert finalize_demo(no_k, GOAL, ExpertConfig(num_samples=101))[2] is None


@pytest.mark.slow
def test_a_demo_records_joints_wrench_and_commands_at_the_control_rate(collection, tmp_path: Path) -> None:
    """The control signals (what `pih export --demos` makes observations and actions of): K = 7 s / 10 ms + 1 samples
    per demo; the joints put the tcp where the demo's first pose measured it; the commands end at the goal with the
    goal stiffness; the file keeps them."""
    import mujoco

    demos = collection.demos
    control = demos.control
    assert control is not None and control.dt == pytest.approx(0.01)
    k = round(CONFIG.duration_s / control.dt) + 1
    assert control.joint_pos.shape == control.joint_vel.shape == (2, k, 7)
    assert control.wrist_wrench.shape == (2, k, 6) and control.action_quat.shape == (2, k, 4)
    assert control.action_stiffness.shape == (2, k, 3, 3) and control.action_rot_stiffness.shape == (2, k)
    env = PegInHoleEnv()
    data = mujoco.MjData(env.model)
    for n in range(2):
        data.qpos[np.asarray(env.scene.ids.arm_qpos_adr)] = control.joint_pos[n, 0]
        mujoco.mj_kinematics(env.model, data)
        np.testing.assert_allclose(data.site_xpos[env.tcp_site], demos.pos[n, 0], atol=2e-6)
    np.testing.assert_allclose(control.action_pos[:, -1], np.tile(demos.goal_pos, (2, 1)), atol=1e-9)
    np.testing.assert_allclose(control.action_stiffness[:, -1], np.broadcast_to(demos.goal_stiffness, (2, 3, 3)))
    assert np.all(control.action_rot_stiffness == 80.0)  # the controller's default, as the expert commands it
    assert np.abs(control.wrist_wrench[:, 0]).max() < 0.01  # at rest in free space, the tool load removed
    loaded = load_demos(save_demos(tmp_path / "demos.npz", demos))
    for name, _ in type(control).ARRAYS:
        np.testing.assert_array_equal(getattr(loaded.control, name), getattr(control, name))


def test_a_demo_file_without_control_signals_still_loads_and_a_partial_one_is_refused(tmp_path: Path) -> None:
    from dataclasses import replace

    from envs.demos.file import ControlSignals
    from tests.helpers.skill_fixtures import synthetic_demos

    old = load_demos(save_demos(tmp_path / "old.npz", synthetic_demos(n=2, m=30)))
    assert old.control is None
    k = 11
    full = replace(old, control=ControlSignals(0.01, np.zeros((2, k, 7)), np.zeros((2, k, 7)), np.zeros((2, k, 6)),
                                               np.zeros((2, k, 3)), np.tile([1.0, 0, 0, 0], (2, k, 1)),
                                               np.tile(np.eye(3), (2, k, 1, 1)), np.full((2, k), 80.0)))
    assert load_demos(save_demos(tmp_path / "new.npz", full)).control.num_samples == k
    with np.load(tmp_path / "new.npz") as archive:
        arrays = {key: archive[key] for key in archive.files if key != "control_joint_vel"}
    np.savez(tmp_path / "partial.npz", **arrays)
    with pytest.raises(EnvError, match="control_joint_vel"):
        load_demos(tmp_path / "partial.npz")
