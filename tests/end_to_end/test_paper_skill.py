"""End to end: scripted demos -> small RiemannianFlow skill -> closed-loop insertions scored by physics, in the
paper's setting (the "paper" task preset: grasped peg, 1 mm clearance, the hole where the demos ended; seated
within 1 mm, inside the walls, at rest), and envs.statistics.regression.assert_no_regression on it: the skill passes
against itself and a time-starved run of it is flagged. Every test of the session's paper_checkpoint lives in this file,
so one xdist worker trains it, once (tests/conftest.py).

Small on purpose (7 demos of 400 samples instead of 4000, 40 epochs instead of 80, 20 starts in each mode
from the issue's default region, +-5 cm / +-15 deg around the mean demo start) so it runs in about a minute
on 2 cores; the full-size figures come from `pih run` / `pih evaluate`. (Margin when written: 20 of 20 in
both modes for start seeds 1, 2 and 3; without the off-data prior, 18-19 of 20.)
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from envs.evaluation.evaluate import EvaluationConfig, evaluate
from envs.statistics.regression import assert_no_regression
from envs.task.task import preset
from rflow.skill_io import load_skill, save_skill

pytestmark = pytest.mark.slow  # trains a model (the paper_checkpoint fixture of conftest.py) and runs physics episodes

GOAL_SHIFT_M = np.array([0.0, 0.03, 0.0])
PAPER = preset("paper")


@pytest.mark.parametrize("mode", ["closed-loop", "open-loop"])
def test_small_skill_inserts_from_perturbed_starts(paper_checkpoint, mode):
    config = EvaluationConfig(episodes=20, seed=1, mode=mode, workers=2, task=PAPER)
    assert (config.task.start.pos_range_m, config.task.start.rot_range_deg) == (0.05, 15.0)
    result = evaluate(paper_checkpoint, config, progress=False)
    failures = [r.reason for r in result.records if not r.success]
    assert result.success_rate >= 0.9, failures
    assert not any(reason.startswith("error") for reason in failures)


def test_goal_shifted_skill_is_scored_as_failing(paper_checkpoint, tmp_path):
    """The same skill with its position goal moved 3 cm sideways ends on the sorter's top face: no success."""
    skill = load_skill(paper_checkpoint)
    skill.models["position"].goal = skill.models["position"].goal + GOAL_SHIFT_M
    shifted = save_skill(tmp_path / "shifted", skill)
    config = EvaluationConfig(episodes=4, seed=1, workers=2,
                              task=PAPER.override(pos_range_m=0.02, rot_range_deg=5.0, time_limit_s=8.0))
    result = evaluate(shifted, config, progress=False)
    assert result.num_success == 0
    assert all(r.final_pos_error_mm > 20.0 for r in result.records)


def test_a_skill_that_follows_the_measured_hole_seats_where_the_bare_flow_misses(paper_checkpoint):
    """The hole 3-4 mm and up to 1 deg off the demos' (1 mm clearance, no chamfer), the contact adaptation off: the
    bare flow lands beside it; run in the frame of the hole a sensor measured (without error), it seats."""
    from envs.evaluation.starts import evaluation_starts
    from envs.task.perturbation import Perturbation

    task = PAPER.override(hole_observation="measured", pos_range_m=0.02, rot_range_deg=5.0, time_limit_s=15.0)
    config = EvaluationConfig(episodes=4, seed=1, workers=2, task=task, contact_adaptation=False)
    errors = [Perturbation(hole_dx_m=0.003 * np.cos(a), hole_dy_m=0.004 * np.sin(a), hole_yaw_deg=yaw, hole_tilt_deg=0.5,
                           hole_tilt_dir_deg=90.0 * i) for i, (a, yaw) in enumerate(zip((0.3, 1.9, 3.5, 5.1),
                                                                                     (1.0, -1.0, 0.5, -0.5)))]
    starts = [dataclasses.replace(start, perturbation=error) for start, error in zip(
        evaluation_starts(load_skill(paper_checkpoint).metadata["demo_starts"], config), errors)]
    blind = evaluate(paper_checkpoint, config, progress=False, starts=starts)
    following = evaluate(paper_checkpoint, dataclasses.replace(config, follow_observed_hole=True), progress=False,
                         starts=starts)
    assert blind.num_success == 0
    assert following.num_success == 4, [r.reason[:120] for r in following.records]


def test_a_trained_skill_passes_against_itself_and_a_time_starved_run_is_flagged(paper_checkpoint):
    """Six episodes of the small paper-preset skill (tests/conftest.py) twice, then with half the shortest
    insertion time as the time limit: every episode the base seated fails, which the check must flag."""
    config = EvaluationConfig(episodes=6, seed=1, workers=2, task=preset("paper"))
    base = evaluate(paper_checkpoint, config, progress=False)
    assert base.num_success >= 5  # the helper needs 5 discordant pairs to flag anything at alpha 0.05
    assert_no_regression(base, evaluate(paper_checkpoint, config, progress=False))
    shortest = min(r.time_to_insert_s for r in base.records if r.success)
    starved_task = config.task.override(time_limit_s=0.5 * shortest)
    starved = evaluate(paper_checkpoint, dataclasses.replace(config, task=starved_task), progress=False)
    with pytest.raises(AssertionError, match="regression"):
        assert_no_regression(base, starved)
