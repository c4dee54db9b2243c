"""A policy run in the frame of the observed hole (envs.policies.goal_frame): the inner policy sees the observed goal
at its own goal, its commands come back moved by the same rigid motion, and without an observation everything passes
unchanged."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from envs.policies.flow_skill import ClosedLoopPolicy
from envs.policies.goal_frame import GoalFramePolicy, RigidMotion
from envs.policies.interface import Action, Observation, PrivilegedState
from envs.poses import Pose, quat_from_rotvec, quat_mul, rotate
from numerics.quaternion import quat_to_mat
from tests.helpers.skill_fixtures import GOAL_POS, GOAL_QUAT, tiny_skill

REFERENCE = Pose(GOAL_POS.copy(), GOAL_QUAT.copy())
OBSERVED = Pose(GOAL_POS + np.array([0.0008, -0.0005, 0.0002]),
                quat_mul(quat_from_rotvec(np.deg2rad([0.4, -0.3, 0.9])), GOAL_QUAT))


def observation(tcp: Pose, goal: Pose = OBSERVED, privileged: PrivilegedState | None = None) -> Observation:
    hole = Pose(goal.pos + 0.03 * rotate(goal.quat, [0.0, 0.0, -1.0]), goal.quat)
    return Observation(0.0, np.zeros(7), np.zeros(7), 0.01, tcp, np.array([1.0, -2.0, 3.0, 0.1, 0.2, 0.3]), hole, goal,
                       privileged)


class Recorder:
    """A policy that keeps what it saw and answers with a fixed action in its own frame."""

    def __init__(self, action: Action):
        self.action, self.seen = action, []

    def reset(self, obs: Observation, period_s: float) -> None:
        self.seen.append(obs)

    def act(self, obs: Observation) -> Action:
        self.seen.append(obs)
        return self.action


def test_the_rigid_motion_takes_the_reference_onto_the_observed_goal_and_back() -> None:
    motion = RigidMotion.between(REFERENCE, OBSERVED)
    moved = motion.pose(REFERENCE)
    assert np.allclose(moved.pos, OBSERVED.pos, atol=1e-15) and np.allclose(moved.quat, OBSERVED.quat, atol=1e-15)
    x = Pose(np.array([0.6, 0.1, 0.35]), quat_mul(quat_from_rotvec([0.2, -0.1, 0.3]), GOAL_QUAT))
    back = motion.inverse_pose(motion.pose(x))
    assert np.allclose(back.pos, x.pos, atol=1e-15) and np.allclose(back.quat, x.quat, atol=1e-15)
    r = quat_to_mat(motion.quat)
    assert np.allclose(motion.pose(x).pos, r @ (x.pos - REFERENCE.pos) + OBSERVED.pos, atol=1e-15)


def test_without_an_observation_error_everything_passes_unchanged() -> None:
    action = Action(Pose(GOAL_POS, GOAL_QUAT), twist=np.ones(6))
    inner = Recorder(action)
    policy = GoalFramePolicy(inner, REFERENCE)
    obs = observation(Pose(GOAL_POS + 0.05, GOAL_QUAT), goal=Pose(GOAL_POS.copy(), GOAL_QUAT.copy()))
    policy.reset(obs, 0.01)
    assert policy.act(obs) is action and all(seen is obs for seen in inner.seen)


def test_the_inner_policy_sees_the_observed_goal_at_its_own_and_its_commands_come_back_moved() -> None:
    k3 = np.diag([300.0, 500.0, 1500.0])
    k6 = np.diag([300.0, 500.0, 1500.0, 5.0, 10.0, 20.0])
    action = Action(Pose(GOAL_POS + [0.0, 0.0, 0.01], GOAL_QUAT), stiffness=k3, twist=np.arange(1.0, 7.0),
                    accel=np.arange(2.0, 8.0), anchor=Pose(GOAL_POS, GOAL_QUAT), push=np.arange(3.0, 9.0))
    inner = Recorder(action)
    policy = GoalFramePolicy(inner, REFERENCE)
    truth = PrivilegedState(OBSERVED, rotate(OBSERVED.quat, [0.0, 0.0, 1.0]), OBSERVED)
    tcp = Pose(OBSERVED.pos + [0.01, 0.0, 0.05], OBSERVED.quat)
    policy.reset(observation(tcp, privileged=truth), 0.01)
    out = policy.act(observation(tcp, privileged=truth))
    seen = inner.seen[-1]
    assert np.allclose(seen.nominal_goal.pos, REFERENCE.pos, atol=1e-15)
    assert abs(float(np.dot(seen.nominal_goal.quat, REFERENCE.quat))) == pytest.approx(1.0, abs=1e-15)
    assert np.allclose(seen.privileged.goal.pos, REFERENCE.pos, atol=1e-15)
    assert np.allclose(seen.privileged.hole_axis, rotate(REFERENCE.quat, [0.0, 0.0, 1.0]), atol=1e-15)
    assert np.allclose(seen.tcp.pos, REFERENCE.pos + rotate(REFERENCE.quat, rotate(OBSERVED.quat * [1, -1, -1, -1],
                                                                                    [0.01, 0.0, 0.05])), atol=1e-15)
    assert np.array_equal(seen.wrist_wrench, observation(tcp).wrist_wrench)  # sensor frame: as it is
    r = quat_to_mat(policy.motion.quat)
    assert np.allclose(out.pose.pos, r @ (action.pose.pos - REFERENCE.pos) + OBSERVED.pos, atol=1e-15)
    assert np.allclose(out.anchor.pos, OBSERVED.pos, atol=1e-15)
    for name in ("twist", "accel", "push"):
        value = getattr(action, name)
        assert np.allclose(getattr(out, name), np.concatenate([r @ value[:3], r @ value[3:]]), atol=1e-12)
    assert np.allclose(out.stiffness, r @ k3 @ r.T, atol=1e-9)
    assert np.allclose(np.linalg.eigvalsh(out.stiffness), [300.0, 500.0, 1500.0])
    policy.inner.action = dataclasses.replace(action, stiffness=k6)
    block = np.kron(np.eye(2), r)
    assert np.allclose(policy.act(observation(tcp)).stiffness, block @ k6 @ block.T, atol=1e-9)


def test_policies_in_moved_frames_answer_in_batches_as_they_do_alone() -> None:
    skill = tiny_skill()
    goals = [OBSERVED, Pose(GOAL_POS - [0.0005, 0.0, 0.0], GOAL_QUAT), Pose(GOAL_POS.copy(), GOAL_QUAT.copy())]
    tcps = [Pose(g.pos + [0.02, -0.01, 0.08], quat_mul(quat_from_rotvec([0.05, 0.0, -0.1]), g.quat)) for g in goals]

    def started() -> list[GoalFramePolicy]:
        policies = [GoalFramePolicy(ClosedLoopPolicy(skill, 0.05), REFERENCE) for _ in goals]
        for policy, tcp, goal in zip(policies, tcps, goals):
            policy.reset(observation(tcp, goal), 0.01)
        return policies

    alone = [p.act(observation(t, g)) for p, t, g in zip(started(), tcps, goals)]
    batch = started()
    assert len({p.batch_key() for p in batch}) == 1
    together = GoalFramePolicy.act_many(batch, [observation(t, g) for t, g in zip(tcps, goals)])
    for a, b in zip(alone, together):
        assert np.array_equal(a.pose.pos, b.pose.pos) and np.array_equal(a.pose.quat, b.pose.quat)
        assert np.array_equal(a.twist, b.twist) and np.array_equal(a.anchor.pos, b.anchor.pos)
    bare = ClosedLoopPolicy(skill, 0.05)  # the third frame is the identity: the bare policy's own action
    bare.reset(observation(tcps[2], goals[2]), 0.01)
    own = bare.act(observation(tcps[2], goals[2]))
    assert np.array_equal(own.pose.pos, alone[2].pose.pos) and np.array_equal(own.twist, alone[2].twist)


def test_the_evaluation_option_is_a_bool_and_reaches_the_config() -> None:
    from envs.errors import EnvError
    from envs.evaluation.config import EvaluationConfig
    from scripts.cli import build_parser
    from scripts.evaluate import config_from_args

    with pytest.raises(EnvError, match="follow_observed_hole"):
        EvaluationConfig(follow_observed_hole="yes")
    args = build_parser("evaluate").parse_args(["evaluate", "--model", "m", "--follow-observed-hole", "--hole-observation",
                                      "measured", "--hole-observation-tilt-deg", "0.2"])
    config = config_from_args(args)
    assert config.follow_observed_hole and config.settings()["follow_observed_hole"] is True
    assert (config.task.perturbations.hole_observation, config.task.perturbations.hole_observation_tilt_deg) == \
        ("measured", 0.2)
