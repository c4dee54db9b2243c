"""A pose + stiffness skill on R^3 x S^3 x SPD(3): SPD and bounded generation from 1000 starts, convergence to
the goal stiffness, reproduction of the demonstrated stiffness, checkpoints, policies, `pih train --stiffness`."""

from __future__ import annotations

import json

import mujoco
import numpy as np
import pytest

from controllers.action import Action
from controllers.impedance import CartesianImpedanceController, full_stiffness, validate_stiffness
from envs.errors import EnvError
from envs.policies.flow_skill import ClosedLoopPolicy, OpenLoopPolicy, StiffnessSetting, generate_plan
from envs.poses import Pose
from rflow.errors import RFlowError
from rflow.generate import rollout
from rflow.skill_io import POSE_STIFFNESS, fit_pose_skill, load_skill, save_skill, stiffness_reproduction
from rflow.stiffness import StiffnessBounds, log_euclidean_mean, profile_distance
from scripts.cli import main
from tests.helpers.panda_fixtures import arm_model
from tests.helpers.skill_fixtures import TINY, tiny_skill
from tests.helpers.stiffness_fixtures import (SCHEDULE, HOLE_AXIS, small_stiffness_skill, stiffness_demos,
                                              write_stiffness_demo_file)

STARTS = 1000


@pytest.fixture(scope="module")
def trained():
    return small_stiffness_skill()


def _random_starts(skill, demos, num, seed=0):
    """Points whose tangent vectors are uniform in twice the demos' tangent box (per dimension, around its centre;
    at least +-0.1 wide, so directions the demos never vary in, e.g. off-diagonal stiffness, are exercised too)."""
    model = skill.models["joint"]
    v = np.asarray(POSE_STIFFNESS.log(POSE_STIFFNESS.prepare(skill.joint_point(demos.pos, demos.quat, demos.stiffness)),
                                      model.goal)).reshape(-1, 12)
    centre, half = 0.5 * (v.max(0) + v.min(0)), np.maximum(v.max(0) - v.min(0), 0.1)
    rng = np.random.default_rng(seed)
    return np.asarray(POSE_STIFFNESS.exp(centre + rng.uniform(-1.0, 1.0, (num, 12)) * half, model.goal))


def test_generated_stiffness_is_spd_bounded_and_converges_from_1000_starts(trained):
    skill, demos = trained
    model = skill.models["joint"]
    starts = _random_starts(skill, demos, STARTS)
    transient = rollout(model, starts, steps=200, xi=1e-12)  # 200 demo steps: 10 s
    raw = skill.split_point(transient.points)[2]
    assert np.linalg.eigvalsh(raw).min() > 0.0  # SPD by construction (Exp map), before any clip
    bounded, clipped = skill.bound_stiffness(raw)
    lam = np.linalg.eigvalsh(bounded)
    assert lam.min() >= 100.0 * (1 - 1e-9) and lam.max() <= 3000.0 * (1 + 1e-9)
    print(f"eigenvalue clip acted on {100 * clipped.mean():.2f} % of {clipped.size} generated samples "
          f"({100 * clipped[:, 0].mean():.1f} % of the starts themselves)")
    late = rollout(model, transient.points[:, -1], steps=100, xi=1e-12, dt=1.0)  # then 100 s more
    final = skill.split_point(late.points[:, -1])[2]
    goal = np.broadcast_to(skill.goal_stiffness, final.shape)
    assert profile_distance(goal[:, None], final[:, None]).max() < 1e-3  # Log-Euclidean, dimensionless


def test_goal_stiffness_is_the_demos_goal_and_inside_the_bounds(trained):
    skill, demos = trained
    assert np.allclose(skill.goal_stiffness, SCHEDULE.goal_stiffness(HOLE_AXIS))
    assert not skill.bound_stiffness(skill.goal_stiffness)[1]


def test_learned_stiffness_reproduces_the_demos_better_than_any_constant_profile(trained):
    skill, demos = trained
    rec = stiffness_reproduction(skill, demos.pos, demos.quat, demos.stiffness)
    k = demos.stiffness
    constants = {"start": skill.start_stiffness, "goal": skill.goal_stiffness,
                 "Log-Euclidean mean": log_euclidean_mean(k.reshape(-1, 3, 3))}
    best = min(float(profile_distance(k, np.broadcast_to(c, k.shape)).mean()) for c in constants.values())
    print(f"mean Log-Euclidean distance {rec['log_euclidean_mean']:.3f} vs {best:.3f} for the best constant profile; "
          f"clip fraction {rec['clip_fraction']:.4f}")
    assert rec["log_euclidean_mean"] < best  # it learned how the stiffness varies, not one value


def test_checkpoint_round_trip_keeps_the_stiffness_model(trained, tmp_path):
    skill, _ = trained
    loaded = load_skill(save_skill(tmp_path / "ck", skill))
    assert loaded.has_stiffness and np.allclose(loaded.goal_stiffness, skill.goal_stiffness)
    assert loaded.stiffness_bounds == StiffnessBounds()
    x = skill.joint_point(skill.goal_pos + [0.0, 0.02, 0.1], skill.goal_quat, skill.start_stiffness)
    assert np.allclose(rollout(loaded.models["joint"], x, 20).points, rollout(skill.models["joint"], x, 20).points)


def test_pose_only_joint_skills_still_load_and_have_no_stiffness(tmp_path):
    loaded = load_skill(save_skill(tmp_path / "ck", tiny_skill("joint")))
    assert not loaded.has_stiffness and loaded.models["joint"].manifold.name == "pose"
    with pytest.raises(RFlowError):
        loaded.goal_stiffness


def test_stiffness_needs_the_joint_layout_and_bounds_that_hold_it():
    demos = stiffness_demos(n=3, m=20)
    with pytest.raises(RFlowError, match="joint"):
        fit_pose_skill(demos.pos, demos.quat, demos.dt, TINY, "separate", False, stiffness=demos.stiffness)
    with pytest.raises(RFlowError, match="outside the bounds"):
        fit_pose_skill(demos.pos, demos.quat, demos.dt, TINY, "joint", False, stiffness=demos.stiffness,
                       bounds=StiffnessBounds(500.0, 3000.0))


def test_open_loop_plan_carries_bounded_stiffness_ending_at_the_goal(trained):
    skill, demos = trained
    start = Pose(pos=demos.pos[0, 0], quat=demos.quat[0, 0])
    plan = generate_plan(skill, start, 30.0, 0.05)
    assert plan.stiffness.shape == (plan.pos.shape[0], 3, 3)
    assert np.allclose(plan.stiffness[0], skill.start_stiffness)
    assert np.allclose(plan.stiffness[-1], skill.goal_stiffness, rtol=1e-3)
    policy = OpenLoopPolicy(skill, duration_s=2.0, stiffness=StiffnessSetting.parse("learned"))
    policy.reset_at(start, 0.01)
    assert np.allclose(policy.command(0, start).stiffness, policy.plan.stiffness[1])


def test_closed_loop_integrates_the_stiffness_state_instead_of_measuring_it(trained):
    skill, demos = trained
    policy = ClosedLoopPolicy(skill, stiffness=StiffnessSetting.parse("learned"))
    start = Pose(pos=demos.pos[0, 0], quat=demos.quat[0, 0])
    policy.reset_at(start, 0.05)
    first = policy.command(0, start).stiffness
    assert np.allclose(first, skill.start_stiffness)
    plan = generate_plan(skill, start, 0.5, 0.05)
    held = policy.stiffness_state  # the first period advances one full step: nothing was asked before it
    assert not np.allclose(held, first)
    for step in range(1, 10):  # the arm does not move: no progress, so the stiffness holds
        cmd = policy.command(step, start)
    assert np.allclose(cmd.stiffness, held) and np.array_equal(policy.stiffness_state, held)
    assert np.isfinite(cmd.stiffness).all() and policy.stiffness_clipped_steps == 0
    assert plan.stiffness is not None


def test_constant_stiffness_setting_and_full_matrix():
    setting = StiffnessSetting.parse("constant:800")
    assert setting.constant_n_m == 800.0
    k = full_stiffness(800.0 * np.eye(3), 80.0)
    assert np.allclose(k, np.diag([800.0] * 3 + [80.0] * 3))
    validate_stiffness(k)
    for bad in ("constant:0", "constant:-5", "constant:nan", "constant:", "stiff", "constant:abc"):
        with pytest.raises(EnvError):
            StiffnessSetting.parse(bad)
    with pytest.raises(EnvError, match="learned"):
        ClosedLoopPolicy(tiny_skill(), stiffness=StiffnessSetting.parse("learned"))


TINY_ARGS = ["--epochs", "2", "--layers", "2", "--width", "16", "--subsample", "1", "--horizon", "5",
             "--transitions-per-epoch", "256", "--threads", "1", "--quiet"]


@pytest.mark.parametrize("source", ["expert", "variability"])
def test_pih_train_stiffness_reports_the_log_euclidean_distance(tmp_path, capsys, source):
    demos = write_stiffness_demo_file(tmp_path, n=3, m=30)
    assert main(["train", "--demos", str(demos), "--out", str(tmp_path / "ck"), "--stiffness", source, *TINY_ARGS]) == 0
    out = capsys.readouterr().out
    assert "mean Log-Euclidean distance" in out
    rec = json.loads((tmp_path / "ck" / "skill.json").read_text())["metadata"]["stiffness"]
    assert rec["source"] == source and len(rec["log_euclidean_per_demo"]) == 3
    assert load_skill(tmp_path / "ck").has_stiffness


@pytest.mark.parametrize("args,words", [(["--stiffness", "expert", "--k-min-n-m", "-1"], "--k-min-n-m"),
                                        (["--stiffness", "expert", "--k-min-n-m", "500", "--k-max-n-m", "400"], "k_min"),
                                        (["--stiffness", "expert"], "no 'stiffness'")])
def test_pih_train_stiffness_bad_input_exits_2(tmp_path, capsys, args, words):
    from tests.helpers.skill_fixtures import write_demo_file

    demos = write_demo_file(tmp_path)  # no stiffness in this file
    assert main(["train", "--demos", str(demos), "--out", str(tmp_path / "ck"), *args, *TINY_ARGS]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pih train: error:") and words in err and "\n" not in err
    assert not (tmp_path / "ck").exists()


class _Recorded(Exception):
    """Raised by the recording controller once it has recorded the stiffness of the lead."""


class _RecordingController(CartesianImpedanceController):
    """The impedance controller, recording the stiffness its pose lead is computed with (and stopping there)."""

    def lead_arguments(self, data, stiffness=None):
        self.stiffness = stiffness
        raise _Recorded


def test_feedforward_lead_uses_the_commanded_stiffness():
    model = arm_model()
    controller = _RecordingController(model, "flange")
    data = mujoco.MjData(model)
    pose = Pose(pos=np.zeros(3), quat=np.array([1.0, 0.0, 0.0, 0.0]))
    k = np.diag([300.0, 300.0, 1000.0])
    command = Action(pose, stiffness=k, twist=np.full(6, 0.01), anchor=pose)
    with pytest.raises(_Recorded):
        controller.command(data, command)
    assert np.allclose(controller.stiffness, np.diag([300.0, 300.0, 1000.0, 80.0, 80.0, 80.0]))
    assert np.allclose(controller.action_stiffness(command), controller.stiffness)
    with pytest.raises(_Recorded):
        controller.command(data, Action(pose, twist=np.full(6, 0.01), anchor=pose))
    assert controller.stiffness is controller.default_stiffness  # no stiffness: the controller's default


@pytest.mark.parametrize("spec,words", [("constant:-5", "K must be in"), ("constant:0", "K must be in"), ("soft", "learned"),
                                        ("learned", "no stiffness model")])
def test_pih_evaluate_bad_stiffness_exits_2_before_any_episode(tmp_path, capsys, spec, words):
    model = save_skill(tmp_path / "ck", tiny_skill())  # a pose skill without stiffness
    out = tmp_path / "eval.json"
    assert main(["evaluate", "--model", str(model), "--episodes", "1", "--json", str(out), "--stiffness", spec]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pih evaluate: error:") and words in err and "\n" not in err
    assert not out.exists()


def test_episode_records_the_learned_stiffness_it_commanded(trained):
    from envs.rollout.episode import StartPose, run_episode
    from envs.sim.env import PegInHoleEnv
    from envs.sim.episode_config import EpisodeConfig
    from tests.helpers.skill_fixtures import GOAL_POS, GOAL_QUAT

    skill, _ = trained
    env = PegInHoleEnv(episode_config=EpisodeConfig(time_limit_s=0.2))
    policy = ClosedLoopPolicy(skill, stiffness=StiffnessSetting.parse("learned"))
    start = StartPose(0, 0, Pose(GOAL_POS + np.array([-0.05, 0.0, 0.2]), GOAL_QUAT))
    record, trace = run_episode(env, policy, start, record_trace=True)
    assert record.steps > 1 and trace.stiffness.shape == (record.steps + 1, 3, 3)
    assert np.allclose(trace.stiffness[1], skill.bound_stiffness(skill.start_stiffness)[0])  # the first step's
    lam = np.linalg.eigvalsh(trace.stiffness[1:])
    assert (record.min_stiffness_n_m, record.max_stiffness_n_m) == pytest.approx((lam.min(), lam.max()))
    assert record.final_stiffness_eig_n_m == pytest.approx(lam[-1].tolist())
    assert not np.allclose(trace.stiffness[-1], trace.stiffness[1])  # the state was integrated, not held


def test_stiffness_figure_is_written_and_refuses_malformed_curves(tmp_path):
    from envs.media.figures import StiffnessCurve, plot_stiffness

    demos = stiffness_demos(n=2, m=20)
    curves = [StiffnessCurve(demos.dt * np.arange(20), k) for k in demos.stiffness]
    assert plot_stiffness(curves, curves[:1], tmp_path / "k.png").stat().st_size > 0
    with pytest.raises(EnvError, match="stiffness curve"):
        StiffnessCurve(np.arange(3.0), np.ones((3, 3)))


@pytest.mark.parametrize("extra,words", [(["--stiffness-figure", "k.txt"], "must end in .png"),
                                         (["--stiffness-figure", "k.png", "--figure", "k.png"], "is also --figure")])
def test_pih_evaluate_bad_stiffness_figure_exits_2_before_any_episode(tmp_path, capsys, monkeypatch, extra, words):
    monkeypatch.chdir(tmp_path)
    model = save_skill(tmp_path / "ck", tiny_skill())
    out = tmp_path / "eval.json"
    assert main(["evaluate", "--model", str(model), "--episodes", "1", "--json", str(out), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pih evaluate: error:") and words in err and "\n" not in err
    assert not out.exists() and not (tmp_path / "k.png").exists()


def test_schedule_stiffness_setting_commands_the_teachers_k_of_the_measured_height():
    """"schedule" commands the expert's K(h) at the measured pose's height above the nominal mouth (h from the
    skill's goal and the mouth depth the reset gives), free-space stiffness far above, the hole's at the goal."""
    from envs.policies.stiffness_schedule import StiffnessSchedule, expert_stiffness

    setting = StiffnessSetting.parse("schedule:2000/400/700")
    assert setting.schedule == StiffnessSchedule(2000.0, 400.0, 700.0)
    assert StiffnessSetting.parse("schedule").schedule == StiffnessSchedule()
    skill = tiny_skill()
    policy = ClosedLoopPolicy(skill, stiffness=setting)
    goal, axis = skill.goal_pos, policy.adapter.axis  # axis: the insertion direction, into the hole
    depth = 0.02
    policy.reset_at(Pose(pos=goal - 0.1 * axis, quat=skill.goal_quat), 0.01, mouth_depth_m=depth)
    far = policy.command(0, Pose(pos=goal - 0.1 * axis, quat=skill.goal_quat)).stiffness
    assert np.allclose(far, 2000.0 * np.eye(3))
    at_goal = policy.scheduled_stiffness(goal)
    assert np.allclose(at_goal, 400.0 * (np.eye(3) - np.outer(axis, axis)) + 700.0 * np.outer(axis, axis))
    mid = goal - (depth + 0.015) * axis  # 15 mm above the mouth: between h_hole = 5 mm and h_free = 30 mm
    assert np.allclose(policy.scheduled_stiffness(mid), expert_stiffness(mid, goal - depth * axis, -axis,
                                                                           setting.schedule))
    assert 700.0 < np.linalg.eigvalsh(policy.scheduled_stiffness(mid)).max() < 2000.0
    with pytest.raises(EnvError, match="nominal hole"):
        policy.reset_at(Pose(pos=goal, quat=skill.goal_quat), 0.01)
    with pytest.raises(EnvError, match="closed loop"):
        OpenLoopPolicy(skill, stiffness=setting)
    for bad in ("schedule:1/2", "schedule:a/b/c", "schedule:0/300/300", "schedule:1500/300/nan"):
        with pytest.raises(EnvError, match="stiffness 'schedule"):
            StiffnessSetting.parse(bad)


@pytest.fixture(scope="module")
def trained_beside():
    return small_stiffness_skill(layout="separate_stiffness")


@pytest.mark.slow
def test_a_stiffness_model_beside_the_pose_models_is_spd_bounded_and_leaves_the_pose_skill(trained_beside, tmp_path):
    """Layout "separate_stiffness": the pose models are the two-model skill's (the same weights as training them
    without stiffness); the stiffness model on R^3 x SPD(3) generates SPD stiffness inside the bounds from 1000
    starts and converges to the goal stiffness; the checkpoint round-trips."""
    from rflow.skill_io import POSITION_STIFFNESS
    from tests.helpers.stiffness_fixtures import SMALL

    skill, demos = trained_beside
    assert skill.layout == "separate_stiffness" and skill.has_stiffness
    plain = fit_pose_skill(demos.pos, demos.quat, demos.dt, SMALL, "separate", progress=False)
    for name in ("position", "orientation"):
        for a, b in zip(skill.models[name].network.state_dict().values(), plain.models[name].network.state_dict().values()):
            assert np.array_equal(a.numpy(), b.numpy())
    model = skill.models["stiffness"]
    v = np.asarray(POSITION_STIFFNESS.log(POSITION_STIFFNESS.prepare(skill.stiffness_point(demos.pos, demos.stiffness)),
                                          model.goal)).reshape(-1, 9)
    centre, half = 0.5 * (v.max(0) + v.min(0)), np.maximum(v.max(0) - v.min(0), 0.1)
    starts = np.asarray(POSITION_STIFFNESS.exp(centre + np.random.default_rng(0).uniform(-1, 1, (STARTS, 9)) * half,
                                               model.goal))
    raw = rollout(model, starts, steps=200, xi=1e-12).points[..., 3:].reshape(STARTS, -1, 3, 3)
    assert np.linalg.eigvalsh(raw).min() > 0.0
    lam = np.linalg.eigvalsh(skill.bound_stiffness(raw)[0])
    assert lam.min() >= 100.0 * (1 - 1e-9) and lam.max() <= 3000.0 * (1 + 1e-9)
    late = rollout(model, rollout(model, starts, 200, xi=1e-12).points[:, -1], steps=100, xi=1e-12, dt=1.0)
    final = late.points[:, -1, 3:].reshape(-1, 3, 3)
    assert profile_distance(np.broadcast_to(skill.goal_stiffness, final.shape)[:, None], final[:, None]).max() < 1e-3
    assert np.allclose(skill.goal_stiffness, demos.stiffness[0, -1])
    loaded = load_skill(save_skill(tmp_path / "ck", skill))
    assert loaded.layout == "separate_stiffness" and np.allclose(loaded.goal_stiffness, skill.goal_stiffness)
    rep = stiffness_reproduction(skill, demos.pos, demos.quat, demos.stiffness)
    assert np.isfinite(rep["log_euclidean_mean"]) and len(rep["log_euclidean_per_demo"]) == demos.pos.shape[0]


def test_the_stiffness_state_follows_the_measured_progress_not_the_clock(trained_beside):
    """Closed loop: a peg that makes the step the flow asked for advances the stiffness by one full flow step, a
    peg that makes half of it by half a step, a peg held still not at all; open loop generates K with the plan."""
    from envs.policies.flow_skill import progress_ratio, stiffness_step

    skill, demos = trained_beside
    start = Pose(pos=demos.pos[0, 0], quat=demos.quat[0, 0])
    assert progress_ratio([0.0, 0.0, 0.0], [0.0, 0.0, 1e-3]) == 0.0
    assert progress_ratio([0.0, 0.0, 5e-4], [0.0, 0.0, 1e-3]) == 0.5
    assert progress_ratio([0.0, 0.0, 3e-3], [0.0, 0.0, 1e-3]) == 1.0
    assert progress_ratio([0.0, 0.0, -1e-3], [0.0, 0.0, 1e-3]) == 0.0
    assert progress_ratio([1.0, 0.0, 0.0], [0.0, 0.0, 1e-9]) == 1.0  # nothing asked (at the goal)
    for fraction in (1.0, 0.5, 0.0):
        policy = ClosedLoopPolicy(skill, stiffness=StiffnessSetting.parse("learned"))
        policy.reset_at(start, 0.01)
        first = policy.command(0, start)
        k1 = policy.stiffness_state
        assert np.allclose(k1, stiffness_step(skill, start.pos, start.quat, skill.start_stiffness, 0.01))
        moved = Pose(pos=start.pos + fraction * first.twist[:3] * 0.01, quat=start.quat)
        policy.command(1, moved)
        if fraction == 0.0:
            assert np.array_equal(policy.stiffness_state, k1)
        else:
            expected = stiffness_step(skill, moved.pos, moved.quat, k1, fraction * 0.01)
            assert np.allclose(policy.stiffness_state, expected, rtol=1e-9, atol=1e-9)
    plan = generate_plan(skill, start, 2.0, 0.01)
    assert plan.stiffness is not None and np.allclose(plan.stiffness[0], skill.start_stiffness)
