"""The Python API refuses bad input with a clear error and keeps its state sound: the Gymnasium environment's
construction, a failed reset, the nominal poses a policy is handed, actions of the wrong type, stiffness and posture
references the law cannot carry, a control MuJoCo refuses, and the lookahead's hemisphere."""

from __future__ import annotations

import gymnasium
import mujoco
import numpy as np
import pytest

from controllers.errors import ControllerError
from envs.errors import EnvError
from envs.gym_env import ENV_ID
from envs.policies.interface import Action
from envs.poses import Pose
from envs.rollout.episode import StartPose, run_episode
from envs.sim.env import PegInHoleEnv
from envs.sim.instability import InstabilityCheck


@pytest.fixture(scope="module")
def env() -> PegInHoleEnv:
    return PegInHoleEnv()


@pytest.mark.parametrize("options, words", [({"camera": None}, "camera=None must be the name"),
                                            ({"camera": 3}, "camera=3 must be the name"),
                                            ({"width": 0}, "width=0 must be an integer"),
                                            ({"height": 10**5}, "height=100000 must be an integer")])
def test_the_gym_environment_refuses_a_camera_or_frame_it_cannot_render(options, words) -> None:
    with pytest.raises(EnvError, match=words):  # camera=None crashed the interpreter inside MuJoCo
        gymnasium.make(ENV_ID, render_mode="rgb_array", **options)


def test_a_failed_reset_leaves_no_episode_to_step(env) -> None:
    env.reset(seed=0)
    goal = env.nominal_goal
    with pytest.raises(EnvError, match="collision"):
        env.reset(start_pose=Pose(goal.pos + np.array([0.03, 0.0, 0.0]), goal.quat))  # inside the sorter
    with pytest.raises(EnvError, match="its reset failed"):
        env.step(env.nominal_goal)
    env.reset(seed=0)  # a good reset makes it usable again
    assert env.step(env.start) is not None


class _Vandal:
    """Writes into the nominal poses it is handed, then holds its start."""

    def reset(self, observation, period_s):
        self.start = observation.tcp
        observation.nominal_hole.pos[:] = 0.0

    def act(self, observation):
        return Action(pose=self.start)


def test_a_policy_cannot_change_the_nominal_poses_of_later_episodes(env) -> None:
    hole = env.nominal_hole.pos.copy()
    record, _ = run_episode(env, _Vandal(), StartPose(0, -1, env.nominal_start()))
    assert record.reason.startswith("error: ValueError") and "read-only" in record.reason
    assert np.array_equal(env.nominal_hole.pos, hole)


class _TuplePose:
    def reset(self, observation, period_s):
        self.start = (observation.tcp.pos, observation.tcp.quat)

    def act(self, observation):
        return Action(pose=self.start)  # a (pos, quat) pair, not a Pose


class _Unprintable(Exception):
    def __str__(self) -> str:
        raise RuntimeError("no message")


class _RaisesUnprintable:
    def reset(self, observation, period_s):
        pass

    def act(self, observation):
        raise _Unprintable()


@pytest.mark.parametrize("policy, words", [(_TuplePose(), "whose pose is a tuple, not an envs.poses.Pose"),
                                           (_RaisesUnprintable(), "_Unprintable: (its message could not be printed)")])
def test_an_episode_records_a_bad_action_or_exception_and_never_raises(env, policy, words) -> None:
    record, _ = run_episode(env, policy, StartPose(0, -1, env.nominal_start()), record_trace=True)
    assert not record.success and words in record.reason


@pytest.mark.parametrize("scale, words", [(1e308, "eigenvalues"), (1e-300, "eigenvalues")])
def test_a_stiffness_the_law_cannot_carry_is_refused(env, scale, words) -> None:
    env.reset(seed=0)
    with pytest.raises(EnvError, match=words):  # 1e308 gave NaN torques and a limp arm
        env.step(env.start, np.eye(6) * scale)


def test_a_posture_reference_beyond_any_joint_is_refused(env) -> None:
    env.reset(seed=0)
    with pytest.raises(ControllerError, match="q_nullspace"):
        env.controller.compute_torque(env.data, env.start.pos, env.start.quat, None, [1e308] * 7)


def test_a_control_mujoco_zeroes_ends_the_episode_as_an_instability(env) -> None:
    env.reset(seed=0)
    check = InstabilityCheck(env.data, slice(0, 7), 10.0)
    assert check.check(0.0) is None
    env.data.warning[mujoco.mjtWarning.mjWARN_BADCTRL].number += 1  # what MuJoCo counts when it zeroes a bad ctrl
    found = check.check(0.1)
    assert found is not None and "mjWARN_BADCTRL" in found and "zeroed the controls" in found


@pytest.mark.parametrize("flag", ["stiffness_action", "privileged"])
def test_a_gym_flag_that_is_no_boolean_is_refused(flag) -> None:
    with pytest.raises(EnvError, match=f"{flag}='no' must be True or False"):  # "no" counted as true
        gymnasium.make(ENV_ID, **{flag: "no"})


@pytest.mark.parametrize("floor", [-1.0, 0.0, float("nan"), True])
def test_nearest_spd_refuses_a_floor_that_would_not_make_it_spd(floor) -> None:
    from rflow.errors import RFlowError
    from rflow.manifolds.spd import nearest_spd

    with pytest.raises(RFlowError, match="min_eigenvalue"):
        nearest_spd(-np.eye(3), min_eigenvalue=floor)
