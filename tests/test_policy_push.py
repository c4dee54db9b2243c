"""The closed-loop policy's integral push: it builds up while the peg is held, stays near zero while the peg
follows the flow, is bounded, and leaks away."""

from __future__ import annotations

import numpy as np
import pytest

from envs.errors import EnvError
from envs.execution.policy import ClosedLoopPolicy
from envs.poses import Pose

QUAT = np.array([0.0, 1.0, 0.0, 0.0])
PERIOD_S = 0.01


def policy(**kwargs) -> ClosedLoopPolicy:
    p = ClosedLoopPolicy(skill=_NoSkill(), **kwargs)  # the push needs no flow: a skill without stiffness
    p.reset(Pose(np.zeros(3), QUAT), PERIOD_S)
    return p


class _NoSkill:
    has_stiffness = False


def run(p: ClosedLoopPolicy, positions: list[np.ndarray], twist: np.ndarray) -> np.ndarray:
    for pos in positions:
        p._integrate_push(Pose(pos, QUAT), twist)
    return p._push.copy()


def test_push_grows_while_the_peg_is_held() -> None:
    p = policy(push_limit_m=0.05, push_leak_s=1.0)
    twist = np.array([0.0, 0.0, -0.01, 0.0, 0.0, 0.0])  # the flow wants 10 mm/s down
    push = run(p, [np.zeros(3)] * 101, twist)  # held for 1 s
    # leaky integral of 10 mm/s over 1 s with tau = 1 s: 10 mm (1 - e^-1) ~ 6.3 mm, pointing down
    assert push[2] == pytest.approx(-0.01 * (1 - np.exp(-1.0)), rel=0.05)
    assert np.allclose(push[[0, 1, 3, 4, 5]], 0.0)


def test_push_stays_near_zero_while_the_peg_follows_the_flow() -> None:
    p = policy()
    twist = np.array([0.0, 0.0, -0.01, 0.0, 0.0, 0.0])
    positions = [np.array([0.0, 0.0, -0.01 * PERIOD_S * k]) for k in range(101)]
    assert np.linalg.norm(run(p, positions, twist)) < 1e-9


def test_push_is_bounded_by_its_limit() -> None:
    p = policy(push_limit_m=0.002, push_leak_s=100.0)
    push = run(p, [np.zeros(3)] * 500, np.array([0.03, 0.0, -0.04, 0.0, 0.0, 0.0]))
    assert np.linalg.norm(push[:3]) == pytest.approx(0.002)


def test_rotational_push_is_off_by_default() -> None:
    p = policy()
    push = run(p, [np.zeros(3)] * 100, np.array([0.0, 0.0, 0.0, 0.1, 0.0, 0.0]))
    assert np.allclose(push, 0.0)


def test_push_leaks_away_when_the_flow_stops_asking() -> None:
    p = policy(push_leak_s=0.5)
    run(p, [np.zeros(3)] * 100, np.array([0.0, 0.0, -0.01, 0.0, 0.0, 0.0]))
    held = np.linalg.norm(p._push)
    after = np.linalg.norm(run(p, [np.zeros(3)] * 100, np.zeros(6)))  # 1 s later, flow at rest
    assert after == pytest.approx(held * (1 - PERIOD_S / 0.5) ** 100, rel=1e-6)


@pytest.mark.parametrize("kwargs", [{"push_limit_m": -1.0}, {"push_limit_m": float("nan")}, {"push_leak_s": 0.0}])
def test_bad_push_settings_are_rejected(kwargs) -> None:
    with pytest.raises(EnvError, match="push"):
        policy(**kwargs)
