"""A success-rate regression check for a user's own test suite.

    from envs.statistics.regression import assert_no_regression

    def test_my_change_keeps_insertion():
        assert_no_regression("runs/base_eval.json", "runs/new_eval.json", margin=0.02)

Both evaluations must have run the same episodes (`pih evaluate` with the same --seed, --episodes and start /
task options): the check pairs them by episode and fails when the candidate's success rate is shown lower than
the base's by more than ``margin`` (envs.statistics.comparison, envs.statistics.fixed_sample).
"""

from __future__ import annotations

from typing import Any

from envs.statistics.comparison import Comparison, compare_evaluations, load_evaluation
from envs.statistics.fixed_sample import DECISIONS


def assert_no_regression(base: Any, candidate: Any, margin: float = 0.0, alpha: float = 0.05) -> Comparison:
    """Fail when the candidate regresses against the base.

    Tested: H0 p_c - p_b >= -margin (success rates of the candidate and the base on the paired episodes) against
    H1 p_c - p_b < -margin at level ``alpha``; the check fails when the one-sided (1 - alpha) upper confidence
    bound of p_c - p_b (Newcombe's paired interval) lies below -margin.

    Args:
        base, candidate: evaluation JSON paths, their dicts, or EvaluationResults.
        margin: the drop in success rate tolerated (0.02 = 2 points), in [0, 1).
        alpha: the probability of failing although the candidate is not worse by more than the margin.

    Returns:
        The Comparison (rates, paired counts, p-values, finer metrics), for further checks.

    Raises:
        AssertionError: the candidate regresses; the message gives the rates, paired counts and McNemar's p.
        EnvError: an input that is not an evaluation, or evaluations whose episodes do not pair.
    """
    comparison = compare_evaluations(load_evaluation(base, "base"), load_evaluation(candidate, "candidate"),
                                     margin, alpha)
    if comparison.decision == DECISIONS[0]:
        raise AssertionError(comparison.message())
    return comparison


__all__ = ["assert_no_regression"]
