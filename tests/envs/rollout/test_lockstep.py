"""envs.rollout.lockstep: episodes run side by side give the records, and the traces' poses, of the same episodes
run one at a time, to the last bit, whatever the number of slots, the order or the threads; the batched flow query
(`ClosedLoopPolicy.act_many`) equals each policy's own ``act``; an error ends only its own episode; slots that
share a model are refused. Physics episodes of the tiny skill, 45 mm above the goal with a 1 mm / 1 deg hole error
(as tests/helpers/policy_record_cases.py), so the contact adaptation acts."""

from __future__ import annotations

import numpy as np
import pytest

from envs.errors import EnvError
from envs.evaluation.evaluate import sample_starts
from envs.policies.flow_skill import ClosedLoopPolicy, StiffnessSetting, make_policy
from envs.policies.interface import observe
from envs.poses import Pose
from envs.rollout.episode import EpisodeRun, StartPose, run_episode
from envs.rollout.lockstep import act_for, run_lockstep
from envs.sim.env import EpisodeConfig, PegInHoleEnv
from envs.task.perturbation import PerturbationRanges
from tests.helpers.skill_fixtures import GOAL_POS, GOAL_QUAT, tiny_skill

TIME_LIMIT_S = 1.5


@pytest.fixture(scope="module")
def skill():
    return tiny_skill()


@pytest.fixture(scope="module")
def starts():
    found = sample_starts(GOAL_POS[None] + np.array([[0.0, 0.0, 0.045]]), GOAL_QUAT[None], 5, 11, 0.002, 2.0,
                          perturbations=PerturbationRanges(hole_error_m=0.001, hole_error_deg=1.0))
    far = StartPose(99, -1, Pose(pos=GOAL_POS + np.array([2.0, 0.0, 0.0]), quat=GOAL_QUAT))  # out of reach
    return [*found[:2], far, *found[2:]]


def env():
    return PegInHoleEnv(episode_config=EpisodeConfig(time_limit_s=TIME_LIMIT_S))


def without_wall(record):
    values = record.to_dict()
    values.pop("wall_s")
    return values


@pytest.fixture(scope="module")
def alone(skill, starts):
    one = env()
    return {stiffness: [without_wall(run_episode(one, make_policy(skill, "closed-loop", stiffness=setting(stiffness)),
                                                 s)[0]) for s in starts]
            for stiffness in (None, "constant:500")}


def setting(stiffness):
    return None if stiffness is None else StiffnessSetting.parse(stiffness)


@pytest.mark.parametrize("slots, threads, stiffness", [(3, 1, None), (6, 2, None), (2, 2, "constant:500")])
def test_lockstep_records_equal_one_at_a_time(skill, starts, alone, slots, threads, stiffness):
    envs = [env() for _ in range(slots)]
    policies = [make_policy(skill, "closed-loop", stiffness=setting(stiffness)) for _ in range(slots)]
    seen = []
    records = run_lockstep(envs, policies, starts, threads=threads, on_record=lambda r: seen.append(r.index))
    assert [without_wall(r) for r in records] == alone[stiffness]
    assert sorted(seen) == sorted(s.index for s in starts)
    assert records[2].failure == "unreachable_start"
    assert any(r["steps"] > 0 and r["peak_contact_force_n"] > 1.0 for r in alone[stiffness])  # contact reached


def test_the_batched_flow_query_equals_each_policy_s_own(skill, starts):
    """Policies at different states (different starts, different steps into their episodes) answer one batched
    query with the actions their own ``act`` gives."""
    envs = [env() for _ in range(3)]
    policies = [make_policy(skill, "closed-loop") for _ in range(3)]
    twins = [make_policy(skill, "closed-loop") for _ in range(3)]
    for i, (e, p, t) in enumerate(zip(envs, policies, twins)):
        e.reset(start_pose=starts[i + 3].pose, perturbation=starts[i + 3].perturbation)
        for q in (p, t):
            q.reset(observe(e), e.control_period_s)
        for _ in range(5 * i):  # move the episodes apart
            action = p.act(observe(e))
            t.act(observe(e))
            e.step(action.pose)
    for _ in range(3):
        batch = type(policies[0]).act_many(policies, [observe(e) for e in envs])  # the insertion's, then the flow's
        own = [t.act(observe(e)) for t, e in zip(twins, envs)]
        for a, b in zip(batch, own):
            for name in ("pose", "anchor"):
                assert np.array_equal(getattr(a, name).pos, getattr(b, name).pos)
                assert np.array_equal(getattr(a, name).quat, getattr(b, name).quat)
            for name in ("twist", "accel", "push"):
                assert np.array_equal(getattr(a, name), getattr(b, name))
            assert a.rotational_stiffness == b.rotational_stiffness
        for e, a in zip(envs, batch):
            e.step(a.pose)


class _FailsAtStep:
    """A closed-loop policy that raises at its k-th act (to end its own episode as an error)."""

    def __init__(self, inner, k):
        self.inner, self.k, self.n = inner, k, 0

    def reset(self, observation, period_s):
        self.n = 0
        self.inner.reset(observation, period_s)

    def act(self, observation):
        self.n += 1
        if self.n == self.k:
            raise RuntimeError("policy failed on purpose")
        return self.inner.act(observation)


def test_an_error_ends_only_its_own_episode(skill, starts, alone):
    envs = [env() for _ in range(2)]
    policies = [_FailsAtStep(make_policy(skill, "closed-loop"), 7), make_policy(skill, "closed-loop")]
    records = run_lockstep(envs, policies, starts[:2])  # slot 0 runs start 0, slot 1 start 1
    assert records[0].failure == "error" and "policy failed on purpose" in records[0].reason
    assert without_wall(records[1]) == alone[None][1]


def _begun_runs(skill, starts):
    """Two closed-loop episodes (starts 3 and 4) begun side by side: their envs, policies and runs."""
    envs = [env() for _ in range(2)]
    policies = [make_policy(skill, "closed-loop") for _ in range(2)]
    runs = [EpisodeRun(e, p, s) for e, p, s in zip(envs, policies, starts[3:5])]
    for run in runs:
        assert run.begin()
    return envs, policies, runs


def test_a_batched_query_that_raises_falls_back_to_each_slot(skill, starts):
    envs, _, runs = _begun_runs(skill, starts)
    envs[0].data.site_xmat[envs[0].tcp_site] = np.nan  # slot 0's measured pose becomes NaN
    envs[0]._obs = envs[0]._observe(track=False)
    actions = act_for(runs)
    assert actions[0] is None and not runs[0].running and runs[0].record.failure == "error"
    assert actions[1] is not None and runs[1].running


def test_slots_must_not_share_a_model(skill, starts):
    one = env()
    with pytest.raises(EnvError, match="share"):
        run_lockstep([one, one], [make_policy(skill, "closed-loop")] * 2, starts[:1])
    with pytest.raises(EnvError, match="one policy per environment"):
        run_lockstep([env()], [], starts[:1])


def test_an_exception_in_the_physics_ends_only_its_episode(skill, starts, alone):
    """Whatever escapes the env's physics (here a RuntimeError) is that episode's "error: ...", alone or in lockstep."""
    broken = env()

    def boom(period):
        raise RuntimeError("physics broke on purpose")

    broken.run_period = boom
    record, _ = run_episode(broken, make_policy(skill, "closed-loop"), starts[0])
    assert record.failure == "error" and "physics broke on purpose" in record.reason
    records = run_lockstep([broken, env()], [make_policy(skill, "closed-loop") for _ in range(2)], starts[:2],
                           threads=2)
    assert records[0].failure == "error" and without_wall(records[1]) == alone[None][1]


def test_a_policy_whose_own_part_fails_in_a_batched_query_ends_only_its_episode(skill, starts):
    _, policies, runs = _begun_runs(skill, starts)

    def boom(*args):
        raise RuntimeError("adaptation broke on purpose")

    policies[1].inner.adapter.update = boom  # the second: the first has already taken its step when it fails
    actions = act_for(runs)
    assert actions[1] is None and runs[1].record.failure == "error" and "on purpose" in runs[1].record.reason
    assert actions[0] is not None and runs[0].running and policies[0].inner._step == 1  # one step, not one per try
