"""envs.statistics.regression.assert_no_regression: passes the same records, fails a degraded candidate with a
readable message (on physics, with a trained skill: tests/end_to_end/test_paper_skill.py)."""

from __future__ import annotations

import json

import pytest

from envs.errors import EnvError
from envs.evaluation.config import EvaluationConfig
from envs.evaluation.result import EvaluationResult
from envs.rollout.episode import record_from_dict
from envs.statistics.regression import assert_no_regression
from tests.helpers.evaluation_fixtures import synthetic_evaluation

EPISODES = 60
BASE = [i != 3 for i in range(EPISODES)]
DEGRADED = [i % 6 != 0 for i in range(EPISODES)]


def test_the_same_records_pass():
    evaluation = synthetic_evaluation(BASE)
    assert assert_no_regression(evaluation, evaluation).decision == "no regression"


def test_a_degraded_candidate_fails_with_rates_counts_and_p_value():
    with pytest.raises(AssertionError) as err:
        assert_no_regression(synthetic_evaluation(BASE), synthetic_evaluation(DEGRADED))
    message = str(err.value)
    for part in ("regression", "83.3 % (50/60)", "98.3 % (59/60)", "base only 10", "candidate only 1", "McNemar"):
        assert part in message


def test_a_margin_larger_than_the_drop_passes():
    assert_no_regression(synthetic_evaluation(BASE), synthetic_evaluation(DEGRADED), margin=0.5)


def test_paths_dicts_and_results_are_the_same_input(tmp_path):
    data = synthetic_evaluation(DEGRADED)
    path = tmp_path / "cand.json"
    path.write_text(json.dumps(data))
    result = EvaluationResult(EvaluationConfig(episodes=EPISODES), [record_from_dict(r) for r in data["per_episode"]],
                              1.0, scene={"insertion_depth_m": 0.03})
    outcomes = [assert_no_regression(synthetic_evaluation(BASE), c, margin=0.5).to_dict()["success"]
                for c in (data, path, result)]
    assert outcomes[0] == outcomes[1] == outcomes[2]


def test_evaluations_of_other_episodes_are_an_input_error_not_a_failure():
    with pytest.raises(EnvError, match="start_pos differs"):
        assert_no_regression(synthetic_evaluation(BASE), synthetic_evaluation(BASE, seed=1))
