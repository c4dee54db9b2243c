"""envs.policies.flow_skill: policies that turn a pose skill into commanded peg_tip poses, and the velocity
feed-forward."""

from __future__ import annotations

import numpy as np
import pytest

from envs.errors import EnvError
from envs.policies.flow_skill import (
    ClosedLoopPolicy,
    OpenLoopPolicy,
    generate_plan,
    make_policy,
    on_goal_hemisphere,
    skill_lookahead,
    skill_state_step,
    skill_step,
)
from envs.policies.interface import Action
from envs.poses import Pose
from envs.sim.env import PegInHoleEnv
from tests.helpers.skill_fixtures import GOAL_POS, GOAL_QUAT, tiny_skill


@pytest.fixture(scope="module")
def skill():
    return tiny_skill()


@pytest.fixture(scope="module")
def env():
    return PegInHoleEnv()


START = Pose(pos=GOAL_POS + np.array([-0.04, 0.02, 0.15]), quat=GOAL_QUAT)


def test_on_goal_hemisphere_flips_the_far_sign():
    assert np.allclose(on_goal_hemisphere(-GOAL_QUAT, GOAL_QUAT), GOAL_QUAT)


def test_skill_step_holds_the_goal(skill):
    pos, quat = skill_step(skill, GOAL_POS, GOAL_QUAT, 0.1)
    assert np.allclose(pos, GOAL_POS, atol=1e-9) and abs(abs(quat @ GOAL_QUAT) - 1.0) < 1e-9


def test_skill_step_accepts_the_negated_quaternion(skill):
    _, q1 = skill_step(skill, START.pos, START.quat, 0.1)
    _, q2 = skill_step(skill, START.pos, -START.quat, 0.1)
    assert np.allclose(q1, q2)


def test_skill_step_rejects_nan(skill):
    with pytest.raises(EnvError):
        skill_step(skill, np.array([np.nan, 0.0, 0.0]), GOAL_QUAT, 0.1)


def test_plan_starts_at_the_start(skill):
    plan = generate_plan(skill, START, 2.0, 0.01)
    assert np.allclose(plan.pos[0], START.pos) and plan.pos.shape == (201, 3)


def test_plan_converges_to_the_goal(skill):
    plan = generate_plan(skill, START, 60.0, 0.01)
    assert np.linalg.norm(plan.pos[-1] - GOAL_POS) < 1e-3


def test_closed_loop_twist_vanishes_at_the_goal(skill):
    command = ClosedLoopPolicy(skill, 0.05).command(0, Pose(GOAL_POS, GOAL_QUAT))
    assert np.allclose(command.twist, 0.0, atol=1e-9)


def test_closed_loop_anchor_is_the_measured_pose(skill):
    command = ClosedLoopPolicy(skill, 0.05).command(0, START)
    assert np.allclose(command.anchor.pos, START.pos)


def test_open_loop_command_before_reset_is_an_error(skill):
    with pytest.raises(EnvError):
        OpenLoopPolicy(skill, 1.0).command(0, START)


def test_open_loop_holds_the_last_sample_after_the_plan(skill):
    policy = OpenLoopPolicy(skill, 0.5)
    policy.reset_at(START, 0.01)
    command = policy.command(1000, START)
    assert np.allclose(command.pose.pos, policy.plan.pos[-1]) and not np.any(command.twist)


def test_unknown_mode_is_an_error(skill):
    with pytest.raises(EnvError, match="unknown mode"):
        make_policy(skill, "teleport")


def test_feedforward_gain_zero_sends_the_pose(env):
    env.reset(seed=0)
    command = Action(START, twist=np.ones(6), anchor=Pose(GOAL_POS, GOAL_QUAT))
    assert env.controller.command(env.data, command, 0.0)[0] is START


def test_damping_lead_points_along_the_twist(env):
    env.reset(seed=0)
    v = np.array([0.0, 0.0, -0.05, 0.0, 0.0, 0.0])
    assert env.controller.pose_lead(env.data, v) @ v > 0.0


def test_feedforward_moves_the_arm_straight(env):
    """Commanding measured + K^-1 D v moves along v: < 1 mm sideways over ~4 cm down (without: ~1.7 mm)."""
    obs = env.reset(seed=3)
    start = obs.peg_tip
    v = np.array([0.0, 0.0, -0.05, 0.0, 0.0, 0.0])
    for _ in range(100):
        here = env.observation.peg_tip
        env.step(Action(here, twist=v, anchor=Pose(here.pos, start.quat)))
    moved = env.observation.peg_tip.pos - start.pos
    assert moved[2] < -0.03 and np.linalg.norm(moved[:2]) < 1e-3


@pytest.mark.parametrize("layout", ["separate", "joint"])
def test_the_lookahead_is_two_single_queries_to_the_last_bit(layout) -> None:
    """`skill_lookahead` (the closed loop's two flow poses, compiled for both pose models) equals one
    `skill_state_step` and a `skill_step` from its pose, row by row, for the two-model and the joint layouts."""
    skill = tiny_skill(layout)
    rng = np.random.default_rng(3)
    pos = GOAL_POS + rng.normal(0.0, 0.03, (4, 3))
    quat = GOAL_QUAT + rng.normal(0.0, 0.1, (4, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    quat[2] *= -1.0  # the other hemisphere: put on the goal's first
    p, q, _ = skill_lookahead(skill, pos, list(quat), None, 0.05)
    assert p.shape == (2, 4, 3) and q.shape == (2, 4, 4)
    for i in range(4):
        p1, q1, k1 = skill_state_step(skill, pos[i], quat[i], None, 0.05)
        p2, q2 = skill_step(skill, p1, q1, 0.05, k1)
        for got, want in ((p[0, i], p1), (q[0, i], q1), (p[1, i], p2), (q[1, i], q2)):
            assert np.array_equal(got, want)
