"""The controller's feed-forward lead (controllers.feedforward.led_pose, compiled in feedforward_kernel) equals, bit for
bit, its Python reference (`_reference_led_pose` below: limits, `pose_lead`, push, the rotation vector onto the
anchor), over random arm states, twists (under and over the limits, zero), accelerations, pushes, anchors, stiffnesses
and gains; and `CartesianImpedanceController.command` is that lead with the action's stiffness."""

from __future__ import annotations

import numpy as np
import pytest

from controllers.errors import ControllerError
from controllers import feedforward_kernel
from controllers.action import Action
from controllers.feedforward import (MAX_ACCEL_M_S2, MAX_ANGULAR_ACCEL_RAD_S2, MAX_ANGULAR_SPEED_RAD_S, MAX_SPEED_M_S,
                                     led_pose)
from envs.poses import Pose, quat_from_rotvec, quat_from_rotvec_one, quat_mul_one
from envs.sim.env import PegInHoleEnv
from numerics.small_linalg import norm
from tests.helpers.env_states import wandering_states


def _reference_limit(twist, max_speed, max_spin):
    xi = np.asarray(twist, dtype=np.float64)
    v, w = xi[:3], xi[3:]
    speed, spin = norm(v), norm(w)
    factor = min(1.0, max_speed / speed if speed > 0 else 1.0, max_spin / spin if spin > 0 else 1.0)
    return xi * factor


def _reference_led_pose(env, action, gain, stiffness):
    """`led_pose` in numpy and Python floats around the controller's `pose_lead`."""
    raw = np.asarray(action.twist, dtype=np.float64)
    twist = _reference_limit(raw, MAX_SPEED_M_S, MAX_ANGULAR_SPEED_RAD_S)
    scale = norm(twist) / norm(raw) if raw.any() else 1.0
    accel = _reference_limit(scale * (np.zeros(6) if action.accel is None else action.accel), MAX_ACCEL_M_S2,
                             MAX_ANGULAR_ACCEL_RAD_S2)
    push = np.zeros(6) if action.push is None else action.push
    lead = (gain * env.controller.pose_lead(env.data, twist, accel, stiffness) + push).tolist()
    anchor = action.pose if action.anchor is None else action.anchor
    quat = np.array(quat_mul_one(quat_from_rotvec_one(lead[3:]), np.asarray(anchor.quat, dtype=np.float64).tolist()))
    return Pose(pos=anchor.pos + np.array(lead[:3]), quat=quat / norm(quat))


@pytest.fixture(scope="module")
def env():
    return PegInHoleEnv()


def _random_action(rng: np.random.Generator, env: PegInHoleEnv) -> Action:
    tcp = env.observation.tcp
    kind = rng.integers(4)
    twist = np.zeros(6) if kind == 0 else rng.normal(0.0, [0.05, 0.05, 0.05, 0.3, 0.3, 0.3]) * (
        30.0 if kind == 1 else 1.0)  # kind 1: beyond the speed limits
    accel = None if rng.uniform() < 0.3 else rng.normal(0.0, 1.5, 6) * (10.0 if rng.uniform() < 0.3 else 1.0)
    push = None if rng.uniform() < 0.4 else rng.normal(0.0, 0.003, 6)
    anchor = None if rng.uniform() < 0.3 else Pose(tcp.pos + rng.normal(0.0, 0.002, 3),
                                                   quat_mul_one(quat_from_rotvec_one(rng.normal(0.0, 0.02, 3).tolist()),
                                                                tcp.quat.tolist()))
    if anchor is not None:
        anchor = Pose(anchor.pos, np.asarray(anchor.quat))
    stiffness = None if rng.uniform() < 0.5 else np.diag(rng.uniform(200.0, 3000.0, 3))
    rotational = None if rng.uniform() < 0.5 else float(rng.uniform(2.0, 80.0))
    pose = Pose(tcp.pos + rng.normal(0.0, 0.001, 3), quat_from_rotvec(rng.normal(0.0, 0.01, 3)))
    return Action(pose, stiffness, rotational, twist, accel, anchor, push)


def test_the_compiled_lead_equals_the_python_one_bit_for_bit(env) -> None:
    rng = np.random.default_rng(5)
    checked = 0
    for episode, period in wandering_states(env, rng, episodes=6, periods=40, step_m=0.003):
        action = _random_action(rng, env)
        stiffness = env.controller.action_stiffness(action)
        gain = [1.0, 0.7, 1.3][period % 3]
        ref = _reference_led_pose(env, action, gain, stiffness)
        got = led_pose(env.controller, env.data, action, gain, stiffness)
        assert np.array_equal(ref.pos, got.pos) and np.array_equal(ref.quat, got.quat), (episode, period)
        commanded, commanded_k = env.controller.command(env.data, action, gain)
        assert np.array_equal(commanded_k, stiffness)
        if action.twist is not None:
            assert np.array_equal(commanded.pos, got.pos) and np.array_equal(commanded.quat, got.quat)
        checked += 1
    assert checked >= 200


def test_the_limit_scales_both_parts_by_one_factor() -> None:
    def limited(xi):
        return xi * feedforward_kernel.limit_factor(xi, MAX_SPEED_M_S, MAX_ANGULAR_SPEED_RAD_S)

    xi = np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.5])
    assert np.array_equal(limited(xi), xi * (MAX_SPEED_M_S / 1.0))
    assert np.array_equal(limited(np.zeros(6)), np.zeros(6))
    rng = np.random.default_rng(1)
    for _ in range(200):
        xi = rng.normal(0.0, 1.0, 6) * rng.uniform(0.01, 10.0)
        assert np.array_equal(limited(xi), _reference_limit(xi, MAX_SPEED_M_S, MAX_ANGULAR_SPEED_RAD_S))


@pytest.mark.parametrize("field, value, error", [
    ("twist", np.array([0.0, 0.0, np.nan, 0.0, 0.0, 0.0]), ControllerError),
    ("twist", np.zeros(5), ControllerError),
    ("accel", np.full(6, np.inf), ControllerError),
    ("push", np.zeros(4), ControllerError),
])
def test_a_malformed_action_is_refused_naming_the_field(env, field, value, error) -> None:
    env.reset(seed=0)
    tcp = env.observation.tcp
    values = {"twist": np.full(6, 0.01), "accel": None, "push": None, field: value}
    action = Action(Pose(tcp.pos, tcp.quat), twist=values["twist"], accel=values["accel"], push=values["push"])
    with pytest.raises(error, match=field):
        env.controller.command(env.data, action, 1.0)


def test_a_zero_gain_or_no_twist_commands_the_action_s_pose(env) -> None:
    env.reset(seed=0)
    tcp = env.observation.tcp
    pose = Pose(tcp.pos, tcp.quat)
    assert env.controller.command(env.data, Action(pose, twist=np.full(6, 0.01)), 0.0)[0] is pose
    assert env.controller.command(env.data, Action(pose), 1.0)[0] is pose


@pytest.mark.parametrize("stiffness, rotational, words", [
    (np.eye(6) * 500.0, 40.0, "leave rotational_stiffness None"),
    (np.eye(4), None, r"\(3, 3\) or \(6, 6\)"),
])
def test_a_malformed_stiffness_is_refused(env, stiffness, rotational, words) -> None:
    env.reset(seed=0)
    with pytest.raises(ControllerError, match=words):
        env.controller.command(env.data, Action(env.observation.tcp, stiffness, rotational))
