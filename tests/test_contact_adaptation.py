"""The closed-loop contact adaptation (envs.execution.adaptation): the axial push builds up while the peg is
held and leaks away, the frame yields to a sideways motion the walls refuse only near the goal, both are
bounded, and the policy queries the flow in the shifted frame."""

from __future__ import annotations

import numpy as np
import pytest

from envs.errors import EnvError
from envs.execution.adaptation import ContactAdaptation, ContactAdapter
from envs.execution.policy import ClosedLoopPolicy, skill_step
from envs.poses import Pose
from skill_fixtures import GOAL_POS, GOAL_QUAT, tiny_skill

PERIOD_S = 0.01
AXIS = np.array([0.0, 0.0, -1.0])  # the insertion axis: down
GOAL = np.array([0.5, 0.0, 0.2])


def adapter(**kwargs) -> ContactAdapter:
    return ContactAdapter(ContactAdaptation(**kwargs), GOAL, AXIS)


def hold(a: ContactAdapter, pos: np.ndarray, velocity_d: np.ndarray, steps: int) -> None:
    """The flow asks for ``velocity_d`` while the peg stays at ``pos``."""
    for _ in range(steps):
        a.update(pos, velocity_d, PERIOD_S)


def test_axial_push_grows_while_the_peg_is_held() -> None:
    a = adapter(push_limit_m=0.05, push_leak_s=1.0)
    hold(a, GOAL + [0.0, 0.0, 0.01], np.array([0.0, 0.0, -0.01]), 101)  # held 1 s, the flow wants 10 mm/s down
    # leaky integral of 10 mm/s over 1 s with tau = 1 s: 10 mm (1 - e^-1) ~ 6.3 mm, pointing down
    assert a.push[2] == pytest.approx(-0.01 * (1 - np.exp(-1.0)), rel=0.05)
    assert np.allclose(a.push[:2], 0.0)


def test_push_stays_near_zero_while_the_peg_follows_the_flow() -> None:
    a = adapter()
    for k in range(101):
        a.update(GOAL + [0.0, 0.0, 0.03 - 0.01 * PERIOD_S * k], np.array([0.0, 0.0, -0.01]), PERIOD_S)
    assert np.linalg.norm(a.push) < 1e-9 and np.linalg.norm(a.frame) < 1e-9


def test_push_is_bounded_and_leaks_away() -> None:
    a = adapter(push_limit_m=0.002, push_leak_s=0.5)
    hold(a, GOAL, np.array([0.0, 0.0, -0.04]), 500)
    assert np.linalg.norm(a.push) == pytest.approx(0.002)
    hold(a, GOAL, np.zeros(3), 100)  # 1 s later, the flow at rest
    assert np.linalg.norm(a.push) == pytest.approx(0.002 * (1 - PERIOD_S / 0.5) ** 100, rel=1e-6)


def test_frame_yields_to_a_refused_sideways_motion_near_the_goal() -> None:
    a = adapter(frame_limit_m=0.01)
    hold(a, GOAL + [0.0, 0.0, 0.02], np.array([0.001, 0.0, 0.0]), 101)  # wants +x at 1 mm/s, walls hold it
    # delta = -integral of the refused lateral velocity: 1 mm/s over 1 s (100 intervals) = -1 mm in x
    assert a.frame == pytest.approx([-0.001, 0.0, 0.0], abs=1e-12)
    assert np.allclose(a.push, 0.0)  # the sideways demand pushes nothing


def test_frame_stays_put_far_from_the_goal_and_is_bounded_near_it() -> None:
    far = adapter(radius_m=0.035)
    hold(far, GOAL + [0.0, 0.0, 0.05], np.array([0.001, 0.0, 0.0]), 200)
    assert np.allclose(far.frame, 0.0)
    near = adapter(frame_limit_m=0.0015)
    hold(near, GOAL, np.array([0.0, 0.01, 0.0]), 500)
    assert np.linalg.norm(near.frame) == pytest.approx(0.0015)


def test_rotational_compliance_only_near_the_goal_and_off_switches_everything_off() -> None:
    a = adapter(rotational_stiffness=5.0, radius_m=0.035)
    assert a.rotational_stiffness(GOAL + [0.0, 0.0, 0.03]) == 5.0
    assert a.rotational_stiffness(GOAL + [0.0, 0.0, 0.04]) is None
    off = ContactAdapter(ContactAdaptation.off(), GOAL, AXIS)
    hold(off, GOAL, np.array([0.01, 0.0, -0.01]), 100)
    assert np.allclose(off.push, 0.0) and np.allclose(off.frame, 0.0) and off.rotational_stiffness(GOAL) is None


@pytest.mark.parametrize("kwargs", [{"push_limit_m": -1.0}, {"push_limit_m": float("nan")}, {"push_leak_s": 0.0},
                                    {"frame_limit_m": -0.001}, {"radius_m": float("inf")},
                                    {"rotational_stiffness": 0.0}])
def test_bad_adaptation_settings_are_rejected(kwargs) -> None:
    name = next(iter(kwargs))
    with pytest.raises(EnvError, match=name):
        ContactAdaptation(**kwargs)


def test_policy_queries_the_flow_in_the_shifted_frame() -> None:
    skill = tiny_skill()
    policy = ClosedLoopPolicy(skill, 0.05)
    policy.reset_at(Pose(GOAL_POS, GOAL_QUAT), PERIOD_S)
    delta = np.array([0.0008, -0.0005, 0.0])
    policy.adapter.frame = delta.copy()
    measured = Pose(GOAL_POS + np.array([0.003, 0.001, 0.02]), GOAL_QUAT)
    command = policy.command(0, measured)
    expected, _ = skill_step(skill, measured.pos - delta, measured.quat, 0.05)
    assert command.pose.pos == pytest.approx(expected + delta, abs=1e-12)
    assert command.anchor.pos == pytest.approx(measured.pos, abs=1e-12)
    assert command.rotational_stiffness == ContactAdaptation().rotational_stiffness  # 20 mm from the goal
