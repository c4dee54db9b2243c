"""envs.statistics.regression.assert_no_regression on physics: a small trained skill (the paper_checkpoint fixture of
tests/conftest.py) passes against itself and a time-starved run of it is flagged."""

from __future__ import annotations

import dataclasses

import pytest

from envs.evaluation.evaluate import EvaluationConfig, evaluate
from envs.statistics.regression import assert_no_regression
from envs.task.task import preset

pytestmark = pytest.mark.slow  # trains a model (paper_checkpoint) and runs 18 physics episodes


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
