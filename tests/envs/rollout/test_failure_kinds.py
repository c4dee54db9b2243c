"""envs.rollout.failure: a failed episode's record says what the peg did (jammed, free space, left the grasp, ...),
judged from the simulated peg, with the thresholds of FailureCriteria."""

from __future__ import annotations

import numpy as np
import pytest

from envs.cell.scene import build_scene
from envs.cell.scene_config import SceneConfig
from envs.evaluation.result import failure_kinds
from envs.policies.interface import Action, Observation
from envs.poses import Pose
from envs.rollout.episode import StartPose, run_episode
from envs.rollout.failure import FailureCriteria, ProgressWindow
from envs.sim.env import PegInHoleEnv
from envs.sim.episode_config import EpisodeConfig
from envs.task.perturbation import Perturbation


class HoldPose:
    """Move the commanded position to one pose at 20 mm/s and hold it there, with one translational stiffness (a
    policy that never adapts)."""

    def __init__(self, pose: Pose, stiffness_n_m: float) -> None:
        self.pose, self.stiffness = pose, stiffness_n_m * np.eye(3)
        self.pos = np.zeros(3)
        self.step_m = 0.0

    def reset(self, observation: Observation, period_s: float) -> None:
        self.pos, self.step_m = np.array(observation.tcp.pos), 0.02 * period_s

    def act(self, observation: Observation) -> Action:
        to_go = self.pose.pos - self.pos
        distance = float(np.linalg.norm(to_go))
        self.pos = self.pose.pos.copy() if distance <= self.step_m else self.pos + to_go * (self.step_m / distance)
        return Action(Pose(self.pos.copy(), self.pose.quat), self.stiffness)


@pytest.fixture(scope="module")
def env() -> PegInHoleEnv:
    return PegInHoleEnv(scene=build_scene(SceneConfig()), episode_config=EpisodeConfig(time_limit_s=4.0))


def _start(env: PegInHoleEnv, height_m: float, perturbation: Perturbation = Perturbation()) -> StartPose:
    return StartPose(0, -1, Pose(env.nominal_goal.pos + height_m * env.hole_axis, env.nominal_goal.quat),
                     perturbation)


def test_a_peg_held_in_the_air_times_out_in_free_space(env) -> None:
    start = _start(env, 0.06)
    record, _ = run_episode(env, HoldPose(start.pose, 1500.0), start)
    assert record.reason.startswith("time_limit") and record.failure == "free_space_timeout"


def test_a_peg_pressed_on_the_plate_beside_the_hole_is_jammed(env) -> None:
    """The real hole 4 mm from the nominal one (beyond the 1 mm chamfer): the peg pressed at the nominal goal at
    500 N/m rests on the plate at ~15 N (below the 40 N force limit) and makes no progress."""
    start = _start(env, 0.04, Perturbation(hole_dx_m=0.004))
    record, _ = run_episode(env, HoldPose(Pose(env.nominal_goal.pos, env.nominal_goal.quat), 500.0), start)
    assert record.reason.startswith("time_limit") and record.failure == "jammed"
    assert record.peak_sustained_wrist_force_n < 40.0


def test_a_hard_push_on_the_plate_is_a_force_limit(env) -> None:
    start = _start(env, 0.04, Perturbation(hole_dx_m=0.004))
    goal_below = Pose(env.nominal_goal.pos - 0.02 * env.hole_axis, env.nominal_goal.quat)
    record, _ = run_episode(env, HoldPose(goal_below, 2000.0), start)
    assert record.failure == "force_limit" and record.reason.startswith("force_limit")


def test_the_window_tells_the_kinds_apart() -> None:
    c = FailureCriteria(window_s=0.05, jam_force_n=5.0, jam_progress_m=0.0005, contact_n=1.0, grasp_slip_m=0.005)

    def judge(rows: list[tuple[float, float, float]], reason: str = "time_limit") -> str:
        window = ProgressWindow(0.01, c)
        for row in rows:
            window.add(*row)
        return window.failure(reason)

    still = [(0.001, 20.0, 0.03)] * 5
    assert judge(still) == "jammed"
    assert judge([(0.001 + 0.0002 * k, 20.0, 0.03) for k in range(5)]) == "time_limit"  # 0.8 mm of progress
    assert judge(still[:4] + [(0.001, 4.0, 0.03)]) == "time_limit"  # the load dropped below 5 N once
    assert judge(still[:3]) == "time_limit"  # shorter than the window: not judged jammed
    assert judge([(-0.02, 0.5, 0.03)] * 5) == "free_space_timeout"
    assert judge([(0.001, 20.0, 0.03)] + [(0.001, 20.0, 0.036)] * 5) == "left_grasp"  # slipped 6 mm, whatever else
    assert judge(still, "force_limit") == "force_limit"
    assert judge(still, "instability: joint speed") == "instability"
    assert judge([], "error: ValueError") == "error"


def test_failures_are_counted_by_kind() -> None:
    from envs.rollout.episode import EpisodeRecord

    records = [EpisodeRecord(0, -1, [0.0] * 3, [1.0, 0, 0, 0], reason="time_limit (depth 0.9 mm)", failure="jammed"),
               EpisodeRecord(1, -1, [0.0] * 3, [1.0, 0, 0, 0], reason="wall_timeout"),
               EpisodeRecord(2, -1, [0.0] * 3, [1.0, 0, 0, 0], success=True, reason="success")]
    assert failure_kinds(records) == {"jammed": 1, "wall_timeout": 1}
