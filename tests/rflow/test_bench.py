import pytest

from rflow.bench import bench_flow, bench_training, skill_training_configs

TIMINGS = ("train_epoch_s", "flow_step_ms", "closed_loop_step_ms", "rollout_1000_ms", "rollouts_100x1000_ms")


def test_quick_flow_benchmark_times_every_path():
    result = bench_flow(quick=True)
    assert all(result[key] > 0 for key in TIMINGS)
    # the policy's tick is two lookahead steps of two models: it cannot be cheaper than one step of one
    assert result["closed_loop_step_ms"] > result["flow_step_ms"]


def test_training_benchmark_compares_the_former_and_the_current_skill_schedule():
    """The benchmark's "current" config is the one `pih train` / `pih run` train with, its "former" one the paper's
    schedule with the same skill settings (rflow.bench cannot import scripts, so this test ties them together)."""
    import dataclasses

    from rflow.train import PAPER_SCHEDULE
    from scripts.train import skill_train_config

    former, current = skill_training_configs()
    assert current == skill_train_config()
    assert former == skill_train_config(**PAPER_SCHEDULE) == dataclasses.replace(current, **PAPER_SCHEDULE)


@pytest.mark.slow
def test_quick_training_benchmark_reports_both_medians_and_their_ratio():
    result = bench_training(quick=True)
    assert result["former_s"] > 0 and result["current_s"] > 0 and result["repeats"] == 1
    assert result["speedup"] == result["former_s"] / result["current_s"]
