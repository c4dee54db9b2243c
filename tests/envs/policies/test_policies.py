"""The Policy protocol (envs.policies.interface): what a policy sees, and the scripted expert and the replay
policy scored by the same episode loop as the skill."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from envs.demos.record import collect_demos
from envs.errors import EnvError
from envs.policies.expert import ScriptedExpertPolicy
from envs.policies.expert_plan import ExpertConfig, plan_expert_path
from envs.policies.interface import Action, Observation, is_policy, observe, policy_task
from envs.policies.replay import ReplayPolicy
from envs.poses import Pose, quat_angle_rad
from envs.rollout.episode import StartPose, run_episode
from envs.sim.env import PegInHoleEnv
from envs.sim.episode_config import EpisodeConfig
from envs.task.perturbation import Perturbation, PerturbationRanges, sample_perturbation

HOLE_ERROR = PerturbationRanges(hole_error_m=0.001, hole_error_deg=1.0)


@pytest.fixture(scope="module")
def env() -> PegInHoleEnv:
    return PegInHoleEnv(episode_config=EpisodeConfig(time_limit_s=12.0, perturbations=HOLE_ERROR))


class _Probe:
    """Keeps every observation it is given and holds the start pose."""

    def reset(self, observation: Observation, period_s: float) -> None:
        self.seen = [observation]

    def act(self, observation: Observation) -> Action:
        self.seen.append(observation)
        return Action(self.seen[0].tcp)


def test_a_policy_sees_the_nominal_hole_and_the_truth_only_when_privileged(env) -> None:
    perturbation = Perturbation(hole_dx_m=0.0008, hole_yaw_deg=0.9)
    start = StartPose(0, -1, env.nominal_start(), perturbation)
    probe = _Probe()
    run_episode(env, probe, start)
    obs = probe.seen[-1]
    assert np.allclose(obs.nominal_hole.pos, env.nominal_hole.pos)
    assert np.linalg.norm(env.hole.pos - obs.nominal_hole.pos) > 7e-4  # the hole moved 0.8 mm; the policy is not told
    assert all(o.privileged is None for o in probe.seen)
    assert not {"peg_tip", "insertion", "hole", "inserted", "success", "contact_force_n"} & {
        f.name for f in dataclasses.fields(Observation)}
    run_episode(env, probe, start, privileged=True)
    truth = probe.seen[0].privileged
    assert np.array_equal(truth.hole.pos, env.hole.pos) and np.array_equal(truth.goal.pos, env.goal.pos)


def test_is_policy_wants_an_instance_with_reset_and_act() -> None:
    replay = ReplayPolicy([0.0, 1.0], np.zeros((2, 3)), np.tile([1.0, 0.0, 0.0, 0.0], (2, 1)))
    assert is_policy(replay) and is_policy(ScriptedExpertPolicy()) and is_policy(_Probe())
    assert not is_policy(ReplayPolicy) and not is_policy({"reset": 1, "act": 2}) and not is_policy(None)


def test_an_action_that_is_not_an_action_ends_the_episode_as_an_error(env) -> None:
    class Wrong(_Probe):
        def act(self, observation: Observation) -> tuple:
            return (observation.tcp.pos, observation.tcp.quat)

    record, _ = run_episode(env, Wrong(), StartPose(0, -1, env.nominal_start()))
    assert record.reason.startswith("error: ActionError: Wrong.act returned a tuple, not an Action")


def test_the_expert_is_a_privileged_teacher(env) -> None:
    record, _ = run_episode(env, ScriptedExpertPolicy(), StartPose(0, -1, env.nominal_start()))
    assert not record.success and "privileged teacher" in record.reason


def test_the_privileged_expert_seats_the_peg_in_the_displaced_hole(env) -> None:
    rng = np.random.default_rng(4)
    expert = ScriptedExpertPolicy()
    for index in range(2):
        start = StartPose(index, -1, env.sample_start(rng), sample_perturbation(HOLE_ERROR, rng))
        record, _ = run_episode(env, expert, start, privileged=True)
        assert record.success, record.reason
        assert np.allclose(expert.plan_pos[-1], env.goal.pos) and not np.allclose(env.goal.pos, env.nominal_goal.pos)


def test_the_expert_follows_a_plan_it_is_given(env) -> None:
    """`pih demos` plans from the requested start and hands the plan over: the expert commands it as it is."""
    start = env.nominal_start()
    env.reset(start_pose=start, perturbation=Perturbation())
    times = env.control_period_s * np.arange(1, 201)
    plan = plan_expert_path(start, env.hole.pos, env.hole_axis, env.goal, ExpertConfig(), times)
    expert = ScriptedExpertPolicy(plan=plan)
    expert.reset(observe(env, privileged=True), env.control_period_s)
    actions = [expert.act(observe(env, privileged=True)) for _ in range(3)]
    assert all(np.array_equal(a.pose.pos, plan[0][k]) for k, a in enumerate(actions))
    assert actions[1].twist is not None and actions[1].stiffness.shape == (3, 3)
    with pytest.raises(EnvError, match="expert plan"):
        ScriptedExpertPolicy(plan=(plan[0], plan[1][:-1]))


def test_a_replay_starts_at_the_measured_pose_and_joins_the_recording_after_the_blend(env) -> None:
    times = np.linspace(0.0, 2.0, 21)
    rec_pos = env.nominal_goal.pos + np.array([0.0, 0.0, 0.1]) * (1.0 - times / 2.0)[:, None]
    rec_quat = np.tile(env.nominal_goal.quat, (21, 1))
    policy = ReplayPolicy(times, rec_pos, rec_quat, blend_s=1.0)
    start = Pose(pos=rec_pos[0] + np.array([0.02, -0.01, 0.0]), quat=env.nominal_start().quat)
    obs = dataclasses.replace(observe_at(env, start), time_s=0.0)
    policy.reset(obs, 0.01)
    first = policy.act(obs)
    assert np.linalg.norm(first.pose.pos - start.pos) < 1e-3 and quat_angle_rad(first.pose.quat, start.quat) < 1e-3
    k = 150  # t = 1.51 s, past the blend
    assert np.allclose(policy.cmd_pos[k], rec_pos[0] + (rec_pos[-1] - rec_pos[0]) * (k + 1) * 0.01 / 2.0, atol=1e-12)
    for _ in range(400):
        last = policy.act(obs)
    assert np.allclose(last.pose.pos, rec_pos[-1]) and not np.any(last.twist)


def test_a_replay_without_feedforward_reaches_its_final_pose(env) -> None:
    start = Pose(env.nominal_goal.pos + np.array([0.0, 0.0, 0.05]), env.nominal_goal.quat)
    s = np.linspace(0.0, 1.0, 30)[:, None]
    end = start.pos + [0.0, 0.03, 0.0]
    policy = ReplayPolicy(0.02 * np.arange(30), start.pos + s * (end - start.pos), np.tile(start.quat, (30, 1)),
                          feedforward=False)
    record, trace = run_episode(env, policy, StartPose(0, -1, start), record_trace=True, max_steps=108)
    assert record.steps == 108 and not record.success  # 0.58 s of replay, then its last pose held for 0.5 s
    assert np.linalg.norm(trace.tcp_pos[-1] - end) < 1e-3
    assert np.array_equal(trace.cmd_pos[-1], trace.cmd_pos[-50])


def observe_at(env: PegInHoleEnv, pose: Pose) -> Observation:
    """An observation of ``env`` at ``pose`` (reset there)."""
    env.reset(start_pose=pose, perturbation=Perturbation())
    return observe(env)


def test_a_short_recording_is_refused() -> None:
    with pytest.raises(EnvError, match="strictly increasing"):
        ReplayPolicy([0.0, 0.0], np.zeros((2, 3)), np.tile([1.0, 0.0, 0.0, 0.0], (2, 1)))
    with pytest.raises(EnvError, match=r"\(K, 3, 3\)"):
        ReplayPolicy([0.0, 1.0], np.zeros((2, 3)), np.tile([1.0, 0.0, 0.0, 0.0], (2, 1)), stiffness=np.eye(3))


def test_replaying_a_demo_from_its_start_seats_the_peg() -> None:
    """A demo's measured poses and commanded stiffness, replayed in the nominal scene by the episode loop."""
    demos = collect_demos(1, seed=2, expert=ExpertConfig(num_samples=400)).demos
    env = PegInHoleEnv(episode_config=EpisodeConfig(time_limit_s=10.0))
    times = demos.dt * np.arange(demos.num_samples)
    policy = ReplayPolicy(times, demos.pos[0], demos.quat[0], demos.stiffness[0])
    start = Pose(pos=demos.pos[0, 0], quat=demos.quat[0, 0])
    record, trace = run_episode(env, policy, StartPose(0, 0, start), record_trace=True)
    assert record.success, record.reason
    assert np.allclose(trace.stiffness[1], demos.stiffness[0, 1], rtol=0.05)  # the demo's stiffness was commanded
    task = policy_task(env)
    assert task.control_period_s == env.control_period_s and task.nominal_goal is env.nominal_goal


def test_in_the_realistic_cell_a_policy_sees_neither_the_true_hole_nor_the_peg_in_the_hand() -> None:
    """The realistic preset moves the hole and the peg in the hand: the observation's tcp is the arm's kinematic tcp
    (the nominal peg tip), not the peg's own tip, and its hole is the believed one, not the true one; no field is
    the truth."""
    from envs.task.task import preset

    task = preset("realistic")
    env = PegInHoleEnv(scene_config=task.scene_config(),
                       episode_config=dataclasses.replace(EpisodeConfig.from_task(task), time_limit_s=1.0))
    perturbation = Perturbation(hole_dx_m=0.0008, hole_yaw_deg=0.9, grasp_lateral_m=0.0009, grasp_tilt_deg=0.9,
                                grasp_yaw_deg=0.8, observed_hole_dx_m=-0.0005)
    probe = _Probe()
    run_episode(env, probe, StartPose(0, -1, env.nominal_start(), perturbation))
    tcp_site = env.data.site_xpos[env.tcp_site]
    tip = env.data.site_xpos[env.peg_tip_site]
    obs = probe.seen[-1]
    assert np.allclose(obs.tcp.pos, tcp_site) and np.linalg.norm(tip - tcp_site) > 1e-3  # the tip is 1+ mm away
    assert np.linalg.norm(env.hole.pos - obs.nominal_hole.pos) > 7e-4 and obs.privileged is None
    values = [np.asarray(getattr(obs, f.name).pos) for f in dataclasses.fields(Observation)
              if isinstance(getattr(obs, f.name), Pose)]
    assert not any(np.allclose(v, env.hole.pos, atol=1e-5) or np.allclose(v, tip, atol=1e-5) for v in values)
