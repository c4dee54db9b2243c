"""The closed-loop contact adaptation (envs.policies.adaptation): the axial push builds up while the peg is
held and leaks away, the frame yields to a sideways motion or a rotation the walls refuse only near the goal, all
are bounded, and the policy queries the flow in the shifted and turned frame."""

from __future__ import annotations

import numpy as np
import pytest

from envs.errors import EnvError
from envs.policies.adaptation import ContactAdaptation, ContactAdapter
from envs.policies.flow_skill import ClosedLoopPolicy, skill_step
from envs.poses import Pose, quat_conj, quat_from_rotvec, quat_mul, quat_to_rotvec, rotate
from tests.helpers.skill_fixtures import GOAL_POS, GOAL_QUAT, tiny_skill

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
    a = adapter(push_limit_m=0.002, push_leak_s=0.5, seat_speed_m_s=0.0)
    hold(a, GOAL, np.array([0.0, 0.0, -0.04]), 500)
    assert np.linalg.norm(a.push) == pytest.approx(0.002)
    hold(a, GOAL, np.zeros(3), 100)  # 1 s later, the flow at rest
    assert np.linalg.norm(a.push) == pytest.approx(0.002 * (1 - PERIOD_S / 0.5) ** 100, rel=1e-6)


def test_the_seat_push_drives_a_resting_peg_down_until_the_floor_holds_it() -> None:
    a = adapter(push_leak_s=1e9, seat_speed_m_s=0.002, seat_radius_m=0.005, seat_force_n=5.0)
    hold(a, GOAL + [0.0, 0.0, 0.001], np.zeros(3), 101)  # at rest 1 mm above the goal, nothing on the wrist
    assert a.push == pytest.approx([0.0, 0.0, -0.002], abs=1e-9)  # 2 mm/s for 1 s, along the axis (down)
    a.sense([0.0, 0.0, 6.0])  # the floor pushes up with 6 N: seated
    hold(a, GOAL + [0.0, 0.0, 0.001], np.zeros(3), 100)
    assert a.push == pytest.approx([0.0, 0.0, -0.002], abs=1e-9)
    far = adapter(push_leak_s=1e9)
    hold(far, GOAL + [0.0, 0.0, 0.006], np.zeros(3), 101)  # 6 mm from the goal: outside the seat radius
    assert np.linalg.norm(far.push) == 0.0


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
                                    {"frame_limit_m": -0.001}, {"frame_limit_deg": float("nan")},
                                    {"radius_m": float("inf")},
                                    {"rotational_stiffness": 0.0}, {"search_amplitude_m": -0.001},
                                    {"search_period_s": 0.0}, {"search_band_m": float("nan")},
                                    {"search_push_scale": 1.5}])
def test_bad_adaptation_settings_are_rejected(kwargs) -> None:
    name = next(iter(kwargs))
    with pytest.raises(EnvError, match=name):
        ContactAdaptation(**kwargs)


def started_policy(skill) -> ClosedLoopPolicy:
    """A closed-loop policy with a 50 ms lookahead, reset at the goal."""
    policy = ClosedLoopPolicy(skill, 0.05)
    policy.reset_at(Pose(GOAL_POS, GOAL_QUAT), PERIOD_S)
    return policy


def test_policy_queries_the_flow_in_the_shifted_frame() -> None:
    skill = tiny_skill()
    policy = started_policy(skill)
    delta = np.array([0.0008, -0.0005, 0.0])
    policy.adapter.frame = delta.copy()
    measured = Pose(GOAL_POS + np.array([0.003, 0.001, 0.02]), GOAL_QUAT)
    command = policy.command(0, measured)
    expected, _ = skill_step(skill, measured.pos - delta, measured.quat, 0.05)
    assert command.pose.pos == pytest.approx(expected + delta, abs=1e-12)
    assert command.anchor.pos == pytest.approx(measured.pos, abs=1e-12)
    assert command.rotational_stiffness == ContactAdaptation().rotational_stiffness  # 20 mm from the goal


def hold_turn(a: ContactAdapter, pos: np.ndarray, quat: np.ndarray, omega_d: np.ndarray, steps: int) -> None:
    """The flow asks to turn at ``omega_d`` while the walls hold the peg at (``pos``, ``quat``)."""
    for _ in range(steps):
        a.update_rotation(pos, quat, omega_d, PERIOD_S)


def test_frame_turns_with_a_refused_rotation_near_the_goal_and_is_bounded() -> None:
    a = adapter(frame_limit_deg=5.0)
    hold_turn(a, GOAL + [0.0, 0.0, 0.02], GOAL_QUAT, np.array([0.0, 0.01, 0.0]), 101)  # 10 mrad/s about y, held
    # rho = -integral of the refused rotation: 10 mrad/s over 1 s (100 intervals) = -10 mrad about y
    assert a.rotation == pytest.approx([0.0, -0.01, 0.0], abs=1e-9)
    hold_turn(a, GOAL, GOAL_QUAT, np.array([0.0, 0.0, 0.5]), 100)
    assert np.linalg.norm(a.rotation) == pytest.approx(np.deg2rad(5.0))
    far = adapter(radius_m=0.035)
    hold_turn(far, GOAL + [0.0, 0.0, 0.05], GOAL_QUAT, np.array([0.0, 0.01, 0.0]), 100)
    assert not far.rotation.any()
    off = ContactAdapter(ContactAdaptation.off(), GOAL, AXIS)
    hold_turn(off, GOAL, GOAL_QUAT, np.array([0.0, 0.01, 0.0]), 100)
    assert not off.rotation.any()


def test_frame_does_not_turn_while_the_peg_turns_as_the_flow_asks() -> None:
    a = adapter()
    omega = np.array([0.02, -0.01, 0.005])
    for k in range(101):
        quat = quat_mul(quat_from_rotvec(omega * PERIOD_S * k), GOAL_QUAT)
        a.update_rotation(GOAL, quat, omega, PERIOD_S)
    assert np.linalg.norm(a.rotation) < 1e-9


def test_policy_queries_the_flow_in_the_turned_frame() -> None:
    skill = tiny_skill()
    policy = started_policy(skill)
    rho = np.array([0.004, -0.01, 0.006])
    policy.adapter.rotation = rho.copy()
    turn = quat_from_rotvec(rho)
    measured = Pose(GOAL_POS + np.array([0.003, 0.001, 0.02]), quat_mul(quat_from_rotvec([0.0, 0.02, 0.0]), GOAL_QUAT))
    command = policy.command(0, measured)
    pos, quat = skill_step(skill, measured.pos, quat_mul(quat_conj(turn), measured.quat), 0.05)
    expected = quat_mul(turn, quat)
    assert command.pose.pos == pytest.approx(pos, abs=1e-12)
    assert abs(float(np.dot(command.pose.quat, expected))) == pytest.approx(1.0, abs=1e-12)
    # the angular rate is the turned frame's, rotated back: it points from the measured toward the command
    step = quat_to_rotvec(quat_mul(command.pose.quat, quat_conj(measured.quat)))
    assert np.dot(command.twist[3:], step) > 0.0
    unturned = started_policy(skill)
    plain = unturned.command(0, Pose(measured.pos, quat_mul(quat_conj(turn), measured.quat)))
    assert command.twist[3:] == pytest.approx(rotate(turn, plain.twist[3:]), abs=1e-12)


MOUTH_DEPTH_M = 0.03  # the goal lies 30 mm beyond the mouth along the (downward) axis


def stalled_at_mouth(depth_below_mouth_m: float, steps: int, **kwargs) -> ContactAdapter:
    """An adapter whose peg is held ``depth_below_mouth_m`` below the mouth while the flow asks 20 mm/s down."""
    a = adapter(**kwargs)
    a.reset(mouth_depth_m=MOUTH_DEPTH_M)
    hold(a, GOAL + [0.0, 0.0, MOUTH_DEPTH_M - depth_below_mouth_m], np.array([0.0, 0.0, -0.02]), steps)
    return a


def test_stall_search_circles_the_axis_while_the_peg_stalls_at_the_mouth() -> None:
    a = stalled_at_mouth(0.0009, 100, search_amplitude_m=0.002, search_period_s=1.0, search_push_m=0.005)
    assert np.linalg.norm(a.push) > 0.005 and a.search_s > 0.0
    radii, angles = [], []
    for _ in range(200):  # two more turns
        a.update(GOAL + [0.0, 0.0, MOUTH_DEPTH_M - 0.0009], np.array([0.0, 0.0, -0.02]), PERIOD_S)
        radii.append(np.linalg.norm(a.search))
        angles.append(np.arctan2(a.search[1], a.search[0]))
        assert abs(a.search @ AXIS) < 1e-15  # sideways only
    assert radii[-1] == pytest.approx(0.002) and max(radii) <= 0.002 + 1e-15
    assert np.ptp(np.unwrap(angles)) > 2 * 2 * np.pi - 0.2  # it turned twice
    assert np.allclose(a.offset, a.config.search_push_scale * a.push + a.search)  # less push while searching
    assert np.allclose(a.frame, 0.0)  # the frame holds still while searching


def test_stall_search_stays_off_below_the_mouth_without_a_mouth_and_when_off() -> None:
    deep = stalled_at_mouth(0.005, 300)  # stalled 5 mm inside the hole (a jam): no search
    assert np.linalg.norm(deep.push) > 0.005 and np.allclose(deep.search, 0.0)
    blind = adapter()  # reset without the nominal mouth
    hold(blind, GOAL + [0.0, 0.0, MOUTH_DEPTH_M], np.array([0.0, 0.0, -0.02]), 300)
    assert np.allclose(blind.search, 0.0)
    off = stalled_at_mouth(0.0009, 300, search_amplitude_m=0.0)
    assert np.allclose(off.search, 0.0)


def test_stall_search_ends_when_the_peg_drops_in() -> None:
    a = stalled_at_mouth(0.0009, 300)
    assert np.linalg.norm(a.search) > 0.0
    a.update(GOAL + [0.0, 0.0, MOUTH_DEPTH_M - 0.004], np.array([0.0, 0.0, -0.02]), PERIOD_S)  # 4 mm in
    assert np.allclose(a.search, 0.0) and a.search_s == 0.0
