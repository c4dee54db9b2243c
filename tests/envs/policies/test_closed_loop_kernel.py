"""The compiled closed-loop arithmetic (envs.policies.closed_loop_kernel) equals, bit for bit, the Python it
replaced (tests/helpers/closed_loop_reference.py): the contact adaptation's state along random episodes near the hole
(push, seat push, stall search, frame shift and turn, sensing), and the query and action of the closed loop from random
flow poses, turned and not, at speeds other than 1."""

from __future__ import annotations

import numpy as np
import pytest

from envs.policies import closed_loop_kernel as kernel
from envs.policies.adaptation import ContactAdaptation, ContactAdapter
from envs.poses import quat_from_rotvec, quat_mul, rotate
from tests.helpers.closed_loop_reference import ReferenceAdapter, reference_action, reference_query

GOAL = np.array([0.5, 0.02, 0.18])
GOAL_QUAT = quat_from_rotvec(np.array([3.1, 0.05, -0.02]))
AXIS = rotate(GOAL_QUAT, np.array([0.0, 0.0, 1.0]))

CONFIGS = [
    ContactAdaptation(),
    ContactAdaptation(push_limit_m=0.003, push_leak_s=0.4, frame_limit_m=0.0008, frame_limit_deg=0.4,
                      search_push_m=0.001, search_period_s=0.3, seat_force_n=1.0),
    ContactAdaptation.off(),
    ContactAdaptation().without(["search", "compliance"]),
]


def _state(a) -> dict:
    """What the adaptation exposes, for either implementation."""
    return {"push": a.push, "frame": a.frame, "rotation": a.rotation, "search": np.asarray(a.search),
            "search_s": a.search_s, "resistance": a.resistance_n, "offset": a.offset}


def _assert_same(ref: dict, got: dict, step: int) -> None:
    for key in ref:
        assert np.array_equal(np.asarray(ref[key]), np.asarray(got[key])), f"{key} differs at step {step}"


@pytest.mark.parametrize("config", CONFIGS)
def test_the_adaptation_s_state_follows_the_python_one_bit_for_bit(config) -> None:
    rng = np.random.default_rng(17)
    for episode in range(6):
        ref, got = ReferenceAdapter(config, GOAL, AXIS), ContactAdapter(config, GOAL, AXIS)
        mouth = None if episode == 0 else 0.03
        ref.reset(mouth)
        got.reset(mouth)
        pos = GOAL + AXIS * rng.uniform(0.0, 0.04) + rng.normal(0.0, 0.001, 3)
        quat = quat_mul(quat_from_rotvec(rng.normal(0.0, 0.01, 3)), GOAL_QUAT)
        held = rng.uniform() < 0.5
        for step in range(400):
            if step % 50 == 0:
                held = not held  # alternate: the walls hold the peg (stall, search) / it follows the flow
            velocity = -AXIS * rng.uniform(0.0, 0.02) + rng.normal(0.0, 0.002, 3)
            omega = rng.normal(0.0, 0.02, 3)
            if not held:
                pos = pos + velocity * 0.01 * rng.uniform(0.5, 1.0)
                quat = quat_mul(quat_from_rotvec(omega * 0.01 * rng.uniform(0.0, 1.0)), quat)
            force = rng.normal(0.0, 4.0, 3) + (8.0 * AXIS if rng.uniform() < 0.3 else 0.0)
            ref.sense(rotate(quat, force))
            got.sense_wrench(quat, np.concatenate([force, rng.normal(0.0, 0.1, 3)]))
            ref.update(pos, velocity, 0.01)
            got.update(pos, velocity, 0.01)
            ref.update_rotation(pos, quat, omega, 0.01)
            got.update_rotation(pos, quat, omega, 0.01)
            _assert_same(_state(ref), _state(got), step)
            assert ref.rotational_stiffness(pos) == got.rotational_stiffness(pos)


@pytest.mark.parametrize("turned", [False, True])
@pytest.mark.parametrize("speed", [1.0, 0.7])
def test_the_query_and_the_action_follow_the_python_ones_bit_for_bit(turned: bool, speed: float) -> None:
    rng = np.random.default_rng(23 + int(turned))
    for _ in range(300):
        ref, got = ReferenceAdapter(ContactAdaptation(), GOAL, AXIS), ContactAdapter(ContactAdaptation(), GOAL, AXIS)
        frame = rng.normal(0.0, 0.0005, 3)
        rotation = rng.normal(0.0, 0.01, 3) if turned else np.zeros(3)
        ref.frame, ref.rotation = frame.copy(), rotation.copy()
        got.frame, got.rotation = frame, rotation
        pos = GOAL + rng.normal(0.0, 0.02, 3)
        quat = quat_mul(quat_from_rotvec(rng.normal(0.0, 0.2, 3)), GOAL_QUAT) * rng.choice([-1.0, 1.0])
        q_pos, q_quat, delta, rho = reference_query(ref, pos, quat)
        g_pos, g_quat, g_delta, g_rho = (np.empty(3), np.empty(4), np.empty(3), np.empty(4))
        assert kernel.query_into(got.state, pos, quat, g_pos, g_quat, g_delta, g_rho) == turned
        for a, b in ((q_pos, g_pos), (q_quat, g_quat), (delta, g_delta)) + (((rho, g_rho),) if turned else ()):
            assert np.array_equal(a, b)
        p1 = q_pos + rng.normal(0.0, 0.002, 3)
        q1 = quat_mul(quat_from_rotvec(rng.normal(0.0, 0.02, 3)), q_quat) * rng.choice([-1.0, 1.0])
        q1 = q1 * (1.0 + rng.normal(0.0, 1e-9))  # the flow's quaternions are unit only to rounding
        p2 = p1 + rng.normal(0.0, 0.002, 3)
        q2 = quat_mul(quat_from_rotvec(rng.normal(0.0, 0.02, 3)), q1) * rng.choice([-1.0, 1.0])
        want = reference_action(pos, quat, q_pos, q_quat, delta, rho, p1, q1, p2, q2, 0.05, speed)
        out = np.empty(kernel.ACTION_SIZE)
        kernel.action_into(pos, quat, g_pos, g_quat, g_delta, g_rho, turned, p1, q1, p2, q2, 0.05, speed,
                           speed**2, out)
        slots = (kernel.ACTION_POS, kernel.ACTION_QUAT, kernel.ACTION_TWIST, kernel.ACTION_ACCEL,
                 kernel.ACTION_ANCHOR_POS, kernel.ACTION_ANCHOR_QUAT, kernel.ACTION_SIZE)
        for value, start, end in zip(want, slots[:-1], slots[1:]):
            assert np.array_equal(value, out[start:end])


def test_the_adapter_s_vectors_are_copies_and_settable() -> None:
    """Reading the state hands out copies (a caller holding the frame does not see it move), and a test may set
    the frame and the rotation."""
    a = ContactAdapter(ContactAdaptation(), GOAL, AXIS)
    frame = a.frame
    a.frame = [0.001, 0.0, 0.0]
    assert np.array_equal(frame, np.zeros(3)) and np.array_equal(a.frame, [0.001, 0.0, 0.0])
    a.reset(0.03)
    assert np.array_equal(a.frame, np.zeros(3)) and a.mouth_depth_m == 0.03
    a.reset()
    assert a.mouth_depth_m is None
