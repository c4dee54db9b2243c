"""envs.policies.insertion: the phases follow the measured tcp and the tared wrench (the inner skill's action until the
touch, a force-holding spiral with a wiggle, centring on the chamfer, a speed-limited insertion that follows the
measured rotation), and in physics the search finds a hole the peg lands beside, beyond the chamfer's reach."""

from __future__ import annotations

import math

import numpy as np
import pytest

from envs.cell.scene import build_scene
from envs.cell.scene_config import SceneConfig
from envs.errors import EnvError
from envs.policies.insertion import APPROACH, INSERT, SEARCH, InsertionConfig, InsertionPolicy
from envs.policies.interface import Action, Observation
from envs.poses import Pose
from envs.rollout.episode import StartPose, run_episode
from envs.sim.env import PegInHoleEnv
from envs.sim.episode_config import EpisodeConfig
from envs.task.perturbation import Perturbation
from numerics.quaternion import quat_conj, quat_mul, quat_to_rotvec

GOAL = Pose(np.array([0.6, 0.0, 0.2]), np.array([0.0, 1.0, 0.0, 0.0]))  # the peg axis (z) points down: a = -z


class _Inner:
    """A stand-in skill: commands the goal (one Action object); counts its calls."""

    def __init__(self) -> None:
        self.calls = 0
        self.action = Action(GOAL)

    def reset(self, observation: Observation, period_s: float) -> None:
        self.calls = 0

    def act(self, observation: Observation) -> Action:
        self.calls += 1
        return self.action


def _observation(pos, force_down_n: float = 0.0, quat=GOAL.quat) -> Observation:
    """The tcp at ``pos`` (orientation ``quat``), the wrist reading a force pushing the tool up (against a = -z) of
    ``force_down_n`` newtons, in the sensor (tcp) frame."""
    rot = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])  # R(GOAL.quat)
    wrench = np.concatenate([rot.T @ np.array([0.0, 0.0, force_down_n]), np.zeros(3)])
    return Observation(0.0, np.zeros(7), np.zeros(7), 0.02, Pose(np.asarray(pos, dtype=float), np.asarray(quat)),
                       wrench, GOAL, GOAL)


def _policy(**settings) -> tuple[InsertionPolicy, _Inner]:
    inner = _Inner()
    policy = InsertionPolicy(inner, GOAL, InsertionConfig(**settings))
    policy.reset(_observation(GOAL.pos + [0.0, 0.0, 0.1]), 0.01)
    return policy, inner


@pytest.mark.parametrize("field", ["force_n", "spiral_pitch_m", "follow_s"])
@pytest.mark.parametrize("value", [0.0, -1.0, math.nan, math.inf, True])
def test_a_setting_must_be_a_finite_positive_number(field, value) -> None:
    with pytest.raises(EnvError, match=f"InsertionConfig.{field}="):
        InsertionConfig(**{field: value})


def test_the_inner_action_passes_until_the_peg_touches_near_the_hole() -> None:
    policy, inner = _policy()
    far = GOAL.pos + [0.0, 0.0, 0.05]  # 50 mm above the goal: beyond the radius, even pressed
    assert policy.act(_observation(far, 10.0)) is inner.action
    near = GOAL.pos + [0.0, 0.0, 0.03]
    assert policy.act(_observation(near, 2.0)) is inner.action  # near, but below the touch force
    assert policy.phase == APPROACH
    action = policy.act(_observation(near, 4.0))
    assert policy.phase == SEARCH and action is not inner.action and inner.calls == 3


def test_the_search_holds_the_force_along_the_axis_and_spirals_out_across_it() -> None:
    config = InsertionConfig()
    policy, _ = _policy()
    touch = GOAL.pos + [0.001, -0.002, 0.03]
    policy.act(_observation(touch, 5.0))
    radii, pushes, turns = [], [], []
    for k in range(2000):  # 20 s on the flat top
        action = policy.act(_observation(touch, 5.0))
        offset = action.pose.pos - touch
        pushes.append(-offset[2])  # along a = -z
        radii.append(float(np.hypot(offset[0], offset[1])))
        turns.append(float(np.linalg.norm(quat_to_rotvec(quat_mul(action.pose.quat, quat_conj(GOAL.quat))))))
        assert action.rotational_stiffness == config.search_rotational_stiffness_nm_rad
    assert np.allclose(pushes, config.force_n / config.axial_stiffness_n_m)
    path_m = config.spiral_speed_m_s * 6.0  # after 6 s along an Archimedean spiral: r = sqrt(path pitch / pi)
    assert radii[599] == pytest.approx(math.sqrt(path_m * config.spiral_pitch_m / math.pi), rel=0.05)
    assert max(radii) == pytest.approx(config.spiral_radius_m) and radii[10] < 0.5 * config.spiral_pitch_m
    assert np.all(np.diff(np.array(radii)) >= -1e-12)  # outward, then on the largest circle
    assert max(turns) == pytest.approx(math.radians(config.wiggle_deg), rel=0.01)


def test_on_the_chamfer_the_search_stops_pushing_sideways_and_in_the_bore_the_insertion_starts() -> None:
    config = InsertionConfig()
    policy, _ = _policy()
    touch = GOAL.pos + [0.0, 0.0, 0.03]
    policy.act(_observation(touch, 5.0))
    for _ in range(50):
        policy.act(_observation(touch, 5.0))
    on_chamfer = touch + [0.0004, 0.0, -0.0005]  # 0.5 mm down: past the capture depth
    action = policy.act(_observation(on_chamfer, 5.0))
    assert np.allclose(action.pose.pos[:2], on_chamfer[:2]) and policy.phase == SEARCH  # no lateral force
    in_bore = touch + [0.0004, 0.0, -0.0025]
    action = policy.act(_observation(in_bore, 5.0))
    assert policy.phase == INSERT
    assert action.rotational_stiffness == config.insert_rotational_stiffness_nm_rad
    assert np.allclose(action.pose.pos[:2], in_bore[:2])


def test_the_insertion_advances_at_its_speed_and_never_more_than_the_force_ahead() -> None:
    config = InsertionConfig()
    policy, _ = _policy()
    touch = GOAL.pos + [0.0, 0.0, 0.03]
    policy.act(_observation(touch, 5.0))
    tip = touch + [0.0, 0.0, -0.0025]
    policy.act(_observation(tip, 5.0))
    assert policy.phase == INSERT
    leads = []
    for k in range(100):  # the peg held where it is (a stuck peg): the reference stops F / K_a ahead
        leads.append(-(policy.act(_observation(tip, 5.0)).pose.pos[2] - tip[2]))
    assert leads[0] == pytest.approx(2 * config.insert_speed_m_s * 0.01)
    assert max(leads) == pytest.approx(config.force_n / config.axial_stiffness_n_m)
    assert np.all(np.diff(leads) >= -1e-15)


def test_while_inserting_the_command_turns_toward_the_measured_rotation() -> None:
    config = InsertionConfig()
    policy, _ = _policy()
    touch = GOAL.pos + [0.0, 0.0, 0.03]
    policy.act(_observation(touch, 5.0))
    turned = quat_mul(np.array([math.cos(0.005), math.sin(0.005), 0.0, 0.0]), GOAL.quat)  # 0.57 deg about x
    tip = touch + [0.0, 0.0, -0.0025]
    angles = []
    for k in range(100):
        action = policy.act(_observation(tip - [0.0, 0.0, 1e-3 * k], 5.0, quat=turned))  # progressing
        angles.append(float(np.linalg.norm(quat_to_rotvec(quat_mul(action.pose.quat, quat_conj(turned))))))
    assert angles[0] > 0.009 and angles[-1] < 0.01 * math.exp(-0.5)  # tau = 1 s: e^-1 after 1 s


def test_in_physics_the_search_finds_a_hole_the_peg_lands_beside() -> None:
    """A peg 2 mm beside the hole (beyond the 1 mm chamfer) lowered straight onto the part stalls on its top; with
    the insertion it is seated."""
    env = PegInHoleEnv(scene=build_scene(SceneConfig(hole_depth_m=0.03)), episode_config=EpisodeConfig(time_limit_s=20.0))
    goal = env.nominal_goal
    beside = Pose(goal.pos + np.array([0.002, 0.0, 0.0]), goal.quat)

    class Lower:
        def reset(self, observation, period_s):
            self.k = 0

        def act(self, observation):
            self.k += 1
            return Action(Pose(beside.pos + max(0.0, 0.04 - 0.0002 * self.k) * env.hole_axis - 0.003 * env.hole_axis,
                               goal.quat))

    start = StartPose(0, 0, Pose(beside.pos + 0.04 * env.hole_axis, goal.quat), Perturbation())
    plain, _ = run_episode(env, Lower(), start)
    searched, _ = run_episode(env, InsertionPolicy(Lower(), goal), start)
    assert not plain.success and plain.insertion_depth_mm < 1.0
    assert searched.success, searched.reason
