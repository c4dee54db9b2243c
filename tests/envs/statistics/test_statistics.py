"""envs.statistics.fixed_sample, .sequential and .pairing: Wilson interval, paired success comparison, finer metrics,
the sequential e-processes, the pairing of records, and their error rates, power and coverage on synthetic
Bernoulli pairs (fixed seeds)."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from envs.errors import EnvError
from envs.statistics.fixed_sample import (
    PairedCounts,
    compare_metric,
    compare_success,
    mcnemar_exact,
    noninferiority_decision,
    paired_difference_interval,
    unpaired_exact_test,
    wilson_interval,
)
from envs.statistics.pairing import pair_records
from envs.statistics.sequential import SequentialComparison, SequentialPairedTest, betting_log_wealth

ALPHA = 0.05
SIMULATIONS = 2000
SLACK = 0.015  # three Monte Carlo standard deviations of a rate near 0.05 over 2000 simulations
NULL = (0.85, 0.05, 0.05, 0.05)  # both, base only, candidate only, neither: equal rates 0.90, correlated pairs
WORSE = (0.89, 0.06, 0.01, 0.04)  # base 0.95, candidate 0.90: 5 points worse, correlated pairs


def score_interval(k: int, n: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """The Wilson score equation written out (the reference for the scipy-based interval)."""
    p = k / n
    centre, half = p + z * z / (2 * n), z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return max(0.0, (centre - half) / (1 + z * z / n)), min(1.0, (centre + half) / (1 + z * z / n))


def simulated_tables(probs: tuple[float, ...], pairs: int, seed: int = 0) -> list[PairedCounts]:
    return [PairedCounts(*map(int, t)) for t in np.random.default_rng(seed).multinomial(pairs, probs, SIMULATIONS)]


def simulated_differences(probs: tuple[float, ...], pairs: int, seed: int = 0) -> np.ndarray:
    """(SIMULATIONS, pairs) paired success differences s_c - s_b."""
    kind = np.random.default_rng(seed).choice(4, size=(SIMULATIONS, pairs), p=probs)
    return np.select([kind == 1, kind == 2], [-1.0, 1.0], 0.0)


@functools.lru_cache(maxsize=None)
def decision_and_interval(counts: PairedCounts) -> tuple[str, tuple[float, float], float]:
    """The batch decision (margin 0), the 95 % Newcombe interval and McNemar's p of "candidate worse" of a table
    (cached: simulations repeat tables)."""
    decision = noninferiority_decision(paired_difference_interval(counts, 1.0 - 2.0 * ALPHA), 0.0)
    return decision, paired_difference_interval(counts, 0.95), mcnemar_exact(counts)[1]


# ------------------------------------------------------------------------------------------ Wilson


def test_wilson_interval_equals_the_score_formula_on_a_grid():
    worst = max(max(abs(a - b) for a, b in zip(wilson_interval(k, n), score_interval(k, n)))
                for n in range(1, 41) for k in range(n + 1))
    assert worst < 1e-12


def test_wilson_interval_of_half():
    low, high = wilson_interval(5, 10)
    assert math.isclose(low, 0.2366, abs_tol=1e-4) and math.isclose(high, 0.7634, abs_tol=1e-4)


def test_wilson_interval_of_all_successes_excludes_one_below():
    low, high = wilson_interval(100, 100)
    assert math.isclose(low, 0.9630, abs_tol=1e-4) and high == 1.0


def test_wilson_interval_of_no_trials_is_the_unit_interval():
    assert wilson_interval(0, 0) == (0.0, 1.0)


@pytest.mark.parametrize("k, n, confidence", [(3, 2, 0.95), (-1, 5, 0.95), (1, -1, 0.95), (1, 5, 1.0)])
def test_wilson_interval_rejects_bad_input(k, n, confidence):
    with pytest.raises(EnvError):
        wilson_interval(k, n, confidence)


def test_a_higher_confidence_widens_the_wilson_interval():
    narrow, wide = wilson_interval(7, 20, 0.8), wilson_interval(7, 20, 0.99)
    assert wide[0] < narrow[0] and wide[1] > narrow[1]


# ------------------------------------------------------------------------------------------ paired success


def test_paired_counts_sort_the_pairs_into_the_table():
    counts = PairedCounts.of([1, 1, 0, 0, 1], [1, 0, 1, 0, 1])
    assert counts == PairedCounts(both=2, base_only=1, cand_only=1, neither=1)


def test_mcnemar_exact_p_of_ten_base_only_against_one():
    assert mcnemar_exact(PairedCounts(49, 10, 1, 0)) == (12 / 1024, 12 / 2048)  # 2 P(X >= 10), X ~ Bin(11, 1/2)


def test_newcombe_interval_reproduces_the_published_example():
    """Cavo et al. 2012 in Fagerland, Lydersen & Laake, Statistical Analysis of Contingency Tables (2017), ch. 8:
    59 both, 6 first only, 16 second only, 80 neither: -0.0621, 95 % CI -0.1186 to -0.0046."""
    low, high = paired_difference_interval(PairedCounts(59, 16, 6, 80))
    assert round(low, 4) == -0.1186 and round(high, 4) == -0.0046


@pytest.mark.parametrize("counts", [PairedCounts(20, 0, 0, 0), PairedCounts(0, 0, 0, 20), PairedCounts(0, 20, 0, 0),
                                    PairedCounts(1, 0, 0, 0)])
def test_newcombe_interval_of_extreme_tables_holds_the_estimate_inside_minus_one_one(counts):
    low, high = paired_difference_interval(counts)
    assert -1.0 <= low <= counts.difference <= high <= 1.0 and high > low


def test_the_unpaired_test_looks_for_a_worse_candidate():
    worse, better = unpaired_exact_test(PairedCounts(80, 15, 0, 5)), unpaired_exact_test(PairedCounts(80, 0, 15, 5))
    assert worse[1] < 0.01 < 0.5 < better[1]


def test_same_successes_are_no_regression_and_a_much_worse_candidate_is_one():
    base = [True] * 50
    assert compare_success(base, base).decision == "no regression"
    assert compare_success(base, [i % 4 != 0 for i in range(50)]).decision == "regression"


def test_a_margin_forgives_a_small_drop():
    base, cand = [True] * 200, [i % 25 != 0 for i in range(200)]  # 4 points worse, 8 discordant pairs
    assert compare_success(base, cand, margin=0.0).decision == "regression"
    assert compare_success(base, cand, margin=0.05).decision == "no regression"


def test_batch_decision_and_mcnemar_keep_alpha_under_the_null():
    tables = simulated_tables(NULL, 300)
    rejected = np.mean([decision_and_interval(t)[0] == "regression" for t in tables])
    mcnemar = np.mean([decision_and_interval(t)[2] <= ALPHA for t in tables])
    assert rejected <= ALPHA + SLACK and mcnemar <= ALPHA + SLACK


def test_batch_decision_finds_a_five_point_drop_in_300_pairs():
    tables = simulated_tables(WORSE, 300, seed=1)
    assert np.mean([decision_and_interval(t)[0] == "regression" for t in tables]) >= 0.9  # 0.96 when written


def test_newcombe_interval_covers_the_true_difference_near_nominally():
    tables = simulated_tables(WORSE, 200, seed=2)
    covered = np.mean([lo <= -0.05 <= hi for lo, hi in (decision_and_interval(t)[1] for t in tables)])
    assert 0.93 <= covered <= 0.975  # 0.962 when written


# ------------------------------------------------------------------------------------------ finer metrics


def test_metric_counts_better_and_worse_by_its_direction_and_drops_missing_pairs():
    m = compare_metric([30.0, 30.0, 25.0, np.nan], [30.0, 20.0, 28.0, 30.0], higher_is_better=True)
    assert (m.pairs, m.better, m.worse, m.tied) == (3, 1, 1, 1)


def test_metric_of_a_consistently_worse_candidate_has_a_small_wilcoxon_p():
    base = np.linspace(1.0, 3.0, 30)
    m = compare_metric(base, base + 0.5, higher_is_better=False)  # lower is better: 0.5 s slower every time
    assert m.wilcoxon_p_worse < 1e-4 and m.median_difference == pytest.approx(0.5)


def test_metric_of_equal_values_is_tied_with_p_one():
    m = compare_metric([1.0, 2.0], [1.0, 2.0], higher_is_better=True)
    assert m.wilcoxon_p == 1.0 and m.median_ci == (0.0, 0.0)


# ------------------------------------------------------------------------------------------ sequential


def first_crossing(log_wealth: np.ndarray, threshold: float) -> np.ndarray:
    """Pairs needed to reach ``threshold`` in each simulation (inf: never), peeking after every pair."""
    hit = log_wealth >= math.log(threshold)
    return np.where(hit.any(axis=-1), hit.argmax(axis=-1) + 1.0, np.inf)


def test_sequential_regression_test_keeps_alpha_when_checked_after_every_pair():
    d = simulated_differences(NULL, 400)
    assert np.mean(np.isfinite(first_crossing(betting_log_wealth(-d, 1.0), 1 / ALPHA))) <= ALPHA + SLACK


def test_sequential_no_regression_test_keeps_alpha_at_its_boundary():
    margin = 0.05  # the candidate is exactly 5 points worse: "worse by the margin" is true
    d = simulated_differences((0.83, 0.08, 0.03, 0.06), 400, seed=3)
    log_wealth = betting_log_wealth(d + margin, 1.0 - margin)
    assert np.mean(np.isfinite(first_crossing(log_wealth, 1 / ALPHA))) <= ALPHA + SLACK


def test_sequential_test_finds_a_five_point_drop_within_400_pairs():
    d = simulated_differences(WORSE, 400, seed=4)
    needed = first_crossing(betting_log_wealth(-d, 1.0), 1 / ALPHA)
    assert np.mean(np.isfinite(needed)) >= 0.85  # 0.93, median 184 pairs when written


def test_sequential_test_of_a_bounded_continuous_metric_keeps_alpha_and_finds_a_shift():
    rng = np.random.default_rng(5)
    noise = rng.uniform(-0.3, 0.3, size=(SIMULATIONS, 300))
    assert np.mean(np.isfinite(first_crossing(betting_log_wealth(-noise, 1.0), 1 / ALPHA))) <= ALPHA + SLACK
    assert np.mean(np.isfinite(first_crossing(betting_log_wealth(-(noise - 0.05), 1.0), 1 / ALPHA))) >= 0.9


def test_incremental_test_equals_the_vectorised_wealth():
    d = simulated_differences(WORSE, 60, seed=6)[0]
    test = SequentialPairedTest(margin=0.02)
    for x in d:
        test.update(x)
    assert test.e_regression == pytest.approx(math.exp(betting_log_wealth(-0.02 - d, 1.02)[-1]))


def test_sequential_comparison_stops_at_the_first_decision_and_keeps_it():
    comparison = SequentialComparison({"success": 0.0}, ALPHA)
    for _ in range(100):
        comparison.update({"success": -1.0})  # the candidate fails every pair the base seats
    assert comparison.decision == "regression" and comparison.decided_at == comparison.pairs < 100


def test_sequential_comparison_rejects_a_pair_without_every_metric():
    with pytest.raises(EnvError, match="metrics"):
        SequentialComparison({"success": 0.0, "progress": 0.0}).update({"success": 0.0})


def test_bets_refuse_an_outcome_below_the_loss_bound():
    with pytest.raises(EnvError):
        betting_log_wealth([0.5, -1.5], 1.0)


# ------------------------------------------------------------------------------------------ pairing


def record(index: int, pos: tuple[float, float, float] = (0.1, 0.2, 0.3), dx: float = 0.5, **extra: object) -> dict:
    return {"index": index, "start_pos": list(pos), "start_quat": [1.0, 0.0, 0.0, 0.0], "success": True,
            "perturbation": {"hole_dx_mm": dx, "hole_yaw_deg": 0.3}, **extra}


def test_pairing_sorts_by_episode_and_accepts_rounding():
    base, cand = pair_records([record(1), record(0)], [record(0, dx=0.5 + 1e-12), record(1)])
    assert [r["index"] for r in base] == [0, 1] == [r["index"] for r in cand]


@pytest.mark.parametrize("cand, message", [
    ([record(0), record(1, pos=(0.1, 0.2, 0.31))], "episode 1: start_pos differs"),
    ([record(0), record(1, dx=0.6)], "episode 1: perturbation hole_dx_mm differs"),
    ([record(0)], "episode 1 is only in the base"),
    ([record(0), record(1), record(2)], "episode 2 is only in the candidate"),
    ([record(0), record(0)], "candidate holds episode 0 twice"),
    ([record(0), {"index": 1, "success": True}], "no numeric start_pos"),
])
def test_pairing_refuses_episodes_that_differ_in_one_line(cand, message):
    with pytest.raises(EnvError, match=message) as err:
        pair_records([record(0), record(1)], cand)
    assert "\n" not in str(err.value)


def test_an_episode_that_never_ran_carries_no_perturbation_to_compare():
    base, _ = pair_records([record(0)], [record(0, perturbation={}, reason="worker_died")])
    assert len(base) == 1
