"""One schema for Gym and the Policy interface (envs/gym/schema.py): the Gym observation's keys are the `Observation`'s
fields and its values the policy's numbers exactly, the action is an `Action` with the rotational stiffness, and the
info names its quantities with their units."""

from __future__ import annotations

from dataclasses import fields

import gymnasium
import numpy as np
import pytest

from envs.gym.schema import ActionSchema, observation_dict, observation_from_dict
from envs.gym_env import ENV_ID
from envs.policies.interface import Observation, PolicyTask, PrivilegedState, observe, policy_task
from envs.poses import Pose


@pytest.fixture(scope="module")
def env():
    made = gymnasium.make(ENV_ID, time_limit_s=0.3, hole_error_mm=1.0, privileged=True)
    yield made.unwrapped
    made.close()


def _expected_keys(value: object, cls: type, prefix: str = "") -> set[str]:
    """A dataclass's fields as flat keys: a Pose field f as f_pos and f_quat, any other field by its name."""
    keys = set()
    for f in fields(cls):
        if f.name == "privileged":
            continue
        if isinstance(getattr(value, f.name), Pose):
            keys |= {f"{prefix}{f.name}_pos", f"{prefix}{f.name}_quat"}
        else:
            keys.add(prefix + f.name)
    return keys


def test_the_gym_observations_keys_are_the_policy_observations_fields(env) -> None:
    obs, _ = env.reset(seed=2)
    policy_view = observe(env.sim, privileged=True)
    plain = _expected_keys(policy_view, Observation)
    assert {"tcp_pos", "tcp_quat", "nominal_goal_pos", "nominal_goal_quat", "nominal_hole_pos", "time_s"} <= plain
    assert set(obs) == plain | _expected_keys(policy_view.privileged, PrivilegedState, "privileged_")
    assert set(env.observation_space.spaces) == set(obs)
    unprivileged = gymnasium.make(ENV_ID, time_limit_s=0.3)
    assert set(unprivileged.reset(seed=2)[0]) == plain
    unprivileged.close()


def test_the_gym_observation_holds_the_policys_numbers_to_the_last_bit(env) -> None:
    obs, _ = env.reset(seed=3)
    obs, *_ = env.step(np.zeros(6, dtype=np.float32))
    policy_view = observe(env.sim, privileged=True)
    rebuilt = observation_from_dict(obs)
    for f in fields(Observation):
        mine, theirs = getattr(rebuilt, f.name), getattr(policy_view, f.name)
        if isinstance(theirs, Pose):
            np.testing.assert_array_equal(mine.pos, theirs.pos)
            np.testing.assert_array_equal(mine.quat, theirs.quat)
        elif f.name != "privileged":
            np.testing.assert_array_equal(mine, theirs)
    np.testing.assert_array_equal(rebuilt.privileged.hole.pos, env.sim.hole.pos)
    np.testing.assert_array_equal(rebuilt.privileged.goal.quat, env.sim.goal.quat)
    again = observation_dict(rebuilt, privileged=True)
    assert set(again) == set(obs) and all(np.array_equal(again[k], obs[k]) for k in obs)
    assert all(v.dtype == np.float64 for v in obs.values())


def test_the_action_is_a_policy_action_with_rotational_stiffness(env) -> None:
    task: PolicyTask = policy_task(env.sim)
    schema = ActionSchema.for_task(task, stiffness=True)
    assert [name for name, _ in schema.parts] == ["pos_m", "rotvec_rad", "stiffness_n_m", "rotational_stiffness_nm_rad"]
    goal = task.nominal_goal
    action = schema.to_policy_action(schema.to_action(np.concatenate([goal.pos, np.zeros(3), [400, 500, 600, 12.0]])))
    np.testing.assert_allclose(action.pose.pos, goal.pos, atol=1e-6)
    np.testing.assert_allclose(action.pose.quat, goal.quat, atol=1e-7)
    np.testing.assert_allclose(np.diag(action.stiffness), [400, 500, 600], rtol=1e-6)
    assert action.rotational_stiffness == pytest.approx(12.0, rel=1e-5)
    assert ActionSchema.for_task(task) == ActionSchema.for_cell(env.sim.nominal_hole, env.sim.nominal_goal)
    assert env.action_schema == ActionSchema.for_cell(env.sim.nominal_hole, env.sim.nominal_goal,
                                                      env.sim.config.start_region)


def test_info_names_the_truth_with_units_instead_of_a_mixed_vector(env) -> None:
    env.reset(seed=4)
    _, _, _, _, info = env.step(np.zeros(6, dtype=np.float32))
    ins = env.sim.observation.insertion
    assert (info["insertion_depth_m"], info["lateral_error_m"], info["tilt_deg"], info["yaw_error_deg"]) == \
        (ins.depth_m, ins.lateral_m, ins.tilt_deg, ins.yaw_error_deg)
    assert "insertion" not in info and isinstance(info["in_hole"], bool)
