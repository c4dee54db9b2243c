"""The Gymnasium environment pih/PegInHole-v1: registration, spaces (the policy's observation; a normalised action),
Gymnasium's and stable-baselines3's checkers, determinism, ends and reward."""

from __future__ import annotations

import subprocess
import sys
import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from envs.errors import EnvError
from envs.gym_env import ENV_ID, STIFFNESS_RANGE_N_M, TRUTH_KEYS, PegInHoleGymEnv
from envs.poses import quat_angle_rad, quat_conj, quat_mul, quat_to_rotvec


@pytest.fixture(scope="module")
def env() -> PegInHoleGymEnv:
    made = gymnasium.make(ENV_ID, time_limit_s=0.5)
    yield made.unwrapped
    made.close()


def test_make_maps_options_onto_the_simulator_configs() -> None:
    made = gymnasium.make(ENV_ID, shape="triangle", clearance_mm=0.5, time_limit_s=1.5, translational_stiffness=900.0,
                          hole_error_mm=0.5)
    sim = made.unwrapped.sim
    assert sim.scene.config.shape == "triangle"
    assert sim.scene.config.clearance_m == pytest.approx(0.0005)
    assert sim.config.time_limit_s == 1.5
    assert sim.config.perturbations.hole_error_m == pytest.approx(0.0005)
    assert sim.controller.config.translational_stiffness == 900.0


def test_unknown_option_is_an_error_naming_it() -> None:
    with pytest.raises(EnvError, match="unknown option 'clearence_mm'"):
        gymnasium.make(ENV_ID, clearence_mm=0.2)


def test_make_with_the_module_prefix_registers_without_an_import() -> None:
    code = ("import gymnasium, sys; env = gymnasium.make('envs.gym_env:pih/PegInHole-v1', shape='square', "
            "clearance_mm=0.2); sys.stdout.write(type(env.unwrapped).__name__)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout == "PegInHoleGymEnv"


def test_env_checker_passes(env: PegInHoleGymEnv) -> None:
    check_env(env)


@pytest.mark.parametrize("options", [{}, {"privileged": True, "stiffness_action": True}])
def test_stable_baselines3_env_checker_passes_without_a_warning(options) -> None:
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    made = gymnasium.make(ENV_ID, time_limit_s=0.2, **options)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # SB3 warns, e.g., on an action Box that is not [-1, 1]
        sb3_check_env(made.unwrapped, warn=True)
    made.close()


def test_no_observation_key_carries_the_simulator_truth_unless_privileged() -> None:
    """With a 1 mm hole-pose error the observation holds the NOMINAL hole; the true state against the displaced hole
    and the peg's own pose are in ``info`` only, and in the observation with privileged=True."""
    made = gymnasium.make(ENV_ID, time_limit_s=0.5, hole_error_mm=1.0)
    env = made.unwrapped
    obs, info = env.reset(seed=1)
    assert not any(key.startswith("privileged") or key in TRUTH_KEYS for key in obs)
    np.testing.assert_array_equal(obs["nominal_hole_pos"], env.sim.nominal_hole.pos)
    assert np.linalg.norm(env.sim.hole.pos - env.sim.nominal_hole.pos) > 1e-5  # the hole did move
    _, _, _, _, info = env.step(np.zeros(6, dtype=np.float32))
    assert set(TRUTH_KEYS) <= set(info)
    np.testing.assert_array_equal(info["peg_tip_pos"], env.sim.observation.peg_tip.pos)
    assert info["insertion_depth_m"] == env.sim.observation.insertion.depth_m
    teacher = gymnasium.make(ENV_ID, time_limit_s=0.5, privileged=True, hole_error_mm=1.0).unwrapped
    privileged = {"privileged_hole_pos", "privileged_hole_quat", "privileged_hole_axis", "privileged_goal_pos",
                  "privileged_goal_quat"}
    assert privileged <= set(teacher.observation_space.spaces)
    seen = teacher.reset(seed=1)[0]
    assert privileged <= set(seen)
    np.testing.assert_array_equal(seen["privileged_hole_pos"], teacher.sim.hole.pos)  # the true, displaced hole


def test_the_action_is_normalised_onto_the_physical_range(env: PegInHoleGymEnv) -> None:
    assert env.action_space.shape == (6,)
    np.testing.assert_array_equal(env.action_space.low, -1.0)
    np.testing.assert_array_equal(env.action_space.high, 1.0)
    np.testing.assert_allclose(env.to_physical(-np.ones(6)), env.physical_low)
    np.testing.assert_allclose(env.to_physical(np.ones(6)), env.physical_high)
    np.testing.assert_allclose(env.to_physical(np.zeros(6))[3:], 0.0)  # a = 0: the nominal goal's orientation
    u = 0.3 * env.physical_low + 0.7 * env.physical_high
    np.testing.assert_allclose(env.to_physical(env.to_action(u)), u, atol=1e-6)
    with pytest.raises(EnvError, match="NaN"):
        env.policy_action(np.full(6, np.nan))


def test_observation_sizes_come_from_the_simulator(env: PegInHoleGymEnv) -> None:
    obs, info = env.reset(seed=0)
    assert env.observation_space["qpos"].shape == env.sim.observation.qpos.shape
    assert env.observation_space["qvel"].shape == env.sim.observation.qvel.shape
    np.testing.assert_array_equal(info["peg_tip_pos"], env.sim.observation.peg_tip.pos)
    np.testing.assert_array_equal(obs["tcp_pos"], env.sim.observation.tcp.pos)
    np.testing.assert_array_equal(obs["wrist_wrench"], env.sim.observation.sensed_wrench)


def test_reset_with_a_seed_is_deterministic_and_seeds_differ(env: PegInHoleGymEnv) -> None:
    actions = np.random.default_rng(0).uniform(env.action_space.low, env.action_space.high, (5, 6))

    def rollout(seed: int) -> list[np.ndarray]:
        obs, _ = env.reset(seed=seed)
        seen = [obs["tcp_pos"], obs["qpos"]]
        for action in actions:
            obs, reward, *_ = env.step(action.astype(np.float32))
            seen += [obs["qpos"], obs["wrist_wrench"], obs["tcp_pos"], np.array([reward])]
        return seen

    first, again, other = rollout(7), rollout(7), rollout(8)
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a, b)
    assert not np.allclose(first[0], other[0])


def test_random_actions_run_until_the_time_limit_truncates(env: PegInHoleGymEnv) -> None:
    env.action_space.seed(3)
    obs, _ = env.reset(seed=3)
    for steps in range(1, 1000):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs) and np.isfinite(reward)
        if terminated or truncated:
            break
    assert truncated == (info["reason"] == "time_limit") and terminated != truncated
    if truncated:
        assert steps == round(0.5 / env.sim.control_period_s)


def test_action_is_the_peg_tip_pose_relative_to_the_goal_orientation(env: PegInHoleGymEnv) -> None:
    rotvec = np.array([0.0, 0.0, 0.2])
    goal = env.sim.nominal_goal
    action = env.policy_action(env.to_action(np.concatenate([goal.pos, rotvec])))
    np.testing.assert_allclose(action.pose.pos, goal.pos, atol=1e-7)  # float32 actions: ~1e-8 m
    assert quat_angle_rad(action.pose.quat, goal.quat) == pytest.approx(0.2, abs=1e-7)
    assert action.stiffness is None and action.rotational_stiffness is None
    clipped = env.policy_action(env.to_action(np.concatenate([goal.pos + 10.0, np.zeros(3)])))
    np.testing.assert_allclose(clipped.pose.pos, env.physical_high[:3])


def test_stiffness_action_sets_the_translational_diagonal_and_the_rotational_stiffness() -> None:
    made = gymnasium.make(ENV_ID, stiffness_action=True)
    env = made.unwrapped
    assert env.action_space.shape == (10,)
    np.testing.assert_allclose(env.physical_low[6:9], STIFFNESS_RANGE_N_M[0])
    physical = np.concatenate([env.sim.nominal_goal.pos, np.zeros(3), [300.0, 600.0, 900.0, 20.0]])
    action = env.policy_action(env.to_action(physical))
    np.testing.assert_allclose(action.stiffness, np.diag([300.0, 600.0, 900.0]), rtol=1e-6)
    assert action.rotational_stiffness == pytest.approx(20.0, rel=1e-6)


def test_reward_is_minus_the_distance_of_the_peg_to_the_true_goal(env: PegInHoleGymEnv) -> None:
    goal = env.sim.nominal_goal
    start = (goal.pos + np.array([0.0, 0.0, 0.1]), goal.quat)
    obs, _ = env.reset(options={"start_pose": start})
    _, reward, *_ = env.step(env.to_action(np.concatenate([start[0], np.zeros(3)])))
    peg, true_goal = env.sim.observation.peg_tip, env.sim.goal
    distance = np.linalg.norm(peg.pos - true_goal.pos)
    angle = quat_angle_rad(peg.quat, true_goal.quat)
    assert reward == pytest.approx(-(distance + 0.1 * angle), rel=1e-9)
    assert 0.08 < -reward < 0.12


def test_an_insertion_terminates_with_success_and_the_bonus() -> None:
    """Slowly lowering the peg from 1 cm above the opening into the hole: the simulator declares success."""
    made = gymnasium.make(ENV_ID, time_limit_s=5.0)
    env = made.unwrapped
    env.reset(seed=0)
    hole, goal = env.sim.hole, env.sim.goal  # the true ones: this scripted test knows them
    above = hole.pos + 0.01 * env.sim.hole_axis
    env.reset(seed=0, options={"start_pose": (above, goal.quat)})
    rotvec = quat_to_rotvec(quat_mul(goal.quat, quat_conj(env.sim.nominal_goal.quat)))
    for k in range(500):
        s = min(1.0, k / 300)
        action = env.to_action(np.concatenate([above + s * (goal.pos - above), rotvec]))
        obs, reward, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
    assert terminated and not truncated and info["reason"] == "success" and info["is_success"]
    assert reward > 90.0 and info["inserted"] is True
    record = info["episode_record"]  # the record `pih evaluate` writes
    assert record["success"] and record["reason"] == "success" and record["steps"] == k + 1


def test_render_returns_an_rgb_frame() -> None:
    made = gymnasium.make(ENV_ID, render_mode="rgb_array", width=160, height=120)
    made.reset(seed=0)
    try:
        frame = made.render()
    except EnvError as err:
        pytest.skip(f"no OpenGL context here: {err}")
    finally:
        made.close()
    assert frame.shape == (120, 160, 3) and frame.dtype == np.uint8 and frame.std() > 0.0


@pytest.mark.parametrize("action, words", [
    ("abc", r"action must be an array of 6 real numbers, got 'abc'"),  # numpy's ValueError before
    ([None] * 6, "action must be an array of 6 real numbers, got \\[None"),  # read as NaN before
    (None, "action must be an array of 6 real numbers, got None"),  # "must have shape (6,), got (1,)" before
    (np.zeros(6, dtype=complex), "action must be an array of 6 real numbers"),  # the imaginary part dropped
    (np.zeros((2, 3)), r"action has shape \(2, 3\), expected \(6,\)"),  # taken as (6,) before
    (np.zeros((2, 6)), r"action has shape \(2, 6\), expected \(6,\)"),  # "got (12,)" before
])
def test_a_bad_action_is_refused_in_one_line_naming_it(env: PegInHoleGymEnv, action, words) -> None:
    env.reset(seed=0)
    with pytest.raises(EnvError, match=f"^{ENV_ID}: {words}") as caught:
        env.step(action)
    assert "\n" not in str(caught.value)
    assert env.step(np.zeros((1, 6)))[0]["time_s"] > 0.0  # the episode goes on; a (1, 6) action is the (6,) one


def test_to_action_refuses_a_physical_command_with_nan(env: PegInHoleGymEnv) -> None:
    with pytest.raises(EnvError, match="physical command .* contains NaN"):  # returned a NaN action before
        env.to_action(np.full(6, np.nan))


def test_stepping_before_the_first_reset_or_after_the_end_says_so() -> None:
    env = PegInHoleGymEnv(time_limit_s=0.03)  # the simulator is reset for the spaces; the environment is not
    with pytest.raises(EnvError, match=rf"^{ENV_ID}: step\(\) before reset\(\): call reset\(\) first$"):
        env.step(np.zeros(6))  # stepped from the nominal start before
    env.reset(seed=0)
    truncated = False
    while not truncated:
        truncated = env.step(np.zeros(6))[3]
    with pytest.raises(EnvError, match=rf"^{ENV_ID}: no episode to step: it ended \(time_limit\); call reset\(\) "
                                       r"first$"):
        env.step(np.zeros(6))
    env.close()
