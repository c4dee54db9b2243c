"""envs.evaluation.evaluate: start sampling, episode records and the batch runner (tiny skills)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from envs.errors import EnvError
from envs.evaluation.evaluate import (
    EpisodeRecord,
    EvaluationConfig,
    StartPose,
    _failed_unit,
    evaluate,
    run_episode,
    scene_config_for,
)
from envs.evaluation.result import EvaluationResult
from envs.evaluation.starts import sample_starts
from envs.policies.flow_skill import ClosedLoopPolicy, StiffnessSetting
from envs.poses import Pose, quat_angle_rad
from envs.sim.env import PegInHoleEnv
from envs.sim.episode_config import EpisodeConfig
from envs.statistics.fixed_sample import wilson_interval
from envs.task.perturbation import Perturbation
from envs.task.task import Task
from rflow.skill_io import save_skill
from tests.helpers.skill_fixtures import GOAL_POS, GOAL_QUAT, tiny_skill


@pytest.fixture(scope="module")
def skill():
    return tiny_skill()


@pytest.fixture(scope="module")
def env():
    return PegInHoleEnv(episode_config=EpisodeConfig(time_limit_s=0.2))


def test_starts_depend_only_on_the_seed():
    p, q = GOAL_POS[None] + [[0, 0, 0.2]], GOAL_QUAT[None]
    a = sample_starts(p, q, 5, 7, 0.05, 15.0)
    b = sample_starts(p, q, 5, 7, 0.05, 15.0)
    assert all(np.array_equal(x.pose.pos, y.pose.pos) for x, y in zip(a, b))


def test_starts_stay_in_the_perturbation_range():
    p, q = GOAL_POS[None] + [[0, 0, 0.2]], GOAL_QUAT[None]
    starts = sample_starts(p, q, 200, 0, 0.05, 15.0)
    offsets = np.array([s.pose.pos for s in starts]) - p[0]
    angles = np.rad2deg([quat_angle_rad(s.pose.quat, GOAL_QUAT) for s in starts])
    assert np.abs(offsets).max() <= 0.05 and angles.max() <= 15.0 + 1e-9


def test_starts_around_demos_use_every_demo():
    p = GOAL_POS[None] + np.array([[0, 0, 0.2], [0.05, 0, 0.2], [0, 0.05, 0.2]])
    starts = sample_starts(p, np.tile(GOAL_QUAT, (3, 1)), 60, 0, 0.0, 0.0, around="demo")
    assert {s.demo_index for s in starts} == {0, 1, 2}


def test_starts_around_the_mean_are_centred_on_it():
    p = GOAL_POS[None] + np.array([[0, 0, 0.2], [0.06, 0, 0.2], [0, 0.06, 0.2]])
    starts = sample_starts(p, np.tile(GOAL_QUAT, (3, 1)), 5, 0, 0.0, 0.0, around="mean")
    assert all(np.allclose(s.pose.pos, p.mean(axis=0)) for s in starts)


def test_config_rejects_an_unknown_mode():
    with pytest.raises(EnvError):
        EvaluationConfig(mode="teleport")


@pytest.mark.parametrize("kwargs", [{"adaptation_off": ("push",)}, {"contact_adaptation": False}])
def test_config_rejects_an_adaptation_ablation_of_the_open_loop(kwargs):
    """The contact adaptation is part of the closed loop: turning it off in open loop would run and mean nothing."""
    with pytest.raises(EnvError, match="part of the closed loop"):
        EvaluationConfig(mode="open-loop", **kwargs)
    EvaluationConfig(mode="closed-loop", **kwargs)  # where it exists it may be turned off


def test_scene_of_another_shape_is_an_error():
    with pytest.raises(EnvError, match="trained on 'triangle'"):
        scene_config_for({"shape": "triangle"}, EvaluationConfig(task=Task(shape="square")), Pose(GOAL_POS, GOAL_QUAT))


def test_scene_takes_the_demos_clearance():
    config = scene_config_for({"shape": "square", "clearance_m": 0.0005}, EvaluationConfig(), Pose(GOAL_POS, GOAL_QUAT))
    assert config.clearance_m == 0.0005


def test_scene_takes_the_tasks_pads_whatever_the_demos_had():
    config = scene_config_for({"shape": "square", "scene": {"grasp_force_n": 70.0}},
                              EvaluationConfig(task=Task(pad_stiffness_nm_rad=67.4)), Pose(GOAL_POS, GOAL_QUAT))
    assert config.pad_stiffness_nm_rad == 67.4


def test_unreachable_start_is_recorded_not_raised(skill, env):
    far = StartPose(0, 0, Pose(np.array([2.0, 0.0, 0.5]), GOAL_QUAT))
    record, _ = run_episode(env, ClosedLoopPolicy(skill), far)
    assert not record.success and record.reason.startswith("unreachable start")


class _Exploding:
    def reset(self, observation, period_s: float) -> None:
        pass

    def act(self, observation) -> None:
        raise ValueError("boom")


def test_exception_inside_an_episode_is_recorded(env):
    start = StartPose(0, 0, Pose(GOAL_POS + np.array([-0.05, 0.0, 0.2]), GOAL_QUAT))
    record, _ = run_episode(env, _Exploding(), start)
    assert record.reason.startswith("error: ValueError: boom")


def test_time_limit_failure_reports_the_final_pose(skill, env):
    start = StartPose(0, 0, Pose(GOAL_POS + np.array([-0.05, 0.0, 0.2]), GOAL_QUAT))
    record, trace = run_episode(env, ClosedLoopPolicy(skill), start, record_trace=True)
    assert record.reason.startswith("time_limit") and record.final_pos_error_mm > 100.0
    assert trace is not None and trace.pos.shape[0] == record.steps + 1


def test_trace_records_the_robot_signals_of_every_row(skill, env):
    start = StartPose(0, 0, Pose(GOAL_POS + np.array([-0.05, 0.0, 0.2]), GOAL_QUAT))
    record, trace = run_episode(env, ClosedLoopPolicy(skill), start, record_trace=True)
    last = env.observation
    rows = record.steps + 1
    assert trace.qpos.shape == trace.qvel.shape == (rows, 7) and trace.wrist_wrench.shape == (rows, 6)
    np.testing.assert_array_equal(trace.qpos[-1], last.qpos)
    np.testing.assert_array_equal(trace.wrist_wrench[-1], last.wrist_wrench)
    np.testing.assert_array_equal(np.concatenate([trace.tcp_pos[-1], trace.tcp_quat[-1]]),
                                  np.concatenate([last.tcp.pos, last.tcp.quat]))
    assert trace.success.dtype == bool and trace.success[-1] == record.success


def test_an_episode_without_a_record_keeps_its_perturbation():
    start = StartPose(3, -1, Pose(GOAL_POS, GOAL_QUAT), Perturbation(hole_dx_m=0.0005, hole_yaw_deg=0.7))
    assert _failed_unit("3", start, "worker_died")["perturbation"] == start.perturbation.to_dict()


def test_record_json_has_no_nan():
    text = json.dumps(EpisodeRecord(0, 0, [0.0] * 3, [1.0, 0, 0, 0]).to_dict(), allow_nan=False)
    assert '"final_pos_error_mm": null' in text


def test_result_json_holds_rate_and_interval(tmp_path):
    records = [EpisodeRecord(i, 0, [0.0] * 3, [1.0, 0, 0, 0], success=i < 3) for i in range(4)]
    path = EvaluationResult(EvaluationConfig(episodes=4), records, 1.0).save_json(tmp_path / "e.json")
    data = json.loads(path.read_text())
    assert data["success_rate"] == 0.75 and data["success_rate_ci95"] == list(wilson_interval(3, 4))


@pytest.mark.slow
def test_batch_keeps_order_and_count_with_two_workers(skill, tmp_path):
    save_skill(tmp_path / "ck", skill)
    config = EvaluationConfig(episodes=3, task=Task(time_limit_s=0.05), workers=2)
    result = evaluate(tmp_path / "ck", config, progress=False)
    assert [r.index for r in result.records] == [0, 1, 2]


@pytest.mark.parametrize("setting", [None, "constant:600"])
def test_episode_records_the_commanded_stiffness(skill, env, setting):
    policy = ClosedLoopPolicy(skill, stiffness=None if setting is None else StiffnessSetting.parse(setting))
    expected = env.controller.config.translational_stiffness if setting is None else 600.0
    start = StartPose(0, 0, Pose(GOAL_POS + np.array([-0.05, 0.0, 0.2]), GOAL_QUAT))
    record, trace = run_episode(env, policy, start, record_trace=True)
    assert (record.min_stiffness_n_m, record.max_stiffness_n_m) == pytest.approx((expected, expected))
    assert record.final_stiffness_eig_n_m == pytest.approx([expected] * 3)
    assert trace.stiffness.shape == (trace.pos.shape[0], 3, 3) and np.allclose(trace.stiffness, expected * np.eye(3))


def test_learned_stiffness_result_reports_the_demos_reproduction():
    metadata = {"stiffness": {"source": "expert", "log_euclidean_mean": 0.25, "log_euclidean_per_demo": [0.2, 0.3],
                              "clip_fraction": 0.0}}
    records = [EpisodeRecord(0, 0, [0.0] * 3, [1.0, 0, 0, 0], min_stiffness_n_m=300.0, max_stiffness_n_m=1500.0)]
    learned = EvaluationResult(EvaluationConfig(episodes=1, stiffness="learned"), records, 1.0, metadata=metadata)
    data = learned.to_dict()
    assert data["stiffness_reproduction"]["log_euclidean_mean"] == 0.25
    assert (data["statistics"]["min_stiffness_n_m"], data["statistics"]["max_stiffness_n_m"]) == (300.0, 1500.0)
    assert "Log-Euclidean" in learned.summary_table() and "0.250" in learned.summary_table()
    constant = EvaluationResult(EvaluationConfig(episodes=1, stiffness="constant:500"), records, 1.0, metadata=metadata)
    assert constant.to_dict()["stiffness_reproduction"] is None and "Log-Euclidean" not in constant.summary_table()


def test_summary_says_what_the_force_limit_measures():
    records = [EpisodeRecord(0, 0, [0.0] * 3, [1.0, 0, 0, 0], success=True, peak_wrist_force_n=55.0,
                             peak_sustained_wrist_force_n=22.0)]
    table = EvaluationResult(EvaluationConfig(episodes=1), records, 1.0).summary_table()
    line = next(row for row in table.splitlines() if row.startswith("force limit"))
    assert "40 N on the wrist force held for 5 ms" in line and "peaks may exceed it" in line and "22.0 N" in line
